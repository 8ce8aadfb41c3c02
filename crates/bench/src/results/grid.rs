//! The grid of a results benchmark: methods × scenes × seeds, one run folder per cell, and what
//! each folder says about its cell (complete, half-finished, absent).
//!
//! A cell is complete when its folder holds a `cell.json` equal to the cell's settings and a
//! `metrics.json` that parses; anything else in an existing folder is a half-finished run.

use activemap_eval::MetricsReport;
use activemap_eval::run_folder::{RunError, RunFolder, read_text, write_file};
use activemap_sim::Placement;
use std::collections::{BTreeMap, BTreeSet};
use std::path::{Path, PathBuf};

/// One exploration policy, given as the dataflow that runs it (FBE: `dataflow.yaml`; the Fisher
/// and LLM planners are further dataflow files), optionally with config overrides, so that a
/// variant of a flow is one line of a suite rather than a copy of the file.
#[derive(Debug, Clone, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
pub struct Method {
    /// Row name in the table (letters, digits, `-`, `_`, `.`; also the folder name).
    pub name: String,
    /// Dataflow file of the method.
    pub dataflow: PathBuf,
    /// Overrides of node configs applied to the file, in order, each `NODE.KEY[.SUBKEY...]=VALUE`
    /// as `activemap run --set` takes them (a suite method's `set:`). Absent from `cell.json`
    /// when empty, so folders written before overrides existed still match.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub set: Vec<String>,
}

/// A policy a bare method name stands for (SPEC §6 baselines, issue 14).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct KnownMethod {
    /// The bare name (`--method fbe`).
    pub name: &'static str,
    /// Its dataflow, relative to the repository root (the working directory of the bench).
    pub dataflow: &'static str,
    /// What the paper's ablation calls it.
    pub ablation: &'static str,
}

/// The named policies, in the order of the ablation table: FBE, then the paper's "w/o LLM &
/// localisation" (largest frontier, paths by η·EIG only), "w/o LLM" (largest frontier, the
/// full objective) and the full method (the LLM planner with the Fisher paths; offline, with
/// no provider in its flow, the LLM's fallback is the largest frontier).
pub const KNOWN_METHODS: [KnownMethod; 4] = [
    KnownMethod {
        name: "fbe",
        dataflow: "dataflow.yaml",
        ablation: "FBE (frontiers, shortest paths)",
    },
    KnownMethod {
        name: "fisher_eig_only",
        dataflow: "flows/fisher_eig_only.yaml",
        ablation: "w/o LLM & localisation",
    },
    KnownMethod {
        name: "fisher",
        dataflow: "flows/fisher.yaml",
        ablation: "w/o LLM",
    },
    KnownMethod {
        name: "llm",
        dataflow: "flows/llm.yaml",
        ablation: "Ours (LLM + Fisher)",
    },
];

/// The named policy `name`, if it is one.
pub fn known_method(name: &str) -> Option<&'static KnownMethod> {
    KNOWN_METHODS.iter().find(|m| m.name == name)
}

impl Method {
    /// Parses `NAME=DATAFLOW`, or a bare NAME of [`KNOWN_METHODS`] (its dataflow, relative to
    /// the working directory), checking the name is usable as a folder name.
    pub fn parse(text: &str) -> Result<Self, RunError> {
        let bad = |detail: String| RunError::Settings(format!("method `{text}`: {detail}"));
        let Some((name, file)) = text.split_once('=') else {
            let name = text.trim();
            return match known_method(name) {
                Some(known) => Ok(Self {
                    name: known.name.to_string(),
                    dataflow: PathBuf::from(known.dataflow),
                    set: Vec::new(),
                }),
                None => Err(bad(format!(
                    "not a known method ({}); give others as NAME=DATAFLOW, e.g. mine=flows/mine.yaml",
                    KNOWN_METHODS
                        .iter()
                        .map(|m| format!("{} = {}", m.name, m.dataflow))
                        .collect::<Vec<_>>()
                        .join(", ")
                ))),
            };
        };
        let name = name.trim();
        if !is_folder_name(name) {
            return Err(bad(format!(
                "name `{name}` must be non-empty letters, digits, `-`, `_` or `.`"
            )));
        }
        if file.trim().is_empty() {
            return Err(bad("no dataflow file".into()));
        }
        Ok(Self {
            name: name.to_string(),
            dataflow: PathBuf::from(file.trim()),
            set: Vec::new(),
        })
    }
}

/// Whether `name` can name a method's run folder: non-empty letters, digits, `-`, `_` or `.`,
/// not starting with `.`.
pub(crate) fn is_folder_name(name: &str) -> bool {
    !name.is_empty()
        && !name.starts_with('.')
        && name
            .chars()
            .all(|c| c.is_ascii_alphanumeric() || matches!(c, '-' | '_' | '.'))
}

/// Settings shared by every cell of a grid (they are part of each cell's identity). The
/// `Option` fields added after the first release are left out of `cell.json` when `None`, so
/// folders written before them still match. `Default` is a zero budget: name every field that
/// matters.
#[derive(Debug, Clone, Default, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct GridSettings {
    /// Step budget of each episode.
    pub steps: u64,
    /// Camera width and height, pixels.
    pub resolution: u32,
    /// Largest number of rooms of the procedural houses (`None` = generator default).
    pub max_rooms: Option<u32>,
    /// Largest floor area of the procedural houses, m² (`None` = generator default).
    pub max_area: Option<f64>,
    /// Test views of the evaluation (SPEC §8: 2000).
    pub eval_views: usize,
    /// Simulator noise preset set on the `sim` node (`none`, `realistic`); `None` keeps the
    /// method's own (absent from older `cell.json` files).
    #[serde(default)]
    pub noise: Option<String>,
    /// Horizontal field of view of the camera, degrees, set on the `sim` node and a Fisher
    /// scorer's camera; `None` keeps the method's.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub hfov_deg: Option<f64>,
    /// Height of the camera above the floor, metres, set in the `robot` of every node that
    /// takes one (they must agree); `None` keeps the method's.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub camera_height_m: Option<f64>,
    /// What every `planner` node does when no reachable frontier is left (`end` or `refine`,
    /// its `when_no_frontier` key); `None` keeps the method's. Suites set `refine`, so every
    /// method runs the whole step budget and all are judged after the same number of steps.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub when_no_frontier: Option<String>,
    /// Steps at which the `evaluator` also writes (and `activemap eval` evaluates) a
    /// checkpoint of the same episode, increasing and below `steps`; the tables are then also
    /// written at each ([`crate::results::write_checkpoint_tables`]). Empty: the last step only.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub checkpoints: Vec<u64>,
    /// Keys set in the `llm:` block of every `planner` node whose policy is `llm` (a suite's
    /// `llm:`, typically the `provider`); `None` keeps the method's.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub llm: Option<serde_json::Value>,
}

/// One cell of the grid: a method on a scene with a seed, under the grid's settings.
#[derive(Debug, Clone, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct Cell {
    /// The method.
    pub method: Method,
    /// The scene, `house:<seed>` or a scene file.
    pub scene: String,
    /// How a scene file is placed (`up_axis`, `transform`, `floor` of the `sim` and
    /// `evaluator` nodes); the default (absent from `cell.json`) places it as the format says.
    #[serde(default, skip_serializing_if = "is_default_placement")]
    pub placement: Placement,
    /// Repetition seed (set on every node whose config declares `seed`).
    pub seed: u64,
    /// The grid's settings.
    pub settings: GridSettings,
}

fn is_default_placement(p: &Placement) -> bool {
    *p == Placement::default()
}

/// File in a cell's folder holding the cell (written before the run starts).
pub const CELL_FILE: &str = "cell.json";

impl Cell {
    /// The cell's run folder under `out`: `<method>/<scene>/seed<seed>`, the scene made
    /// folder-safe (`house:3` → `house-3`).
    pub fn dir(&self, out: &Path) -> PathBuf {
        out.join(&self.method.name)
            .join(scene_folder(&self.scene))
            .join(format!("seed{}", self.seed))
    }

    /// Short label for progress lines, e.g. `fbe house:3 seed 1`.
    pub fn label(&self) -> String {
        format!("{} {} seed {}", self.method.name, self.scene, self.seed)
    }

    /// Writes `cell.json` into `dir` (created).
    pub fn save(&self, dir: &Path) -> Result<(), RunError> {
        std::fs::create_dir_all(dir).map_err(|source| RunError::Io {
            path: dir.to_path_buf(),
            source,
        })?;
        let text = serde_json::to_string_pretty(self).unwrap_or_default();
        write_file(&dir.join(CELL_FILE), text)
    }
}

/// A folder-safe form of a scene name: every character other than letters, digits, `-`, `_`
/// and `.` becomes `-` (a path keeps only its file name).
pub fn scene_folder(scene: &str) -> String {
    let name = if scene.contains('/') {
        Path::new(scene)
            .file_name()
            .map_or(scene.to_string(), |f| f.to_string_lossy().into_owned())
    } else {
        scene.to_string()
    };
    name.chars()
        .map(|c| {
            if c.is_ascii_alphanumeric() || matches!(c, '-' | '_' | '.') {
                c
            } else {
                '-'
            }
        })
        .collect()
}

/// Every cell of methods × scenes × seeds, in that nesting order, each scene placed as its
/// format says (a suite gives placements: [`super::suite::Suite::cells`]).
pub fn cells(
    methods: &[Method],
    scenes: &[String],
    seeds: &[u64],
    settings: &GridSettings,
) -> Vec<Cell> {
    let mut out = Vec::with_capacity(methods.len() * scenes.len() * seeds.len());
    for method in methods {
        for scene in scenes {
            for &seed in seeds {
                out.push(Cell {
                    method: method.clone(),
                    scene: scene.clone(),
                    placement: Placement::default(),
                    seed,
                    settings: settings.clone(),
                });
            }
        }
    }
    out
}

/// What a cell's folder holds.
#[derive(Debug, Clone, PartialEq)]
pub enum CellState {
    /// No folder: never started.
    Absent,
    /// A folder without a usable `metrics.json`: interrupted or failed; to be re-run.
    HalfFinished,
    /// Finished: the metrics of its run.
    Complete(Box<MetricsReport>),
}

/// The state of `cell`'s folder under `out`. A folder whose `cell.json` holds other settings
/// is an error (re-running would silently mix two configurations): use another output folder.
pub fn cell_state(cell: &Cell, out: &Path) -> Result<CellState, RunError> {
    let dir = cell.dir(out);
    if !dir.exists() {
        return Ok(CellState::Absent);
    }
    let cell_path = dir.join(CELL_FILE);
    let recorded = match read_text(&cell_path, "the cell's settings") {
        Ok(text) => text,
        Err(RunError::Missing { .. }) => return Ok(CellState::HalfFinished),
        Err(e) => return Err(e),
    };
    let recorded: Cell = serde_json::from_str(&recorded).map_err(|e| RunError::Malformed {
        path: cell_path.clone(),
        detail: e.to_string(),
    })?;
    if recorded != *cell {
        return Err(RunError::Malformed {
            path: cell_path,
            detail: format!(
                "this folder was run with other settings ({}); choose another output folder",
                settings_difference(&recorded, cell)
            ),
        });
    }
    // Absent, unreadable or cut short by a kill: not complete.
    match RunFolder::new(&dir).read_metrics() {
        Ok(Some(m)) => Ok(CellState::Complete(Box::new(m))),
        Ok(None) | Err(_) => Ok(CellState::HalfFinished),
    }
}

/// Names what differs between two cells, for error messages.
fn settings_difference(a: &Cell, b: &Cell) -> String {
    /// Every leaf of a cell's JSON by its dotted path (`settings.` and `method.` left out, so
    /// `steps`, `dataflow`, `placement.up_axis`), strings without their quotes.
    fn leaves(prefix: &str, value: &serde_json::Value, out: &mut BTreeMap<String, String>) {
        match value {
            serde_json::Value::Object(map) => {
                for (key, v) in map {
                    let path = match prefix {
                        "" | "settings" | "method" => key.clone(),
                        _ => format!("{prefix}.{key}"),
                    };
                    leaves(&path, v, out);
                }
            }
            serde_json::Value::String(text) => {
                out.insert(prefix.to_string(), text.clone());
            }
            other => {
                out.insert(prefix.to_string(), other.to_string());
            }
        }
    }
    let flat = |cell: &Cell| {
        let mut out = BTreeMap::new();
        leaves(
            "",
            &serde_json::to_value(cell).unwrap_or_default(),
            &mut out,
        );
        out
    };
    let (fa, fb) = (flat(a), flat(b));
    let keys: BTreeSet<&String> = fa.keys().chain(fb.keys()).collect();
    let shown = |v: Option<&String>| v.map_or("none".to_string(), Clone::clone);
    let diff: Vec<String> = keys
        .into_iter()
        .filter(|k| fa.get(*k) != fb.get(*k))
        .map(|k| format!("{k} {} there, {} now", shown(fa.get(k)), shown(fb.get(k))))
        .collect();
    if diff.is_empty() {
        "the cell differs".into()
    } else {
        diff.join(", ")
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    pub(crate) fn settings() -> GridSettings {
        GridSettings {
            steps: 40,
            resolution: 64,
            max_rooms: Some(2),
            max_area: Some(30.0),
            eval_views: 10,
            noise: None,
            ..GridSettings::default()
        }
    }

    #[test]
    fn methods_parse_and_bad_names_are_refused() {
        let m = Method::parse("fbe=dataflow.yaml").unwrap();
        assert_eq!(m.name, "fbe");
        assert_eq!(m.dataflow, PathBuf::from("dataflow.yaml"));
        for bad in ["fbe_typo", "=x.yaml", "a/b=x.yaml", "fbe=", "..=x.yaml", ""] {
            let e = Method::parse(bad).unwrap_err().to_string();
            assert!(e.contains(&format!("method `{bad}`")), "{e}");
        }
    }

    /// A bare known name resolves to its dataflow; an unknown one is refused with the list.
    #[test]
    fn bare_names_resolve_to_the_known_dataflows() {
        for (name, file) in [
            ("fbe", "dataflow.yaml"),
            ("fisher", "flows/fisher.yaml"),
            ("fisher_eig_only", "flows/fisher_eig_only.yaml"),
            (" fisher ", "flows/fisher.yaml"),
        ] {
            let m = Method::parse(name).unwrap();
            assert_eq!(
                (m.name.as_str(), m.dataflow),
                (name.trim(), PathBuf::from(file))
            );
        }
        // NAME=DATAFLOW still overrides a known name's file.
        assert_eq!(
            Method::parse("fisher=other.yaml").unwrap().dataflow,
            PathBuf::from("other.yaml")
        );
        assert_eq!(
            Method::parse("llm").unwrap().dataflow,
            PathBuf::from("flows/llm.yaml")
        );
        let e = Method::parse("gpt").unwrap_err().to_string();
        assert!(
            e.contains("not a known method")
                && e.contains("fbe = dataflow.yaml")
                && e.contains("fisher = flows/fisher.yaml")
                && e.contains("fisher_eig_only = flows/fisher_eig_only.yaml")
                && e.contains("NAME=DATAFLOW"),
            "{e}"
        );
    }

    #[test]
    fn grid_enumerates_every_cell_into_its_own_folder() {
        let methods = [
            Method::parse("fbe=a.yaml").unwrap(),
            Method::parse("fisher=b.yaml").unwrap(),
        ];
        let scenes = ["house:1".to_string(), "scenes/x y.glb".to_string()];
        let cells = cells(&methods, &scenes, &[1, 2, 3], &settings());
        assert_eq!(cells.len(), 12);
        let dirs: std::collections::BTreeSet<PathBuf> =
            cells.iter().map(|c| c.dir(Path::new("/o"))).collect();
        assert_eq!(dirs.len(), 12);
        assert_eq!(
            cells[0].dir(Path::new("/o")),
            PathBuf::from("/o/fbe/house-1/seed1")
        );
        assert_eq!(
            cells[11].dir(Path::new("/o")),
            PathBuf::from("/o/fisher/x-y.glb/seed3")
        );
    }

    #[test]
    fn cell_states_follow_the_folder_contents() {
        let out = tempfile::tempdir().unwrap();
        let cell = cells(
            &[Method::parse("fbe=a.yaml").unwrap()],
            &["house:1".into()],
            &[7],
            &settings(),
        )
        .remove(0);
        assert_eq!(cell_state(&cell, out.path()).unwrap(), CellState::Absent);
        let dir = cell.dir(out.path());
        std::fs::create_dir_all(&dir).unwrap();
        assert_eq!(
            cell_state(&cell, out.path()).unwrap(),
            CellState::HalfFinished
        );
        cell.save(&dir).unwrap();
        assert_eq!(
            cell_state(&cell, out.path()).unwrap(),
            CellState::HalfFinished
        );
        // A metrics.json cut short by a kill is not complete.
        std::fs::write(dir.join(RunFolder::METRICS_JSON), "{\"psnr_db\": 1").unwrap();
        assert_eq!(
            cell_state(&cell, out.path()).unwrap(),
            CellState::HalfFinished
        );
        let report = MetricsReport {
            psnr_db: Some(20.5),
            test_views: 10,
            ..Default::default()
        };
        std::fs::write(dir.join(RunFolder::METRICS_JSON), report.to_json()).unwrap();
        assert_eq!(
            cell_state(&cell, out.path()).unwrap(),
            CellState::Complete(Box::new(report))
        );
        // Other settings in the same folder: refused, naming the difference.
        let mut other = cell.clone();
        other.settings.steps = 41;
        let e = cell_state(&other, out.path()).unwrap_err().to_string();
        assert!(
            e.contains("cell.json") && e.contains("steps 40 there, 41 now"),
            "{e}"
        );
        // A suite's settings and placement are named too, `none` where one side lacks them.
        let mut other = cell.clone();
        other.settings.camera_height_m = Some(1.25);
        other.placement.up_axis = Some(activemap_sim::UpAxis::Y);
        let e = cell_state(&other, out.path()).unwrap_err().to_string();
        assert!(
            e.contains("camera_height_m none there, 1.25 now")
                && e.contains("placement.up_axis none there, y now"),
            "{e}"
        );
    }
}
