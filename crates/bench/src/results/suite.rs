//! A benchmark suite as a file: what `activemap bench results --suite FILE` runs.
//!
//! A suite is one YAML mapping (the dataflow files' reader, [`activemap_runtime::yaml`], so
//! every error names `file:line:col` and unknown keys are refused):
//!
//! ```yaml
//! description: FBE against the Fisher paths, quick   # optional, printed under the title
//! methods:                          # known names, or { name: mine, dataflow: flows/mine.yaml }
//!   - fbe
//!   - fisher
//!   - name: fisher_utility          # a variant: the file with config overrides (`--set` syntax)
//!     dataflow: ../flows/fisher.yaml
//!     set: [planner.frontier=utility]
//! scenes:
//!   - house:7                       # a procedural house
//!   - scene: ../../shared/data/scenes/aws_small_house.glb
//!     up_axis: y                    # placement of a scene file: up_axis, transform, floor
//!     floor: none
//! houses: { max_rooms: 8, max_area: 200 }   # optional: size limits of every procedural house
//! seeds: [1, 2, 3]
//! steps: 2000
//! camera: { resolution: 160, hfov_deg: 90, height_m: 1.25 }  # each key optional
//! noise: realistic                  # optional: none | realistic (the sim node's preset)
//! eval_views: 500
//! when_no_frontier: refine          # optional, default refine: every method runs all steps
//! checkpoints: [500, 1000]          # optional: tables also at these steps, same episodes
//! llm:                              # optional: keys of the `llm` planners' `llm:` block
//!   provider: { kind: ollama, base_url: "http://127.0.0.1:11434", model: qwen2.5:1.5b }
//! ```
//!
//! A method whose planner has policy `llm` but asks no model (no `provider` in its flow nor in
//! the suite's `llm:`) is skipped with a message: offline it would be the largest-frontier
//! fallback under the `llm` name.
//!
//! Paths (scene files, a method's `dataflow`) are relative to the suite file's folder; a known
//! method name ([`KNOWN_METHODS`]) stands for its dataflow relative to the working directory
//! (the repository root), as on the command line. Settings a suite leaves out keep the method's own (its
//! dataflow file's values), except `when_no_frontier`, which defaults to `refine`: FBE's
//! planner then goes on with look-arounds once no frontier is left instead of ending the
//! episode, so every method is judged after the same number of steps.

use super::grid::{
    Cell, GridSettings, KNOWN_METHODS, Method, is_folder_name, known_method, scene_folder,
};
use activemap_geometry::RobotModel;
use activemap_runtime::dataflow::{Diagnostic, Diagnostics, Override};
use activemap_runtime::yaml::{self, Loc, Node};
use activemap_sim::{NoiseConfig, Placement, SceneSpec};
use std::path::{Path, PathBuf};

/// One scene of a suite: `house:<seed>` or a scene file (absolute), with its placement.
#[derive(Debug, Clone, PartialEq)]
pub struct SuiteScene {
    /// `house:<seed>` or the scene file's absolute path.
    pub scene: String,
    /// How the file is placed (default for a procedural house).
    pub placement: Placement,
}

/// A parsed, checked suite.
#[derive(Debug, Clone, PartialEq)]
pub struct Suite {
    /// The file it was read from.
    pub file: PathBuf,
    /// Its `description`, if any.
    pub description: Option<String>,
    /// The methods (table rows), dataflows absolute.
    pub methods: Vec<Method>,
    /// The scenes.
    pub scenes: Vec<SuiteScene>,
    /// The seeds.
    pub seeds: Vec<u64>,
    /// Settings of every cell.
    pub settings: GridSettings,
}

/// Keys of a suite file.
const SUITE_KEYS: [&str; 12] = [
    "description",
    "methods",
    "scenes",
    "houses",
    "seeds",
    "steps",
    "camera",
    "noise",
    "eval_views",
    "when_no_frontier",
    "llm",
    // Reserved for evaluating one episode at several step counts; refused until it exists.
    "checkpoints",
];

/// Keys of a scene given as a mapping.
const SCENE_KEYS: [&str; 4] = ["scene", "up_axis", "transform", "floor"];

impl Suite {
    /// Reads and checks the suite file `path`; known method names resolve against `root` (the
    /// working directory on the command line). Every problem found is reported, each as
    /// `path:line:col: error: …`.
    pub fn load(path: &Path, root: &Path) -> Result<Self, Diagnostics> {
        let label = path.display().to_string();
        let text = std::fs::read_to_string(path).map_err(|e| {
            Diagnostics(vec![Diagnostic {
                file: label.clone(),
                loc: Loc::default(),
                message: format!("cannot read the suite: {e}"),
            }])
        })?;
        let base = path
            .parent()
            .map(Path::to_path_buf)
            .unwrap_or_else(|| PathBuf::from("."));
        let mut suite = Self::parse(&label, &text, &base, root)?;
        suite.file = path.to_path_buf();
        Ok(suite)
    }

    /// Parses suite `text` (named `file` in errors); relative paths resolve against `base`
    /// (the suite's folder), known method names against `root`.
    pub fn parse(file: &str, text: &str, base: &Path, root: &Path) -> Result<Self, Diagnostics> {
        let mut p = Parser {
            file,
            base,
            root,
            diags: Vec::new(),
        };
        let root = yaml::parse(text).map_err(|e| {
            Diagnostics(vec![Diagnostic {
                file: file.to_string(),
                loc: e.loc,
                message: e.message,
            }])
        })?;
        let suite = p.suite(&root);
        match suite {
            Some(s) if p.diags.is_empty() => Ok(s),
            _ => Err(Diagnostics(p.diags)),
        }
    }

    /// Every cell of the suite: methods × scenes × seeds, in that nesting order.
    pub fn cells(&self) -> Vec<Cell> {
        let mut out = Vec::new();
        for method in &self.methods {
            for scene in &self.scenes {
                for &seed in &self.seeds {
                    out.push(Cell {
                        method: method.clone(),
                        scene: scene.scene.clone(),
                        placement: scene.placement,
                        seed,
                        settings: self.settings.clone(),
                    });
                }
            }
        }
        out
    }
}

struct Parser<'a> {
    file: &'a str,
    base: &'a Path,
    root: &'a Path,
    diags: Vec<Diagnostic>,
}

impl Parser<'_> {
    fn err(&mut self, loc: Loc, message: impl Into<String>) {
        self.diags.push(Diagnostic {
            file: self.file.to_string(),
            loc,
            message: message.into(),
        });
    }

    /// The entries of a mapping, checking its keys against `allowed` (`what` names the
    /// mapping in errors); `None` (and an error) when `node` is not a mapping.
    fn entries<'n>(
        &mut self,
        node: &'n Node,
        what: &str,
        allowed: &[&str],
    ) -> Option<&'n [(String, Loc, Node)]> {
        let Node::Map { entries, .. } = node else {
            self.err(
                node.loc(),
                format!("{what} must be a mapping, not {}", node.type_name()),
            );
            return None;
        };
        for (key, loc, _) in entries {
            if !allowed.contains(&key.as_str()) {
                self.err(
                    *loc,
                    format!(
                        "unknown {what} key `{key}` (expected {})",
                        allowed
                            .iter()
                            .map(|k| format!("`{k}`"))
                            .collect::<Vec<_>>()
                            .join(", ")
                    ),
                );
            }
        }
        Some(entries)
    }

    /// The plain (unquoted) scalar of `key` as `read` takes it from its JSON value; otherwise
    /// an error saying it must be `expected` and showing what it is.
    fn plain<T>(
        &mut self,
        key: &str,
        node: &Node,
        expected: &str,
        read: impl Fn(&serde_json::Value) -> Option<T>,
    ) -> Option<T> {
        let value = match node {
            Node::Scalar { quoted: false, .. } => read(&node.to_json()),
            _ => None,
        };
        if value.is_none() {
            let shown = node
                .as_str()
                .map_or(node.type_name().to_string(), |s| format!("`{s}`"));
            self.err(
                node.loc(),
                format!("`{key}` must be {expected}, got {shown}"),
            );
        }
        value
    }

    /// A plain number of `key` that `ok` accepts; the error says what was expected.
    fn number(
        &mut self,
        key: &str,
        node: &Node,
        expected: &str,
        ok: fn(f64) -> bool,
    ) -> Option<f64> {
        self.plain(key, node, expected, |v| v.as_f64().filter(|x| ok(*x)))
    }

    /// A plain unsigned integer of `key`, at least `min`.
    fn integer(&mut self, key: &str, node: &Node, min: u64) -> Option<u64> {
        self.plain(key, node, &format!("an integer ≥ {min}"), |v| {
            v.as_u64().filter(|x| *x >= min)
        })
    }

    /// A scalar string of `key`.
    fn string(&mut self, key: &str, node: &Node) -> Option<String> {
        match node {
            Node::Scalar { value, .. } if !value.trim().is_empty() => {
                Some(value.trim().to_string())
            }
            _ => {
                self.err(node.loc(), format!("`{key}` must be a non-empty string"));
                None
            }
        }
    }

    /// A non-empty sequence of `key`.
    fn list<'n>(&mut self, key: &str, node: &'n Node) -> Option<&'n [Node]> {
        match node {
            Node::Seq { items, .. } if !items.is_empty() => Some(items),
            _ => {
                self.err(node.loc(), format!("`{key}` must be a non-empty list"));
                None
            }
        }
    }

    /// A path relative to the suite's folder, made canonical, that must be a file.
    fn file_path(&mut self, key: &str, node: &Node, text: &str) -> Option<PathBuf> {
        let path = self.base.join(text);
        let path = std::path::absolute(&path).unwrap_or(path);
        if path.is_file() {
            Some(std::fs::canonicalize(&path).unwrap_or(path))
        } else {
            self.err(
                node.loc(),
                format!(
                    "`{key}`: no such file: {} (paths are relative to the suite's folder)",
                    path.display()
                ),
            );
            None
        }
    }

    fn suite(&mut self, root: &Node) -> Option<Suite> {
        let entries = self.entries(root, "suite", &SUITE_KEYS)?;
        // Missing keys are reported at the top of the file.
        let root_loc = Loc { line: 1, col: 1 };
        let mut description = None;
        let mut methods = None;
        let mut scenes = None;
        let mut seeds = None;
        let mut steps = None;
        let mut eval_views = None;
        let mut checkpoints = None;
        let mut settings = GridSettings {
            resolution: 160,
            when_no_frontier: Some("refine".into()),
            ..GridSettings::default()
        };
        for (key, _, value) in entries {
            match key.as_str() {
                "description" => description = self.string(key, value),
                "methods" => methods = self.methods(value),
                "scenes" => scenes = self.scenes(value),
                "houses" => self.houses(value, &mut settings),
                "seeds" => seeds = self.seeds(value),
                "steps" => steps = self.integer(key, value, 1),
                "eval_views" => eval_views = self.integer(key, value, 1),
                "camera" => self.camera(value, &mut settings),
                "noise" => settings.noise = self.noise(value),
                "when_no_frontier" => {
                    settings.when_no_frontier = self.string(key, value).and_then(|v| {
                        if matches!(v.as_str(), "end" | "refine") {
                            Some(v)
                        } else {
                            self.err(
                                value.loc(),
                                format!("`when_no_frontier` must be `end` or `refine`, got `{v}`"),
                            );
                            None
                        }
                    })
                }
                "checkpoints" => checkpoints = self.checkpoints(value),
                "llm" => match value {
                    Node::Map { .. } => settings.llm = Some(value.to_json()),
                    other => self.err(
                        other.loc(),
                        format!(
                            "`llm` must be a mapping (the planner's `llm:` keys), got {}",
                            other.type_name()
                        ),
                    ),
                },
                _ => {} // refused by `entries`
            }
        }
        for (key, present) in [
            (
                "methods",
                methods.is_some() || root.get("methods").is_some(),
            ),
            ("scenes", scenes.is_some() || root.get("scenes").is_some()),
            ("seeds", seeds.is_some() || root.get("seeds").is_some()),
            ("steps", steps.is_some() || root.get("steps").is_some()),
            (
                "eval_views",
                eval_views.is_some() || root.get("eval_views").is_some(),
            ),
        ] {
            if !present {
                self.err(root_loc, format!("missing key `{key}`"));
            }
        }
        if let Some(scenes) = &scenes {
            self.check_house_sizes(scenes, &settings, root);
        }
        settings.steps = steps?;
        settings.eval_views = usize::try_from(eval_views?).ok()?;
        if let Some((checkpoints, loc)) = checkpoints {
            if let Some(&last) = checkpoints.last()
                && last >= settings.steps
            {
                self.err(
                    loc,
                    format!(
                        "checkpoint {last} is not before the last step ({}): the run itself is evaluated there",
                        settings.steps
                    ),
                );
                return None;
            }
            settings.checkpoints = checkpoints;
        }
        Some(Suite {
            file: PathBuf::from(self.file),
            description,
            methods: methods?,
            scenes: scenes?,
            seeds: seeds?,
            settings,
        })
    }

    fn methods(&mut self, node: &Node) -> Option<Vec<Method>> {
        let items = self.list("methods", node)?;
        let mut out: Vec<Method> = Vec::new();
        let mut ok = true;
        for item in items {
            let method = match item {
                Node::Scalar { value, .. } => match known_method(value.trim()) {
                    Some(known) => {
                        let dataflow = self.root.join(known.dataflow);
                        let dataflow = std::path::absolute(&dataflow).unwrap_or(dataflow);
                        if dataflow.is_file() {
                            Some(Method {
                                name: known.name.to_string(),
                                dataflow,
                                set: Vec::new(),
                            })
                        } else {
                            self.err(
                                item.loc(),
                                format!(
                                    "method `{}`: no such file: {} (known names resolve against the working directory: run from the repository root, or give `{{ name: …, dataflow: … }}`)",
                                    known.name,
                                    dataflow.display()
                                ),
                            );
                            None
                        }
                    }
                    None => {
                        self.err(
                            item.loc(),
                            format!(
                                "method `{value}`: not a known method ({}); give others as `{{ name: NAME, dataflow: FILE }}`",
                                KNOWN_METHODS
                                    .iter()
                                    .map(|m| m.name)
                                    .collect::<Vec<_>>()
                                    .join(", ")
                            ),
                        );
                        None
                    }
                },
                Node::Map { .. } => self.method_map(item),
                other => {
                    self.err(
                        other.loc(),
                        "a method is a known name or `{ name: NAME, dataflow: FILE }`",
                    );
                    None
                }
            };
            match method {
                Some(m) if out.iter().any(|o| o.name == m.name) => {
                    self.err(item.loc(), format!("method `{}` is listed twice", m.name));
                    ok = false;
                }
                Some(m) => out.push(m),
                None => ok = false,
            }
        }
        ok.then_some(out)
    }

    fn method_map(&mut self, node: &Node) -> Option<Method> {
        let entries = self.entries(node, "method", &["name", "dataflow", "set"])?;
        let (mut name, mut dataflow, mut set) = (None, None, Some(Vec::new()));
        for (key, _, value) in entries {
            match key.as_str() {
                "name" => {
                    name = self.string(key, value).and_then(|n| {
                        if is_folder_name(&n) {
                            Some(n)
                        } else {
                            self.err(
                                value.loc(),
                                format!("method name `{n}` must be letters, digits, `-`, `_` or `.` (it names the run folders)"),
                            );
                            None
                        }
                    })
                }
                "dataflow" => {
                    dataflow = self
                        .string(key, value)
                        .and_then(|d| self.file_path("dataflow", value, &d))
                }
                "set" => set = self.overrides(value),
                _ => {}
            }
        }
        if node.get("name").is_none() || node.get("dataflow").is_none() {
            self.err(node.loc(), "a method mapping needs `name` and `dataflow`");
        }
        let (dataflow, set) = (dataflow?, set?);
        if let Some(items) = node.get("set") {
            self.check_overrides(&dataflow, items, &set);
        }
        Some(Method {
            name: name?,
            dataflow,
            set: set.iter().map(|o| o.text().to_string()).collect(),
        })
    }

    /// A method's `set:`: a list of `NODE.KEY[.SUBKEY...]=VALUE` strings, each checked as
    /// `activemap run --set` checks it.
    fn overrides(&mut self, node: &Node) -> Option<Vec<Override>> {
        let items = self.list("set", node)?;
        let mut out = Vec::new();
        for item in items {
            let Some(text) = self.string("set", item) else {
                continue;
            };
            match Override::parse(&text) {
                Ok(o) => out.push(o),
                Err(e) => self.err(item.loc(), format!("`set`: {e}")),
            }
        }
        (out.len() == items.len()).then_some(out)
    }

    /// Applies `set` to the method's dataflow file, reporting an override that names no node
    /// (or a key under a value that is not a mapping) at its line of the suite; the operators'
    /// checks of the values run when the cells' dataflows are derived, before any episode.
    fn check_overrides(&mut self, dataflow: &Path, items: &Node, set: &[Override]) {
        let Ok(text) = std::fs::read_to_string(dataflow) else {
            return;
        };
        let Ok(mut tree) = yaml::parse(&text) else {
            return;
        };
        let Node::Seq { items, .. } = items else {
            return;
        };
        for (index, (o, item)) in set.iter().zip(items).enumerate() {
            if let Err(e) = o.apply(&mut tree, index) {
                self.err(item.loc(), format!("{e} in {}", dataflow.display()));
            }
        }
    }

    fn scenes(&mut self, node: &Node) -> Option<Vec<SuiteScene>> {
        let items = self.list("scenes", node)?;
        let mut out: Vec<SuiteScene> = Vec::new();
        let mut ok = true;
        for item in items {
            match self.scene(item) {
                Some(s) => {
                    let folder = scene_folder(&s.scene);
                    if out.iter().any(|o| scene_folder(&o.scene) == folder) {
                        self.err(
                            item.loc(),
                            format!("scene `{}` is listed twice (its run folders would be the same, `{folder}`)", s.scene),
                        );
                        ok = false;
                    } else {
                        out.push(s);
                    }
                }
                None => ok = false,
            }
        }
        ok.then_some(out)
    }

    fn scene(&mut self, node: &Node) -> Option<SuiteScene> {
        let (name_node, entries): (&Node, &[(String, Loc, Node)]) = match node {
            Node::Scalar { .. } => (node, &[]),
            Node::Map { .. } => {
                let entries = self.entries(node, "scene", &SCENE_KEYS)?;
                let Some(name) = node.get("scene") else {
                    self.err(
                        node.loc(),
                        "a scene mapping needs `scene` (`house:<seed>` or a file)",
                    );
                    return None;
                };
                (name, entries)
            }
            Node::Seq { .. } => {
                self.err(
                    node.loc(),
                    "a scene is `house:<seed>`, a file, or a mapping with `scene`",
                );
                return None;
            }
        };
        let name = self.string("scene", name_node)?;
        let house = SceneSpec::new(name.clone()).house_seed();
        let scene = match house {
            Ok(Some(_)) => name,
            Ok(None) => self
                .file_path("scene", name_node, &name)?
                .display()
                .to_string(),
            Err(e) => {
                self.err(name_node.loc(), e.to_string());
                return None;
            }
        };
        let mut placement = serde_json::Map::new();
        let mut ok = true;
        for (key, key_loc, value) in entries.iter().filter(|e| e.0 != "scene") {
            if !SCENE_KEYS.contains(&key.as_str()) {
                ok = false;
                continue;
            }
            if house.as_ref().is_ok_and(Option::is_some) {
                self.err(
                    *key_loc,
                    format!("`{key}` places a scene file; `{scene}` is a procedural house"),
                );
                ok = false;
                continue;
            }
            let mut one = serde_json::Map::new();
            one.insert(key.clone(), value.to_json());
            match serde_json::from_value::<Placement>(serde_json::Value::Object(one)) {
                Ok(_) => {
                    placement.insert(key.clone(), value.to_json());
                }
                Err(e) => {
                    self.err(value.loc(), format!("bad `{key}`: {e}"));
                    ok = false;
                }
            }
        }
        if !ok {
            return None;
        }
        let placement = serde_json::from_value(serde_json::Value::Object(placement)).ok()?;
        Some(SuiteScene { scene, placement })
    }

    fn houses(&mut self, node: &Node, settings: &mut GridSettings) {
        let Some(entries) = self.entries(node, "houses", &["max_rooms", "max_area"]) else {
            return;
        };
        for (key, _, value) in entries {
            match key.as_str() {
                "max_rooms" => {
                    settings.max_rooms = self
                        .integer(key, value, 1)
                        .and_then(|v| u32::try_from(v).ok())
                }
                "max_area" => {
                    settings.max_area = self.number(key, value, "a positive area, m²", |v| v > 0.0)
                }
                _ => {}
            }
        }
    }

    /// The house generator's own check of the size limits (on the first procedural scene).
    fn check_house_sizes(&mut self, scenes: &[SuiteScene], settings: &GridSettings, root: &Node) {
        let Some(house) = scenes
            .iter()
            .find(|s| SceneSpec::new(s.scene.clone()).is_procedural())
        else {
            return;
        };
        let spec = SceneSpec {
            max_rooms: settings.max_rooms,
            max_area: settings.max_area,
            ..SceneSpec::new(house.scene.clone())
        };
        if let Err(e) = spec.house_config() {
            let loc = root
                .get("houses")
                .map_or(Loc { line: 1, col: 1 }, Node::loc);
            self.err(loc, format!("`houses`: {e}"));
        }
    }

    /// `checkpoints: [500, 1000]`: increasing step counts ≥ 1 (with the list's location, for the
    /// check against `steps`).
    fn checkpoints(&mut self, node: &Node) -> Option<(Vec<u64>, Loc)> {
        let items = self.list("checkpoints", node)?;
        let mut out: Vec<u64> = Vec::new();
        let mut ok = true;
        for item in items {
            match self.integer("checkpoints", item, 1) {
                Some(s) if out.last().is_some_and(|&last| s <= last) => {
                    self.err(
                        item.loc(),
                        format!(
                            "checkpoints must increase: {s} after {}",
                            out[out.len() - 1]
                        ),
                    );
                    ok = false;
                }
                Some(s) => out.push(s),
                None => ok = false,
            }
        }
        ok.then_some((out, node.loc()))
    }

    fn seeds(&mut self, node: &Node) -> Option<Vec<u64>> {
        let items = self.list("seeds", node)?;
        let mut out = Vec::new();
        let mut ok = true;
        for item in items {
            match self.integer("seeds", item, 0) {
                Some(s) if out.contains(&s) => {
                    self.err(item.loc(), format!("seed {s} is listed twice"));
                    ok = false;
                }
                Some(s) => out.push(s),
                None => ok = false,
            }
        }
        ok.then_some(out)
    }

    fn camera(&mut self, node: &Node, settings: &mut GridSettings) {
        let Some(entries) = self.entries(node, "camera", &["resolution", "hfov_deg", "height_m"])
        else {
            return;
        };
        for (key, _, value) in entries {
            match key.as_str() {
                "resolution" => {
                    if let Some(r) = self.integer(key, value, 16) {
                        if r <= 4096 {
                            settings.resolution = r as u32;
                        } else {
                            self.err(
                                value.loc(),
                                format!("`resolution` must be in 16..=4096 pixels, got {r}"),
                            );
                        }
                    }
                }
                "hfov_deg" => {
                    settings.hfov_deg =
                        self.number(key, value, "an angle in (1, 179) degrees", |v| {
                            v > 1.0 && v < 179.0
                        })
                }
                "height_m" => {
                    let height = self.number(key, value, "a height in metres", f64::is_finite);
                    if let Some(h) = height {
                        let robot = RobotModel {
                            camera_height_m: h,
                            ..RobotModel::default()
                        };
                        match robot.validate() {
                            Ok(()) => settings.camera_height_m = Some(h),
                            Err(e) => self.err(value.loc(), format!("`height_m`: {e}")),
                        }
                    }
                }
                _ => {}
            }
        }
    }

    fn noise(&mut self, node: &Node) -> Option<String> {
        let name = self.string("noise", node)?;
        match NoiseConfig::from_value(&serde_json::Value::String(name.clone())) {
            Ok(_) => Some(name),
            Err(e) => {
                self.err(node.loc(), format!("bad `noise`: {e}"));
                None
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use activemap_sim::{Floor, UpAxis};

    /// The repository root: known method names resolve against it.
    fn root() -> PathBuf {
        Path::new(env!("CARGO_MANIFEST_DIR")).join("../..")
    }

    const VALID: &str = "\
description: test suite
methods: [fbe, { name: mine, dataflow: flows/mine.yaml }]
scenes:
  - house:3
  - scene: room.glb
    up_axis: -y
    floor: auto
    transform: { scale: 0.01, rotate_deg: [0, 0, 90] }
houses: { max_rooms: 4, max_area: 80 }
seeds: [1, 2]
steps: 300
camera: { resolution: 96, hfov_deg: 79, height_m: 1.25 }
noise: realistic
eval_views: 20
";

    /// A folder with the files `VALID` names (their content is not read).
    fn folder() -> tempfile::TempDir {
        let dir = tempfile::tempdir().unwrap();
        std::fs::write(dir.path().join("room.glb"), b"").unwrap();
        std::fs::create_dir(dir.path().join("flows")).unwrap();
        std::fs::write(dir.path().join("flows/mine.yaml"), b"nodes: []").unwrap();
        dir
    }

    fn parse(dir: &Path, text: &str) -> Result<Suite, Diagnostics> {
        Suite::parse("s.yaml", text, dir, &root())
    }

    #[test]
    fn a_valid_suite_gives_its_cells() {
        let dir = folder();
        let suite = parse(dir.path(), VALID).unwrap();
        assert_eq!(suite.description.as_deref(), Some("test suite"));
        let names: Vec<&str> = suite.methods.iter().map(|m| m.name.as_str()).collect();
        assert_eq!(names, ["fbe", "mine"]);
        assert!(suite.methods[0].dataflow.ends_with("dataflow.yaml"));
        assert!(suite.methods[0].dataflow.is_absolute() && suite.methods[0].dataflow.is_file());
        assert_eq!(
            suite.methods[1].dataflow,
            std::fs::canonicalize(dir.path().join("flows/mine.yaml")).unwrap()
        );
        assert_eq!(suite.scenes[0].scene, "house:3");
        assert_eq!(suite.scenes[0].placement, Placement::default());
        let room = &suite.scenes[1];
        assert_eq!(
            room.scene,
            std::fs::canonicalize(dir.path().join("room.glb"))
                .unwrap()
                .display()
                .to_string()
        );
        assert_eq!(room.placement.up_axis, Some(UpAxis::NegY));
        assert_eq!(room.placement.floor, Floor::Auto);
        let t = room.placement.transform.unwrap();
        assert_eq!(
            (t.scale, t.rotate_deg),
            (Some(0.01), Some([0.0, 0.0, 90.0]))
        );
        assert_eq!(suite.seeds, [1, 2]);
        let s = &suite.settings;
        assert_eq!((s.steps, s.resolution, s.eval_views), (300, 96, 20));
        assert_eq!((s.max_rooms, s.max_area), (Some(4), Some(80.0)));
        assert_eq!((s.hfov_deg, s.camera_height_m), (Some(79.0), Some(1.25)));
        assert_eq!(s.noise.as_deref(), Some("realistic"));
        assert_eq!(s.when_no_frontier.as_deref(), Some("refine"), "the default");
        assert!(s.checkpoints.is_empty(), "none unless asked for");
        assert_eq!(s.llm, None, "none unless asked for");
        let llm = VALID.replace(
            "eval_views: 20",
            "eval_views: 20\nllm: { provider: { kind: ollama, base_url: \"http://127.0.0.1:1\", model: m } }",
        );
        let keys = parse(dir.path(), &llm).unwrap().settings.llm.unwrap();
        assert_eq!(keys["provider"]["model"], "m");
        let scalar = VALID.replace("eval_views: 20", "eval_views: 20\nllm: ollama");
        let e = parse(dir.path(), &scalar).unwrap_err().to_string();
        assert!(e.contains("`llm` must be a mapping"), "{e}");
        let with = VALID.replace("eval_views: 20", "eval_views: 20\ncheckpoints: [100, 200]");
        let checked = parse(dir.path(), &with).unwrap().settings;
        assert_eq!(checked.checkpoints, [100, 200]);
        let at_end = VALID.replace("eval_views: 20", "eval_views: 20\ncheckpoints: [100, 300]");
        let e = parse(dir.path(), &at_end).unwrap_err().to_string();
        assert!(
            e.contains("checkpoint 300 is not before the last step (300)"),
            "{e}"
        );
        let cells = suite.cells();
        assert_eq!(cells.len(), 2 * 2 * 2);
        assert_eq!(cells[2].placement, room.placement);
        assert_eq!((cells[2].method.name.as_str(), cells[2].seed), ("fbe", 1));
        assert_eq!(cells[7].settings, suite.settings);
        // `end` can be asked for, and the camera's keys are each optional.
        let other = VALID
            .replace("eval_views: 20", "eval_views: 20\nwhen_no_frontier: end")
            .replace(
                "camera: { resolution: 96, hfov_deg: 79, height_m: 1.25 }",
                "camera: {}",
            );
        let s = parse(dir.path(), &other).unwrap().settings;
        assert_eq!(s.when_no_frontier.as_deref(), Some("end"));
        assert_eq!(
            (s.resolution, s.hfov_deg, s.camera_height_m),
            (160, None, None)
        );
    }

    /// Each broken suite is refused with `s.yaml:LINE:COL: error:` at the offending token and
    /// the key or value named.
    #[test]
    fn malformed_suites_name_the_place_and_the_key() {
        let dir = folder();
        // (replace, with, line, token whose column is expected, message fragment)
        let cases = [
            (
                "steps: 300",
                "stpes: 300",
                11,
                "stpes",
                "unknown suite key `stpes`",
            ),
            (
                "steps: 300",
                "steps: -3",
                11,
                "-3",
                "`steps` must be an integer ≥ 1, got `-3`",
            ),
            (
                "steps: 300",
                "steps: \"300\"",
                11,
                "\"300\"",
                "`steps` must be an integer",
            ),
            (
                "    floor: auto",
                "    flor: auto",
                7,
                "flor",
                "unknown scene key `flor`",
            ),
            ("up_axis: -y", "up_axis: w", 6, "w", "bad `up_axis`"),
            (
                "{ scale: 0.01",
                "{ scal: 0.01",
                8,
                "{ scal",
                "bad `transform`: unknown field `scal`",
            ),
            (
                "methods: [fbe,",
                "methods: [gpt,",
                2,
                "gpt",
                "method `gpt`: not a known method",
            ),
            (
                "name: mine,",
                "name: \"my run\",",
                2,
                "\"my run\"",
                "method name `my run`",
            ),
            (
                "hfov_deg: 79",
                "hfov_deg: 200",
                12,
                "200",
                "`hfov_deg` must be an angle in (1, 179)",
            ),
            (
                "height_m: 1.25",
                "height_m: -1",
                12,
                "-1",
                "`height_m`: robot model: camera_height_m",
            ),
            (
                "resolution: 96,",
                "resolution: 96, size: 3,",
                12,
                "size",
                "unknown camera key `size`",
            ),
            ("noise: realistic", "noise: loud", 13, "loud", "bad `noise`"),
            (
                "  - house:3",
                "  - { scene: house:3, floor: auto }",
                4,
                "floor",
                "`floor` places a scene file",
            ),
            (
                "  - house:3",
                "  - house:x",
                4,
                "house:x",
                "scene = house:x",
            ),
            (
                "room.glb",
                "nope.glb",
                5,
                "nope.glb",
                "`scene`: no such file",
            ),
            (
                "seeds: [1, 2]",
                "seeds: [1, 1]",
                10,
                "1]",
                "seed 1 is listed twice",
            ),
            (
                "seeds: [1, 2]",
                "seeds: []",
                10,
                "[]",
                "`seeds` must be a non-empty list",
            ),
            (
                "max_rooms: 4",
                "max_rooms: 0",
                9,
                "0,",
                "`max_rooms` must be an integer ≥ 1, got `0`",
            ),
            (
                "eval_views: 20",
                "eval_views: 20\ncheckpoints: [10, 5]",
                15,
                "5]",
                "checkpoints must increase: 5 after 10",
            ),
            (
                "  - house:3\n",
                "  - house:3\n  - house:3\n",
                5,
                "house:3",
                "scene `house:3` is listed twice",
            ),
        ];
        for (from, to, line, token, fragment) in cases {
            assert!(VALID.contains(from), "{from}");
            let text = VALID.replacen(from, to, 1);
            let col = text.lines().nth(line - 1).unwrap().find(token).unwrap() + 1;
            let e = parse(dir.path(), &text).unwrap_err().to_string();
            let want = format!("s.yaml:{line}:{col}: error: ");
            let hit = e.lines().find(|l| l.contains(fragment));
            assert!(
                hit.is_some_and(|l| l.starts_with(&want)),
                "{to}: want `{want}…{fragment}`, got:\n{e}"
            );
        }
        // A missing key is named, at the top of the file; a syntax error has its place.
        let e = parse(dir.path(), &VALID.replace("steps: 300\n", ""))
            .unwrap_err()
            .to_string();
        assert!(e.contains("s.yaml:1:1: error: missing key `steps`"), "{e}");
        let e = parse(dir.path(), &VALID.replace("seeds: [1, 2]", "seeds: [1, 2"))
            .unwrap_err()
            .to_string();
        assert!(e.starts_with("s.yaml:") && e.contains(": error: "), "{e}");
        let e = Suite::load(&dir.path().join("absent.yaml"), &root())
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("absent.yaml: error: cannot read the suite"),
            "{e}"
        );
    }

    /// A method's `set:` keeps its overrides in order; one without `=`, or naming a node its
    /// dataflow lacks, is refused at its own line and column.
    #[test]
    fn a_methods_set_overrides_are_kept_and_checked_where_written() {
        let dir = folder();
        std::fs::write(
            dir.path().join("flows/mine.yaml"),
            "nodes:\n  - id: planner\n    operator: planner\n    config: { policy: fbe }\n",
        )
        .unwrap();
        let methods = |set: &str| {
            VALID.replace(
                "methods: [fbe, { name: mine, dataflow: flows/mine.yaml }]",
                &format!(
                    "methods:\n  - fbe\n  - name: mine\n    dataflow: flows/mine.yaml\n    set: {set}"
                ),
            )
        };
        let suite = parse(
            dir.path(),
            &methods("[planner.frontier=utility, \"planner.strikes={ max: 3 }\"]"),
        )
        .unwrap();
        assert!(suite.methods[0].set.is_empty());
        assert_eq!(
            suite.methods[1].set,
            ["planner.frontier=utility", "planner.strikes={ max: 3 }"]
        );
        let e = parse(dir.path(), &methods("[planner.frontier]"))
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("s.yaml:6:11: error:") && e.contains("no `=`"),
            "{e}"
        );
        let e = parse(
            dir.path(),
            &methods("[planner.frontier=utility, scorer.mode=fisher]"),
        )
        .unwrap_err()
        .to_string();
        assert!(
            e.contains("s.yaml:6:37: error:") && e.contains("no node `scorer` (nodes: planner)"),
            "{e}"
        );
        let e = parse(dir.path(), &methods("planner.frontier=utility"))
            .unwrap_err()
            .to_string();
        assert!(e.contains("`set` must be a non-empty list"), "{e}");
    }

    /// The shipped suites parse; the furnished house of `table1.yaml` lives in the shared data
    /// next to the checkout, so that suite is skipped (with a message) where it is absent.
    #[test]
    fn shipped_suites_parse() {
        let smoke = Suite::load(&root().join("benchmarks/smoke.yaml"), &root()).unwrap();
        let names: Vec<&str> = smoke.methods.iter().map(|m| m.name.as_str()).collect();
        assert_eq!(names, ["fbe", "fisher"]);
        assert_eq!((smoke.scenes.len(), smoke.seeds.len()), (1, 1));
        assert_eq!(smoke.settings.when_no_frontier.as_deref(), Some("refine"));
        let large = Suite::load(&root().join("benchmarks/large.yaml"), &root()).unwrap();
        assert_eq!(large.scenes.len(), 4);
        let graph = Suite::load(&root().join("benchmarks/pose-graph.yaml"), &root()).unwrap();
        assert_eq!(graph.methods[1].name, "fisher_pose_graph");
        assert_eq!(graph.settings.noise.as_deref(), Some("realistic"));
        assert_eq!(large.settings.checkpoints, [500, 1000]);
        let goal = Suite::load(&root().join("benchmarks/goal-choice.yaml"), &root()).unwrap();
        let variant = &goal.methods[2];
        assert_eq!(variant.name, "fisher_utility");
        assert!(variant.dataflow.ends_with("flows/fisher.yaml"));
        assert_eq!(variant.set, ["planner.frontier=utility"]);
        let house = root().join("../shared/data/scenes/aws_small_house.glb");
        // Every other shipped suite parses too (those on the furnished house where it exists).
        for entry in std::fs::read_dir(root().join("benchmarks")).unwrap() {
            let path = entry.unwrap().path();
            if path.extension().is_some_and(|e| e == "yaml") {
                match Suite::load(&path, &root()) {
                    Ok(_) => {}
                    Err(e) if !house.is_file() && e.to_string().contains("aws_small_house") => {}
                    Err(e) => panic!("{e}"),
                }
            }
        }
        if !house.is_file() {
            eprintln!("skipped table1.yaml: {} absent", house.display());
            return;
        }
        let table1 = Suite::load(&root().join("benchmarks/table1.yaml"), &root()).unwrap();
        let names: Vec<&str> = table1.methods.iter().map(|m| m.name.as_str()).collect();
        assert_eq!(names, ["fbe", "fisher_eig_only", "fisher", "llm"]);
        assert!(table1.scenes.len() >= 6 && table1.seeds == [1, 2, 3]);
        assert_eq!(table1.settings.steps, 2000);
        assert_eq!(table1.settings.camera_height_m, Some(1.25));
        assert_eq!(table1.settings.noise.as_deref(), Some("realistic"));
        assert_eq!(table1.settings.checkpoints, [500, 1000]);
        assert!(
            table1
                .scenes
                .iter()
                .any(|s| s.scene.ends_with("aws_small_house.glb"))
        );
    }
}
