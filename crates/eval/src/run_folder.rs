//! The run folder as one typed contract: every file of a run folder, its name and its format,
//! read and written through [`RunFolder`] and nowhere else.
//!
//! | file | written by | format |
//! | --- | --- | --- |
//! | `trajectory_est.tum`, `trajectory_true.tum` | `evaluator` node | TUM (map frame = the robot's start frame; world) |
//! | `map.ply` | `evaluator` node | 3DGS PLY of the last map, map frame |
//! | `bev.png` | `evaluator` node | bird's-eye view ([`Bev`], drawn in [`crate::bev`]) |
//! | `coverage.csv` | `evaluator` node | [`CoverageRow`]s: `step,coverage` |
//! | `summary.json` | `evaluator` node | [`Summary`] |
//! | `fisher.csv` | `evaluator` node, when the scorer sent any `FisherReport` | [`FisherRow`]s, one per Fisher replan |
//! | `timings.csv` | every node host (`activemap_runtime::node::append_timing`) | [`StageTime`]s: `stage,seconds,calls` |
//! | `recording.mcap` | the launcher's recorder | MCAP |
//! | `dataflow.yaml` | the launcher | the flow that ran |
//! | `metrics.json`, `metrics.md` | `activemap eval` | [`MetricsReport`] |
//! | `eval/views.csv`, `eval/view_NN_{map,truth}.png` | `activemap eval` | [`ViewRow`]s; test renders |
//! | `eval/test_poses.csv` | `activemap eval` | [`TestPoseRow`]s: where each test view was taken |
//! | `llm.jsonl`, `llm/bev_NNNN_step_K.png` | the evaluator, from the LLM planner's `llm` | [`LlmRecord`] per line; the BEV of each query |
//! | `report.html` | `activemap report` | the self-contained page |
//!
//! JSON files are (de)serialised by serde into typed structs; CSV files by the `csv` crate with
//! serde into typed rows (numbers with 6 decimals, as before). Every error names the file and,
//! for a CSV row, its line.

use crate::MetricsReport;
use crate::bev::Bev;
use crate::validity::RunWarning;
use activemap_geometry::RobotModel;
use activemap_geometry::tum::Trajectory;
use activemap_splat::DepthModel;
use serde::de::DeserializeOwned;
use serde::{Deserialize, Serialize, Serializer};
use std::path::{Path, PathBuf};

/// A run folder: the directory one `activemap run` writes, with the name and format of each of
/// its files. Cheap to build; touches the disk only in its `read_*` / `write_*` methods.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct RunFolder {
    dir: PathBuf,
}

impl RunFolder {
    /// Estimated trajectory (TUM, map frame).
    pub const TRAJECTORY_EST: &'static str = "trajectory_est.tum";
    /// True trajectory (TUM, world frame).
    pub const TRAJECTORY_TRUE: &'static str = "trajectory_true.tum";
    /// With the tracker's pose graph: the estimated trajectory as the graph finally places it
    /// (TUM, map frame; [`crate::CorrectedTrajectory`]). Absent without the graph.
    pub const TRAJECTORY_FINAL: &'static str = "trajectory_final.tum";
    /// Final map (3DGS PLY, map frame, without unknown-space Gaussians).
    pub const MAP: &'static str = "map.ply";
    /// 2D coverage per step ([`CoverageRow`]).
    pub const COVERAGE: &'static str = "coverage.csv";
    /// One [`FisherRow`] per Fisher replan of the scorer, when the run had any.
    pub const FISHER: &'static str = "fisher.csv";
    /// The evaluator's [`Summary`].
    pub const SUMMARY: &'static str = "summary.json";
    /// The launcher's copy of the dataflow.
    pub const DATAFLOW: &'static str = "dataflow.yaml";
    /// Bird's-eye PNG of the last occupancy grid with both trajectories and the frontiers.
    pub const BEV: &'static str = "bev.png";
    /// Metrics written by `activemap eval` ([`MetricsReport`]).
    pub const METRICS_JSON: &'static str = "metrics.json";
    /// The metrics as a Markdown table.
    pub const METRICS_MD: &'static str = "metrics.md";
    /// Folder of the test renders and per-view metrics `activemap eval` keeps for the report.
    pub const EVAL_DIR: &'static str = "eval";
    /// Per-view metrics inside [`Self::EVAL_DIR`] ([`ViewRow`]).
    pub const VIEWS: &'static str = "views.csv";
    /// The test views' camera poses inside [`Self::EVAL_DIR`] ([`TestPoseRow`]).
    pub const TEST_POSES: &'static str = "test_poses.csv";
    /// Per-stage time breakdown ([`StageTime`]), when the run records it.
    pub const TIMINGS: &'static str = "timings.csv";
    /// LLM exchanges, one [`LlmRecord`] per line, when the run had any.
    pub const LLM: &'static str = "llm.jsonl";
    /// The BEV image of every LLM query (`bev_NNNN_step_K.png`).
    pub const LLM_DIR: &'static str = "llm";
    /// The report page.
    pub const REPORT: &'static str = "report.html";
    /// The recording of every message of the run.
    pub const RECORDING: &'static str = "recording.mcap";

    /// Folder of the checkpoints: `checkpoints/step_NNNNNN/`, each a run folder of its own
    /// holding the run's results as they stood after that many steps (the `evaluator` node's
    /// `checkpoints`), evaluated by `activemap eval` like the run itself.
    pub const CHECKPOINTS_DIR: &'static str = "checkpoints";

    /// The run folder at `dir` (not created).
    pub fn new(dir: impl Into<PathBuf>) -> Self {
        Self { dir: dir.into() }
    }

    /// The checkpoint of this run after `step` steps (not created).
    pub fn checkpoint(&self, step: u64) -> RunFolder {
        RunFolder::new(
            self.dir
                .join(Self::CHECKPOINTS_DIR)
                .join(format!("step_{step:06}")),
        )
    }

    /// The checkpoints this run holds, by step (empty without a checkpoints folder). Entries
    /// not named `step_N` are an error naming them.
    pub fn checkpoints(&self) -> Result<Vec<(u64, RunFolder)>, RunError> {
        let dir = self.dir.join(Self::CHECKPOINTS_DIR);
        let entries = match std::fs::read_dir(&dir) {
            Ok(entries) => entries,
            Err(e) if e.kind() == std::io::ErrorKind::NotFound => return Ok(Vec::new()),
            Err(source) => return Err(RunError::Io { path: dir, source }),
        };
        let mut out = Vec::new();
        for entry in entries {
            let entry = entry.map_err(|source| RunError::Io {
                path: dir.clone(),
                source,
            })?;
            let name = entry.file_name().to_string_lossy().into_owned();
            let step = name
                .strip_prefix("step_")
                .and_then(|n| n.parse::<u64>().ok())
                .ok_or_else(|| RunError::Malformed {
                    path: entry.path(),
                    detail: "a checkpoint folder is named `step_N` (N the step count)".into(),
                })?;
            out.push((step, RunFolder::new(entry.path())));
        }
        out.sort_by_key(|(step, _)| *step);
        Ok(out)
    }

    /// The folder itself.
    pub fn dir(&self) -> &Path {
        &self.dir
    }

    /// The path of file `name` of the folder (one of the constants).
    pub fn path(&self, name: &str) -> PathBuf {
        self.dir.join(name)
    }

    /// Creates the folder (and its parents) when absent.
    pub fn create(&self) -> Result<(), RunError> {
        std::fs::create_dir_all(&self.dir).map_err(|source| RunError::Io {
            path: self.dir.clone(),
            source,
        })
    }

    /// Whether the run left a `summary.json` (it had an `evaluator` node and it finished).
    pub fn has_summary(&self) -> bool {
        self.path(Self::SUMMARY).exists()
    }

    /// Whether the run was recorded (`recording.mcap` is there).
    pub fn has_recording(&self) -> bool {
        self.path(Self::RECORDING).exists()
    }

    /// The folder of `activemap eval`'s per-view outputs.
    pub fn eval_dir(&self) -> PathBuf {
        self.path(Self::EVAL_DIR)
    }

    /// `eval/views.csv`.
    pub fn views_path(&self) -> PathBuf {
        self.eval_dir().join(Self::VIEWS)
    }

    /// `eval/view_NN_{map,truth,depth_classes}.png` of test view `index`.
    pub fn view_image(&self, index: usize, image: ViewImage) -> PathBuf {
        self.eval_dir()
            .join(format!("view_{index:02}_{}.png", image.suffix()))
    }

    /// `eval/worst_RR_view_NNNN_{map,truth,depth_classes}.png`: the test view `index` (its row
    /// in `eval/views.csv` and `eval/test_poses.csv`), `rank`-th worst by depth MAE (0 = worst).
    pub fn worst_view_image(&self, rank: usize, index: usize, image: ViewImage) -> PathBuf {
        self.eval_dir().join(format!(
            "worst_{rank:02}_view_{index:04}_{}.png",
            image.suffix()
        ))
    }

    /// Reads `summary.json`; a file that is not a JSON object of summary fields is
    /// [`RunError::Malformed`].
    pub fn read_summary(&self) -> Result<Summary, RunError> {
        let path = self.path(Self::SUMMARY);
        let text = read_text(&path, "the evaluator's summary")?;
        // serde would also read a struct from a JSON array; the file holds an object.
        if !text.trim_start().starts_with('{') {
            return Err(RunError::Malformed {
                path,
                detail: "expected a JSON object".into(),
            });
        }
        serde_json::from_str(&text).map_err(|e| RunError::Malformed {
            path,
            detail: e.to_string(),
        })
    }

    /// Writes `summary.json` (pretty JSON), with `"valid"` first ([`Summary::is_valid`]; derived
    /// from the warnings, ignored when read back).
    pub fn write_summary(&self, summary: &Summary) -> Result<(), RunError> {
        #[derive(Serialize)]
        struct Written<'a> {
            valid: bool,
            #[serde(flatten)]
            summary: &'a Summary,
        }
        let written = Written {
            valid: summary.is_valid(),
            summary,
        };
        let text = serde_json::to_string_pretty(&written).map_err(|e| RunError::Malformed {
            path: self.path(Self::SUMMARY),
            detail: e.to_string(),
        })?;
        write_file(&self.path(Self::SUMMARY), text)
    }

    /// Reads the TUM trajectory `name` ([`Self::TRAJECTORY_EST`] or [`Self::TRAJECTORY_TRUE`]);
    /// empty files are refused.
    pub fn read_trajectory(&self, name: &str) -> Result<Trajectory, RunError> {
        let path = self.path(name);
        let text = read_text(&path, "TUM trajectory `t tx ty tz qx qy qz qw`")?;
        let trajectory = Trajectory::parse(&text, &path.display().to_string()).map_err(|e| {
            RunError::Malformed {
                path: path.clone(),
                detail: e.to_string(),
            }
        })?;
        if trajectory.is_empty() {
            return Err(RunError::Malformed {
                path,
                detail: "the trajectory holds no pose".into(),
            });
        }
        Ok(trajectory)
    }

    /// Writes the TUM trajectory `name`.
    pub fn write_trajectory(&self, name: &str, trajectory: &Trajectory) -> Result<(), RunError> {
        let path = self.path(name);
        trajectory
            .write(&path)
            .map_err(|source| RunError::Io { path, source })
    }

    /// Reads `map.ply` (every Gaussian; the PLY layout stores no flags, see the crate docs of
    /// `activemap-splat`).
    pub fn read_map(&self) -> Result<activemap_splat::Gaussians<f32>, RunError> {
        let path = self.path(Self::MAP);
        if !path.exists() {
            return Err(RunError::Missing {
                path,
                what: "3DGS PLY of the final map",
            });
        }
        activemap_splat::ply::read_ply(&path).map_err(|e| RunError::Malformed {
            path,
            detail: e.to_string(),
        })
    }

    /// Writes `map.ply` (the caller leaves out what must not be shown as a surface).
    pub fn write_map(&self, map: &activemap_splat::Gaussians<f32>) -> Result<(), RunError> {
        let path = self.path(Self::MAP);
        activemap_splat::ply::write_ply(&path, map).map_err(|e| RunError::Io {
            path,
            source: std::io::Error::other(e.to_string()),
        })
    }

    /// Reads `coverage.csv`; `None` when the file is absent. Every coverage must lie in [0, 1].
    pub fn read_coverage(&self) -> Result<Option<Vec<CoverageRow>>, RunError> {
        let path = self.path(Self::COVERAGE);
        let Some(rows) = read_rows::<CoverageRow>(&path, "2D coverage per step")? else {
            return Ok(None);
        };
        for (line, row) in &rows {
            if !(0.0..=1.0).contains(&row.coverage) {
                return Err(RunError::MalformedRow {
                    path,
                    line: *line,
                    detail: format!("coverage {} is outside [0, 1]", row.coverage),
                });
            }
        }
        Ok(Some(rows.into_iter().map(|(_, r)| r).collect()))
    }

    /// Writes `coverage.csv` (header even when there is no row).
    pub fn write_coverage(&self, rows: &[CoverageRow]) -> Result<(), RunError> {
        write_rows(&self.path(Self::COVERAGE), rows)
    }

    /// Reads `timings.csv` as written, one row per node process (a restarted node has several:
    /// see [`StageTime::summed`]); `None` when the run recorded no timings. Times must be finite
    /// and non-negative.
    pub fn read_timings(&self) -> Result<Option<Vec<StageTime>>, RunError> {
        let path = self.path(Self::TIMINGS);
        let Some(rows) = read_rows::<StageTime>(&path, "per-stage times")? else {
            return Ok(None);
        };
        for (line, row) in &rows {
            if !(row.seconds.is_finite() && row.seconds >= 0.0) {
                return Err(RunError::MalformedRow {
                    path,
                    line: *line,
                    detail: format!("seconds {} must be finite and ≥ 0", row.seconds),
                });
            }
        }
        Ok(Some(rows.into_iter().map(|(_, r)| r).collect()))
    }

    /// Writes `timings.csv` whole (the node hosts append to it themselves; this is for tools
    /// and fixtures).
    pub fn write_timings(&self, rows: &[StageTime]) -> Result<(), RunError> {
        write_rows(&self.path(Self::TIMINGS), rows)
    }

    /// Reads `fisher.csv`; `None` when the run made no Fisher replan. Each row must hold
    /// together ([`FisherRow::check`]); the first that does not is named by its line.
    pub fn read_fisher(&self) -> Result<Option<Vec<FisherRow>>, RunError> {
        let path = self.path(Self::FISHER);
        let Some(rows) = read_rows::<FisherRow>(&path, "Fisher replans")? else {
            return Ok(None);
        };
        for (line, row) in &rows {
            row.check().map_err(|detail| RunError::MalformedRow {
                path: path.clone(),
                line: *line,
                detail,
            })?;
        }
        Ok(Some(rows.into_iter().map(|(_, r)| r).collect()))
    }

    /// Writes `fisher.csv` (header even when there is no row).
    pub fn write_fisher(&self, rows: &[FisherRow]) -> Result<(), RunError> {
        write_rows(&self.path(Self::FISHER), rows)
    }

    /// Reads `eval/views.csv`; `None` when absent.
    pub fn read_views(&self) -> Result<Option<Vec<ViewRow>>, RunError> {
        let rows = read_rows::<ViewRow>(&self.views_path(), "per-view metrics")?;
        Ok(rows.map(|rows| rows.into_iter().map(|(_, r)| r).collect()))
    }

    /// Writes `eval/views.csv` (the `eval` folder must exist).
    pub fn write_views(&self, rows: &[ViewRow]) -> Result<(), RunError> {
        write_rows(&self.views_path(), rows)
    }

    /// Reads `eval/test_poses.csv`; `None` when absent (runs evaluated before it existed).
    pub fn read_test_poses(&self) -> Result<Option<Vec<TestPoseRow>>, RunError> {
        let path = self.eval_dir().join(Self::TEST_POSES);
        let rows = read_rows::<TestPoseRow>(&path, "test view poses")?;
        Ok(rows.map(|rows| rows.into_iter().map(|(_, r)| r).collect()))
    }

    /// Writes `eval/test_poses.csv` (the `eval` folder must exist).
    pub fn write_test_poses(&self, rows: &[TestPoseRow]) -> Result<(), RunError> {
        write_rows(&self.eval_dir().join(Self::TEST_POSES), rows)
    }

    /// Reads `metrics.json`; `None` when `activemap eval` has not written it.
    pub fn read_metrics(&self) -> Result<Option<MetricsReport>, RunError> {
        let path = self.path(Self::METRICS_JSON);
        let text = match read_text(&path, "metrics of `activemap eval`") {
            Ok(t) => t,
            Err(RunError::Missing { .. }) => return Ok(None),
            Err(e) => return Err(e),
        };
        MetricsReport::from_json(&text)
            .map(Some)
            .map_err(|e| RunError::Malformed {
                path,
                detail: e.to_string(),
            })
    }

    /// Writes `metrics.json` and its Markdown rendering `metrics.md`.
    pub fn write_metrics(&self, report: &MetricsReport, markdown: &str) -> Result<(), RunError> {
        write_file(&self.path(Self::METRICS_JSON), report.to_json())?;
        write_file(&self.path(Self::METRICS_MD), markdown)
    }

    /// Appends one record to `llm.jsonl` (one JSON object per line), creating it.
    pub fn append_llm(&self, record: &LlmRecord) -> Result<(), RunError> {
        use std::io::Write;
        let path = self.path(Self::LLM);
        let line = serde_json::to_string(record).map_err(|e| RunError::Malformed {
            path: path.clone(),
            detail: e.to_string(),
        })?;
        let mut file = std::fs::OpenOptions::new()
            .create(true)
            .append(true)
            .open(&path)
            .map_err(|e| RunError::Io {
                path: path.clone(),
                source: e,
            })?;
        writeln!(file, "{line}").map_err(|e| RunError::Io {
            path: path.clone(),
            source: e,
        })
    }

    /// Writes the BEV PNG of LLM query `index` (decision at `step`) under `llm/`; returns
    /// its path relative to the folder, as [`LlmRecord::bev`] holds it.
    pub fn write_llm_bev(&self, index: usize, step: u64, png: &[u8]) -> Result<String, RunError> {
        let dir = self.path(Self::LLM_DIR);
        std::fs::create_dir_all(&dir).map_err(|e| RunError::Io {
            path: dir.clone(),
            source: e,
        })?;
        let name = format!("{}/bev_{index:04}_step_{step}.png", Self::LLM_DIR);
        let path = self.path(&name);
        std::fs::write(&path, png).map_err(|e| RunError::Io {
            path: path.clone(),
            source: e,
        })?;
        Ok(name)
    }

    /// Reads `llm.jsonl`; `None` when the run made no LLM exchange. Blank lines are skipped.
    pub fn read_llm(&self) -> Result<Option<Vec<LlmRecord>>, RunError> {
        let path = self.path(Self::LLM);
        let text = match read_text(&path, "LLM exchanges") {
            Ok(t) => t,
            Err(RunError::Missing { .. }) => return Ok(None),
            Err(e) => return Err(e),
        };
        let mut records = Vec::new();
        for (n, line) in text.lines().enumerate() {
            if line.trim().is_empty() {
                continue;
            }
            records.push(
                serde_json::from_str(line).map_err(|e| RunError::MalformedRow {
                    path: path.clone(),
                    line: n as u64 + 1,
                    detail: e.to_string(),
                })?,
            );
        }
        Ok(Some(records))
    }

    /// Draws `bev` and writes it as `bev.png`.
    pub fn write_bev(&self, bev: &Bev) -> Result<(), RunError> {
        let path = self.path(Self::BEV);
        let image = bev.render().map_err(RunError::Settings)?;
        image.save(&path).map_err(|e| RunError::Io {
            path,
            source: std::io::Error::other(e.to_string()),
        })
    }

    /// The bytes of the file at `path` (e.g. a PNG of the folder to inline); `None` when absent.
    pub fn read_optional_bytes(&self, path: &Path) -> Result<Option<Vec<u8>>, RunError> {
        match std::fs::read(path) {
            Ok(bytes) => Ok(Some(bytes)),
            Err(e) if e.kind() == std::io::ErrorKind::NotFound => Ok(None),
            Err(source) => Err(RunError::Io {
                path: path.to_path_buf(),
                source,
            }),
        }
    }

    /// Writes `report.html`; returns its path.
    pub fn write_report(&self, html: &str) -> Result<PathBuf, RunError> {
        let path = self.path(Self::REPORT);
        write_file(&path, html)?;
        Ok(path)
    }
}

/// Which image of a test view.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ViewImage {
    /// The render of the run's map.
    Map,
    /// The simulator's ground truth.
    Truth,
    /// Each pixel coloured by where its depth error comes from
    /// ([`crate::DepthErrorClass::colour`]).
    DepthClasses,
}

impl ViewImage {
    /// The end of the image's file name.
    fn suffix(self) -> &'static str {
        match self {
            ViewImage::Map => "map",
            ViewImage::Truth => "truth",
            ViewImage::DepthClasses => "depth_classes",
        }
    }
}

/// `summary.json`: what the `evaluator` node measured, and the scene so `activemap eval` can
/// rebuild it. Fields absent from an older or partial summary read as their defaults
/// (`Option`s as `None`); unknown fields are ignored.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
#[serde(default)]
pub struct Summary {
    /// Pose estimates received.
    pub steps: u64,
    /// Final 2D coverage in [0, 1] (`None`: not recorded).
    pub coverage: Option<f64>,
    /// RMSE ATE after SE(3) alignment, metres (None with fewer than 3 poses), of the online
    /// estimates (each as the tracker published it at its step).
    pub ate_m: Option<f64>,
    /// With the tracker's pose graph: the same ATE of the final trajectory, every estimate
    /// moved by the graph's later corrections (`trajectory_final.tum`); `None` without the
    /// graph (absent in older summaries).
    pub ate_final_m: Option<f64>,
    /// Length of the true path, metres.
    pub path_length_m: f64,
    /// Forward actions whose result the true poses show (0 when the `action` input is not
    /// connected).
    pub forward_actions: u64,
    /// Of those, the ones that moved the robot less than half a step.
    pub blocked_forwards: u64,
    /// Last episode status message.
    pub episode: String,
    /// Whether `recording.mcap` was in the output folder when the evaluator finished.
    pub recording_present: bool,
    /// Gaussians in the last map.
    pub map_gaussians: usize,
    /// The scene the run explored (`house:<seed>` or a file); `None`: not recorded (the
    /// evaluation then reads it from `dataflow.yaml`).
    pub scene: Option<String>,
    /// As in the `sim` config.
    pub max_rooms: Option<u32>,
    /// As in the `sim` config.
    pub max_area: Option<f64>,
    /// As in the `sim` config: `x`, `-x`, `y`, `-y`, `z` or `-z` (absent = the scene format's
    /// default).
    pub up_axis: Option<String>,
    /// As in the `sim` config: the scene file's scale, rotation and translation after its up
    /// axis (absent = none, as in older summaries).
    pub transform: Option<activemap_sim::Transform>,
    /// As in the `sim` config: the floor setting of a scene file, `auto` or a height (absent =
    /// `none`, as in older summaries).
    pub floor: Option<activemap_sim::Floor>,
    /// The robot the run used (camera height, radius, step and turn sizes), as the `sim` and
    /// `evaluator` nodes' `robot` config; `None` (older runs): the default robot.
    pub robot: Option<RobotModel>,
    /// The LLM planner's totals over the recorded exchanges; `None`: the run made none.
    pub llm: Option<LlmSummary>,
    /// The tracker's reported failures and the jumps of its estimate against the truth
    /// ([`crate::step_metrics::tracking_summary`]); `None` in older summaries.
    pub tracking: Option<TrackingSummary>,
    /// The depth model the run's map was fitted under, so that the evaluation renders it the
    /// same way (the `evaluator` node's `depth_model`, which the flow check ties to the
    /// mapper's and the tracker's); `None` (older runs): [`DepthModel::Centre`], the only one
    /// then.
    pub map_depth_model: Option<DepthModel>,
    /// Why the run is invalid ([`crate::validity`]: a start that sees nothing, a robot that
    /// cannot move, an empty map, no reachable floor); empty = valid. Absent in older summaries
    /// (read as empty). `summary.json` also says `"valid": true|false`.
    pub warnings: Vec<RunWarning>,
}

/// What the tracker reported of its own failures over a run, and what the true poses say of
/// its estimate's jumps (issue 34: tracking never fails silently). A jump is the change, from
/// one frame to the next, of the estimate's position error against the true pose (the
/// estimate taken to the true frame by the first frame's pair); it is *explained* when either
/// frame was reported lost, relocalised or moved by a loop closure.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
#[serde(default)]
pub struct TrackingSummary {
    /// Frames the tracker reported `Lost`.
    pub lost_frames: u64,
    /// Runs of consecutive lost frames (skipped frames neither start nor end one).
    pub lost_runs: u64,
    /// Lost frames by reason (`low_overlap`, `depth_residual`, `colour_residual`,
    /// `motion_mismatch`, `non_finite`), only the reasons that occurred.
    pub lost_by_reason: std::collections::BTreeMap<String, u64>,
    /// Frames whose estimate took a solution the motion check had rejected before.
    pub relocalisations: u64,
    /// Frames whose estimate moved with a loop closure of the pose graph.
    pub loop_closures: u64,
    /// The largest jump of the error between consecutive frames, metres.
    pub max_error_jump_m: f64,
    /// Jumps above [`crate::step_metrics::JUMP_LIMIT_M`] that no reported event explains.
    pub unexplained_jumps: u64,
    /// The largest of those, metres (0 without any).
    pub max_unexplained_jump_m: f64,
    /// The frame that ends each of those jumps, in order (absent in runs evaluated before
    /// this field), so that its log and trajectory can be looked up.
    pub unexplained_jump_frames: Vec<u64>,
}

impl TrackingSummary {
    /// One line for logs and the report.
    pub fn line(&self) -> String {
        let reasons: Vec<String> = self
            .lost_by_reason
            .iter()
            .map(|(reason, n)| format!("{reason} {n}"))
            .collect();
        format!(
            "{} lost frame(s) in {} run(s){}, {} relocalisation(s), {} loop closure(s), largest \
             error jump {:.1} cm, {} jump(s) above {:.0} cm that no tracking event explains",
            self.lost_frames,
            self.lost_runs,
            if reasons.is_empty() {
                String::new()
            } else {
                format!(" ({})", reasons.join(", "))
            },
            self.relocalisations,
            self.loop_closures,
            100.0 * self.max_error_jump_m,
            self.unexplained_jumps,
            100.0 * crate::step_metrics::JUMP_LIMIT_M
        ) + &jump_frames(&self.unexplained_jump_frames)
    }
}

/// ` (frames A, B, …)` naming the first few frames of unexplained jumps; empty without any.
fn jump_frames(frames: &[u64]) -> String {
    const SHOWN: usize = 5;
    if frames.is_empty() {
        return String::new();
    }
    let mut names: Vec<String> = frames.iter().take(SHOWN).map(u64::to_string).collect();
    if frames.len() > SHOWN {
        names.push("…".into());
    }
    format!(" (frames {})", names.join(", "))
}

/// Whether a record's decision differs from the fallback's choice: `None` when it does not say
/// (no decision or no recorded fallback target).
fn differs(r: &LlmRecord) -> Option<bool> {
    Some(r.decision? != r.fallback_target?)
}

impl LlmOutcomes {
    /// The outcomes of `records` on `coverage` (rows in step order); `None` without a decision
    /// whose window of `horizon_steps` closes inside the rows.
    pub fn of(records: &[LlmRecord], coverage: &[CoverageRow], horizon_steps: u64) -> Option<Self> {
        let last = coverage.last()?.step;
        // Coverage at step s: the last row at or before s (0 before the first row).
        let at = |s: u64| {
            let i = coverage.partition_point(|c| c.step <= s);
            if i == 0 {
                0.0
            } else {
                coverage[i - 1].coverage
            }
        };
        let mut out = Self {
            horizon_steps,
            ..Self::default()
        };
        let (mut differed_sum, mut same_sum) = (0.0, 0.0);
        let mut open_until = None;
        for r in records {
            // A stale answer decided nothing; a background answer acted from the step that
            // took it up.
            let (Some(step), Some(differs), None) =
                (r.answered_step.or(r.step), differs(r), &r.stale)
            else {
                continue;
            };
            let end = step + horizon_steps;
            if end > last || open_until.is_some_and(|u| step < u) {
                continue;
            }
            open_until = Some(end);
            let gain = (at(end) - at(step)) * 100.0;
            if differs {
                out.differed += 1;
                differed_sum += gain;
            } else {
                out.same += 1;
                same_sum += gain;
            }
        }
        if out.differed + out.same == 0 {
            return None;
        }
        out.differed_gain_pp = (out.differed > 0).then(|| differed_sum / out.differed as f64);
        out.same_gain_pp = (out.same > 0).then(|| same_sum / out.same as f64);
        Some(out)
    }
}

/// The LLM planner's totals in `summary.json` (SPEC §7), over its recorded exchanges.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
#[serde(default)]
pub struct LlmSummary {
    /// Queries (exchanges recorded).
    pub queries: u64,
    /// HTTP attempts, retries included.
    pub calls: u64,
    /// Queries whose decision fell back to the largest frontier.
    pub fallbacks: u64,
    /// Fallbacks by failure kind (`timeout`, `no_json`, …).
    pub failures: std::collections::BTreeMap<String, u64>,
    /// Prompt tokens reported.
    pub prompt_tokens: u64,
    /// Completion tokens reported.
    pub completion_tokens: u64,
    /// Model latency summed over the queries, seconds.
    pub latency_s: f64,
    /// First replies cut by the token limit (finish reason `length`).
    pub cut: u64,
    /// Follow-up turns asked (their calls, tokens and latency are in the totals above).
    pub follow_ups: u64,
    /// Follow-up turns that gave a valid answer.
    pub recovered: u64,
    /// Queries the model answered validly (no fallback).
    pub model_decisions: u64,
    /// Answers asked in the background and not applied (too old, their frontier gone, the
    /// episode over first).
    pub stale: u64,
    /// Of those, the ones whose choice differed from the fallback's (the largest frontier;
    /// counted only where the run recorded it): where the model made a difference.
    pub differed: u64,
    /// What the choices led to ([`LlmSummary::of_run`]); `None`: not computed (no
    /// coverage rows, or no decision with a whole window after it).
    pub outcomes: Option<LlmOutcomes>,
}

/// What the LLM planner's decisions led to: the 2D coverage gained in the `horizon_steps`
/// steps after each decision, averaged separately over the decisions where the model's choice
/// differed from the fallback's and over those where the decision equals the fallback's (the
/// model agreed, or the planner fell back). A window starts where the decision acted: at the
/// replan that asked, or for an answer asked in the background at the one that took it up;
/// stale answers (never applied) are left out. Decisions closer than `horizon_steps` to the end
/// of the run are left out (their window is cut), as are decisions made while an earlier one's
/// window is still open, so each gain belongs to one decision.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
#[serde(default)]
pub struct LlmOutcomes {
    /// Steps after a decision over which the gain is measured.
    pub horizon_steps: u64,
    /// Decisions with a whole window where the model's choice differed from the fallback's.
    pub differed: u64,
    /// Their mean coverage gain, percentage points of the reachable floor.
    pub differed_gain_pp: Option<f64>,
    /// Decisions with a whole window that equal the fallback's.
    pub same: u64,
    /// Their mean coverage gain, percentage points.
    pub same_gain_pp: Option<f64>,
}

/// The default window of [`LlmSummary::of_run`] in the evaluator and the report, steps:
/// the order of one path to a frontier at the default step length (5 cm forward, 10° turns).
pub const LLM_OUTCOME_HORIZON_STEPS: u64 = 50;

impl LlmSummary {
    /// The totals of `records`.
    pub fn of(records: &[LlmRecord]) -> Self {
        let mut s = Self::default();
        for r in records {
            s.queries += 1;
            s.calls += u64::from(r.attempts.unwrap_or(0));
            if let Some(kind) = &r.failure {
                s.fallbacks += 1;
                *s.failures.entry(kind.clone()).or_default() += 1;
            }
            s.prompt_tokens += r.prompt_tokens.unwrap_or(0);
            s.completion_tokens += r.completion_tokens.unwrap_or(0);
            s.latency_s += r.latency_ms.unwrap_or(0.0) / 1e3;
            s.cut += u64::from(r.finish_reason.as_deref() == Some("length"));
            if let Some(f) = &r.follow_up {
                s.follow_ups += 1;
                s.recovered += u64::from(r.target.is_some());
                s.calls += u64::from(f.attempts.unwrap_or(0));
                s.prompt_tokens += f.prompt_tokens.unwrap_or(0);
                s.completion_tokens += f.completion_tokens.unwrap_or(0);
                s.latency_s += f.latency_ms.unwrap_or(0.0) / 1e3;
            }
            s.stale += u64::from(r.stale.is_some());
            if r.target.is_some() {
                s.model_decisions += 1;
                s.differed += u64::from(differs(r) == Some(true));
            }
        }
        s
    }

    /// The totals of `records` with [`LlmSummary::outcomes`] measured on the run's `coverage`
    /// rows (step order) over windows of `horizon_steps` steps.
    pub fn of_run(records: &[LlmRecord], coverage: &[CoverageRow], horizon_steps: u64) -> Self {
        Self {
            outcomes: LlmOutcomes::of(records, coverage, horizon_steps),
            ..Self::of(records)
        }
    }

    /// One line for the report's summary table.
    pub fn line(&self) -> String {
        let failures: Vec<String> = self
            .failures
            .iter()
            .map(|(k, n)| format!("{k} {n}"))
            .collect();
        let mut line = format!(
            "{} queries, {} calls, {} fallbacks{}, {} + {} tokens, {:.1} s model latency",
            self.queries,
            self.calls,
            self.fallbacks,
            if failures.is_empty() {
                String::new()
            } else {
                format!(" ({})", failures.join(", "))
            },
            self.prompt_tokens,
            self.completion_tokens,
            self.latency_s
        );
        if self.cut > 0 {
            line += &format!(", {} replies cut (finish reason length)", self.cut);
        }
        if self.follow_ups > 0 {
            line += &format!(
                ", {} follow-ups ({} recovered)",
                self.follow_ups, self.recovered
            );
        }
        if self.model_decisions > 0 {
            line += &format!(
                "; the model decided {} times, {} of them differently from the fallback",
                self.model_decisions, self.differed
            );
        }
        if self.stale > 0 {
            line += &format!(", {} answers not applied (stale)", self.stale);
        }
        if let Some(o) = &self.outcomes {
            let gain = |n: u64, g: Option<f64>| match g {
                Some(g) => format!("{g:+.2} pp over {n}"),
                None => "none".to_string(),
            };
            line += &format!(
                "; coverage gained in the {} steps after a decision: {} where the model differed, \
                 {} where the decision was the fallback's",
                o.horizon_steps,
                gain(o.differed, o.differed_gain_pp),
                gain(o.same, o.same_gain_pp)
            );
        }
        line
    }
}

impl Summary {
    /// Whether the run is valid: no [`Summary::warnings`].
    pub fn is_valid(&self) -> bool {
        self.warnings.is_empty()
    }

    /// `(field, value)` for display (the report's summary table): numbers with 4 decimals,
    /// absent values as `—`.
    pub fn rows(&self) -> Vec<(&'static str, String)> {
        let real = |v: f64| format!("{v:.4}");
        let opt_real = |v: Option<f64>| v.map_or_else(|| "—".to_string(), real);
        let opt = |v: Option<String>| v.unwrap_or_else(|| "—".to_string());
        vec![
            ("steps", self.steps.to_string()),
            ("coverage", opt_real(self.coverage)),
            ("ate_m", opt_real(self.ate_m)),
            ("ate_final_m", opt_real(self.ate_final_m)),
            ("path_length_m", real(self.path_length_m)),
            ("forward_actions", self.forward_actions.to_string()),
            ("blocked_forwards", self.blocked_forwards.to_string()),
            ("episode", self.episode.clone()),
            ("recording_present", self.recording_present.to_string()),
            ("map_gaussians", self.map_gaussians.to_string()),
            ("scene", opt(self.scene.clone())),
            ("max_rooms", opt(self.max_rooms.map(|v| v.to_string()))),
            ("max_area", opt_real(self.max_area)),
            ("up_axis", opt(self.up_axis.clone())),
            ("transform", opt(self.transform.map(|t| t.to_string()))),
            ("floor", opt(self.floor.map(|f| f.to_string()))),
            (
                "robot",
                opt(self.robot.map(|r| {
                    format!(
                        "camera {:.3} m, radius {:.3} m, step {:.3} m, turn {:.2}°",
                        r.camera_height_m,
                        r.radius_m,
                        r.forward_step_m,
                        r.turn_angle_rad.to_degrees()
                    )
                })),
            ),
            ("llm", opt(self.llm.as_ref().map(LlmSummary::line))),
            (
                "tracking",
                opt(self.tracking.as_ref().map(TrackingSummary::line)),
            ),
            (
                "map_depth_model",
                opt(self
                    .map_depth_model
                    .map(|m| format!("{m:?}").to_lowercase())),
            ),
            (
                "valid",
                if self.is_valid() {
                    "yes".to_string()
                } else {
                    let codes: Vec<&str> = self.warnings.iter().map(|w| w.code.as_str()).collect();
                    format!("NO: {}", codes.join(", "))
                },
            ),
        ]
    }
}

/// A row of a run-folder CSV file: its header, in the order of the serde fields.
pub trait CsvRow: Serialize + DeserializeOwned {
    /// The column names, as the file's first line holds them.
    const HEADER: &'static [&'static str];
}

/// A row of `coverage.csv`: 2D coverage after scoring the grid of frame `step`.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct CoverageRow {
    /// Frame id of the scored grid.
    pub step: u64,
    /// Seen / reachable navigable floor, in [0, 1].
    #[serde(serialize_with = "six_decimals")]
    pub coverage: f64,
}

impl CsvRow for CoverageRow {
    const HEADER: &'static [&'static str] = &["step", "coverage"];
}

/// A row of `timings.csv`: one node process's busy time.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct StageTime {
    /// Node id.
    pub stage: String,
    /// Wall seconds inside `on_event`.
    #[serde(serialize_with = "six_decimals")]
    pub seconds: f64,
    /// Calls of `on_event`.
    pub calls: u64,
}

impl CsvRow for StageTime {
    const HEADER: &'static [&'static str] = &["stage", "seconds", "calls"];
}

impl StageTime {
    /// One row per stage, rows of the same stage (a node restarted by its restart policy)
    /// summed, in the order stages first appear.
    pub fn summed(rows: &[StageTime]) -> Vec<StageTime> {
        let mut out: Vec<StageTime> = Vec::new();
        for row in rows {
            match out.iter_mut().find(|s| s.stage == row.stage) {
                Some(s) => {
                    s.seconds += row.seconds;
                    s.calls += row.calls;
                }
                None => out.push(row.clone()),
            }
        }
        out
    }
}

/// A row of `eval/views.csv`: the image metrics of one test view (empty = not computed).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct ViewRow {
    /// Index of the test view.
    pub view: usize,
    /// PSNR, dB (`inf` for identical images).
    #[serde(serialize_with = "six_decimals")]
    pub psnr_db: f64,
    /// SSIM.
    #[serde(serialize_with = "six_decimals")]
    pub ssim: f64,
    /// LPIPS, when its weights were there.
    #[serde(serialize_with = "six_decimals_opt")]
    pub lpips: Option<f64>,
    /// Depth mean absolute error, metres, when the view had valid depth.
    #[serde(serialize_with = "six_decimals_opt")]
    pub depth_mae_m: Option<f64>,
}

impl CsvRow for ViewRow {
    const HEADER: &'static [&'static str] = &["view", "psnr_db", "ssim", "lpips", "depth_mae_m"];
}

/// A row of `eval/test_poses.csv`: where test view `view` (the row of the same index in
/// `eval/views.csv`) was taken, so that a bad view can be found in the scene: the camera's
/// position on the floor in the world frame and its heading.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct TestPoseRow {
    /// Index of the test view.
    pub view: usize,
    /// Camera position, world x, metres.
    #[serde(serialize_with = "six_decimals")]
    pub x_m: f64,
    /// Camera position, world y, metres.
    #[serde(serialize_with = "six_decimals")]
    pub y_m: f64,
    /// Heading of the optical axis from world +x towards +y, degrees in [−180, 180).
    #[serde(serialize_with = "six_decimals")]
    pub yaw_deg: f64,
}

impl CsvRow for TestPoseRow {
    const HEADER: &'static [&'static str] = &["view", "x_m", "y_m", "yaw_deg"];
}

/// A row of `fisher.csv`: what one replan of the scorer in `fisher` mode decided (SPEC §5–§6),
/// from its `FisherReport`. The chosen-path columns are empty when no path was chosen
/// (`chosen` = −1); reals have 6 decimals, `inf` for +∞.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct FisherRow {
    /// Frame id of the replan.
    pub step: u64,
    /// Whether it was a refine replan (no frontier).
    pub refine: bool,
    /// Candidates that survived the free-space test.
    pub candidates: u64,
    /// Paths scored.
    pub paths: u64,
    /// Index of the chosen path, −1 when none was chosen.
    pub chosen: i64,
    /// Objective of the chosen path (finite: a path with +∞ is never chosen).
    #[serde(serialize_with = "six_decimals_opt")]
    pub objective: Option<f64>,
    /// `Σ_i EIG_i` over the scored poses of the chosen path (finite, ≥ 0).
    #[serde(serialize_with = "six_decimals_opt")]
    pub eig_sum: Option<f64>,
    /// EIG of the chosen path's first scored pose (finite, ≥ 0); empty when it scored none.
    #[serde(serialize_with = "six_decimals_opt")]
    pub eig_first: Option<f64>,
    /// `Σ_i C_local(x_i)` of the chosen path; +∞ when a pose of it sees too little (the
    /// `eig_only` objective ignores the term), never NaN or −∞.
    #[serde(serialize_with = "six_decimals_opt")]
    pub c_local_sum: Option<f64>,
    /// Actions of the chosen path's rollout.
    pub actions: Option<u32>,
    /// Wall-clock milliseconds of the whole replan (finite, ≥ 0).
    #[serde(serialize_with = "six_decimals")]
    pub total_ms: f64,
    /// Whether the model Fisher was reused from the previous replan.
    pub model_reused: bool,
    /// Whether the scorer sent its fallback path instead of a Fisher path.
    pub fallback: bool,
}

impl CsvRow for FisherRow {
    const HEADER: &'static [&'static str] = &[
        "step",
        "refine",
        "candidates",
        "paths",
        "chosen",
        "objective",
        "eig_sum",
        "eig_first",
        "c_local_sum",
        "actions",
        "total_ms",
        "model_reused",
        "fallback",
    ];
}

impl FisherRow {
    /// Whether the row holds together: `chosen` in −1..paths, the chosen-path columns
    /// (`objective`, `eig_sum`, `c_local_sum`, `actions`) present exactly when a path was chosen
    /// (`eig_first` may be empty then), finite and non-negative where documented; the reason
    /// when it does not.
    pub fn check(&self) -> Result<(), String> {
        if self.chosen < -1 || (self.chosen >= 0 && self.chosen as u64 >= self.paths) {
            return Err(format!(
                "chosen {} is not −1 or an index of the {} path(s)",
                self.chosen, self.paths
            ));
        }
        let chosen = self.chosen >= 0;
        let present = [
            ("objective", self.objective.is_some()),
            ("eig_sum", self.eig_sum.is_some()),
            ("eig_first", self.eig_first.is_some()),
            ("c_local_sum", self.c_local_sum.is_some()),
            ("actions", self.actions.is_some()),
        ];
        for (name, is_there) in present {
            if is_there && !chosen {
                return Err(format!(
                    "{name} is given but no path was chosen (chosen −1)"
                ));
            }
            if !is_there && chosen && name != "eig_first" {
                return Err(format!(
                    "{name} is empty but path {} was chosen",
                    self.chosen
                ));
            }
        }
        if let Some(v) = self.objective
            && !v.is_finite()
        {
            return Err(format!("objective {v} must be finite"));
        }
        for (name, v) in [("eig_sum", self.eig_sum), ("eig_first", self.eig_first)] {
            if let Some(v) = v
                && !(v.is_finite() && v >= 0.0)
            {
                return Err(format!("{name} {v} must be finite and ≥ 0"));
            }
        }
        if let Some(v) = self.c_local_sum
            && (v.is_nan() || v == f64::NEG_INFINITY)
        {
            return Err(format!("c_local_sum {v} must be a real or +inf"));
        }
        if !(self.total_ms.is_finite() && self.total_ms >= 0.0) {
            return Err(format!("total_ms {} must be finite and ≥ 0", self.total_ms));
        }
        Ok(())
    }
}

/// One line of `llm.jsonl`: an exchange with the LLM planner (absent fields = not recorded).
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
#[serde(default)]
pub struct LlmRecord {
    /// Step the decision was made on.
    pub step: Option<u64>,
    /// System message sent.
    pub system: Option<String>,
    /// User message text sent.
    pub prompt: Option<String>,
    /// The BEV sent, relative to the run folder (`llm/bev_NNNN_step_K.png`).
    pub bev: Option<String>,
    /// `openai`, `ollama`.
    pub provider: Option<String>,
    /// Model asked.
    pub model: Option<String>,
    /// Candidates offered.
    pub candidates: Option<u32>,
    /// Status of the last HTTP attempt.
    pub http_status: Option<u16>,
    /// HTTP attempts.
    pub attempts: Option<u32>,
    /// Model latency, milliseconds.
    pub latency_ms: Option<f64>,
    /// Prompt tokens.
    pub prompt_tokens: Option<u64>,
    /// Completion tokens.
    pub completion_tokens: Option<u64>,
    /// Raw reply.
    pub reply: Option<String>,
    /// Parsed target frontier, if the reply held a valid one.
    pub target: Option<i64>,
    /// The model's reason, if valid.
    pub reason: Option<String>,
    /// The target decided (the model's or the fallback's; −1: refine).
    pub decision: Option<i64>,
    /// The largest frontier's number: what the fallback would have decided without the model
    /// (absent in runs before it was recorded).
    pub fallback_target: Option<i64>,
    /// The step whose replan took the answer up: `step` when the replan waited for it, later
    /// when asked in the background (`ask.mode: background`); absent when never taken up.
    pub answered_step: Option<u64>,
    /// Why a background answer was not applied (too old, its frontier gone, the episode over).
    pub stale: Option<String>,
    /// Failure kind that made the planner fall back, if any.
    pub failure: Option<String>,
    /// What failed.
    pub failure_detail: Option<String>,
    /// Why the model stopped (`stop`, `length`, …).
    pub finish_reason: Option<String>,
    /// The reasoning returned beside the reply (`reasoning_content`, Ollama's `thinking`).
    pub reasoning: Option<String>,
    /// The reply's `<think>` blocks, joined (they stay in `reply` too; never parsed).
    pub thinking: Option<String>,
    /// The server refused the reply's JSON schema and the request went again without.
    pub schema_refused: Option<bool>,
    /// The follow-up turn, when the reply was cut or held no JSON answer.
    pub follow_up: Option<LlmFollowUpRecord>,
}

/// The follow-up turn of an [`LlmRecord`] (absent fields = not recorded).
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
#[serde(default)]
pub struct LlmFollowUpRecord {
    /// Why it was asked (the first reply's failure and finish reason).
    pub cause: Option<String>,
    /// The user message of the turn.
    pub prompt: Option<String>,
    /// Status of the last HTTP attempt.
    pub http_status: Option<u16>,
    /// HTTP attempts.
    pub attempts: Option<u32>,
    /// Model latency, milliseconds.
    pub latency_ms: Option<f64>,
    /// Prompt tokens.
    pub prompt_tokens: Option<u64>,
    /// Completion tokens.
    pub completion_tokens: Option<u64>,
    /// Raw reply.
    pub reply: Option<String>,
    /// Why the model stopped.
    pub finish_reason: Option<String>,
    /// Reasoning returned beside the reply.
    pub reasoning: Option<String>,
    /// The reply's `<think>` blocks, joined.
    pub thinking: Option<String>,
    /// The server refused the JSON schema and the turn went again without.
    pub schema_refused: Option<bool>,
}

/// Why a run folder could not be evaluated or reported.
#[derive(Debug, thiserror::Error)]
pub enum RunError {
    /// A file the evaluation needs is not there.
    #[error("{}: missing ({what})", path.display())]
    Missing {
        /// The file looked for.
        path: PathBuf,
        /// What it should hold.
        what: &'static str,
    },
    /// A file is there but cannot be parsed.
    #[error("{}: malformed: {detail}", path.display())]
    Malformed {
        /// The file.
        path: PathBuf,
        /// What is wrong.
        detail: String,
    },
    /// A line of a CSV or JSON-lines file cannot be parsed.
    #[error("{}: malformed: line {line}: {detail}", path.display())]
    MalformedRow {
        /// The file.
        path: PathBuf,
        /// 1-based line of the file (the header is line 1).
        line: u64,
        /// What is wrong.
        detail: String,
    },
    /// Reading or writing a file failed.
    #[error("{}: {source}", path.display())]
    Io {
        /// The file.
        path: PathBuf,
        /// The OS error.
        source: std::io::Error,
    },
    /// The scene of the run is unknown or cannot be built.
    #[error("scene: {0}")]
    Scene(String),
    /// A setting is invalid (e.g. a benchmark method given as something other than
    /// `NAME=DATAFLOW`, or a bird's-eye scale out of range).
    #[error("{0}")]
    Settings(String),
    /// A metric failed.
    #[error(transparent)]
    Metric(#[from] crate::EvalError),
    /// A render of the map failed.
    #[error("map render: {0}")]
    Render(String),
}

/// Reads a whole text file; a missing file becomes [`RunError::Missing`].
pub fn read_text(path: &Path, what: &'static str) -> Result<String, RunError> {
    match std::fs::read_to_string(path) {
        Ok(t) => Ok(t),
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => Err(RunError::Missing {
            path: path.to_path_buf(),
            what,
        }),
        Err(source) => Err(RunError::Io {
            path: path.to_path_buf(),
            source,
        }),
    }
}

/// Writes a file, naming it on failure.
pub fn write_file(path: &Path, bytes: impl AsRef<[u8]>) -> Result<(), RunError> {
    std::fs::write(path, bytes).map_err(|source| RunError::Io {
        path: path.to_path_buf(),
        source,
    })
}

/// Serialises a real with 6 decimals (the run folder's CSV number format).
fn six_decimals<S: Serializer>(v: &f64, s: S) -> Result<S::Ok, S::Error> {
    s.collect_str(&format_args!("{v:.6}"))
}

/// As [`six_decimals`]; `None` as an empty field.
fn six_decimals_opt<S: Serializer>(v: &Option<f64>, s: S) -> Result<S::Ok, S::Error> {
    match v {
        Some(v) => six_decimals(v, s),
        None => s.serialize_str(""),
    }
}

/// Reads the CSV file `path` of rows `T` with their 1-based line numbers; `None` when the file
/// is absent. The header must be `T::HEADER`; fields are trimmed; blank lines are skipped.
fn read_rows<T: CsvRow>(
    path: &Path,
    what: &'static str,
) -> Result<Option<Vec<(u64, T)>>, RunError> {
    let text = match read_text(path, what) {
        Ok(t) => t,
        Err(RunError::Missing { .. }) => return Ok(None),
        Err(e) => return Err(e),
    };
    let expected = T::HEADER.join(",");
    let row_error = |e: csv::Error, fallback_line: u64| {
        let line = e.position().map_or(fallback_line, |p| p.line());
        let detail = match e.kind() {
            csv::ErrorKind::UnequalLengths { len, .. } => {
                format!("expected `{expected}`, found {len} field(s)")
            }
            csv::ErrorKind::Deserialize { err, .. } => format!("expected `{expected}`: {err}"),
            _ => e.to_string(),
        };
        RunError::MalformedRow {
            path: path.to_path_buf(),
            line,
            detail,
        }
    };
    let mut reader = csv::ReaderBuilder::new()
        .trim(csv::Trim::All)
        .from_reader(text.as_bytes());
    let header = reader.headers().map_err(|e| row_error(e, 1))?;
    if header.iter().ne(T::HEADER.iter().copied()) {
        return Err(RunError::MalformedRow {
            path: path.to_path_buf(),
            line: 1,
            detail: format!(
                "header `{}`, expected `{expected}`",
                header.iter().collect::<Vec<_>>().join(",")
            ),
        });
    }
    let mut rows = Vec::new();
    let mut record = csv::StringRecord::new();
    let header = header.clone();
    loop {
        let fallback = rows.len() as u64 + 2;
        match reader.read_record(&mut record) {
            Ok(false) => break,
            Ok(true) => {}
            Err(e) => return Err(row_error(e, fallback)),
        }
        let line = record.position().map_or(fallback, |p| p.line());
        let row: T = record
            .deserialize(Some(&header))
            .map_err(|e| row_error(e, line))?;
        rows.push((line, row));
    }
    Ok(Some(rows))
}

/// Writes `rows` as the CSV file `path`, header first (also with no row).
fn write_rows<T: CsvRow>(path: &Path, rows: &[T]) -> Result<(), RunError> {
    let io = |e: csv::Error| RunError::Io {
        path: path.to_path_buf(),
        source: std::io::Error::other(e.to_string()),
    };
    let mut writer = csv::WriterBuilder::new()
        .has_headers(false)
        .from_writer(Vec::new());
    writer.write_record(T::HEADER).map_err(io)?;
    for row in rows {
        writer.serialize(row).map_err(io)?;
    }
    let bytes = writer.into_inner().map_err(|e| RunError::Io {
        path: path.to_path_buf(),
        source: std::io::Error::other(e.to_string()),
    })?;
    write_file(path, bytes)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn coverage_rows_are_parsed_and_bad_rows_named() {
        let dir = tempfile::tempdir().unwrap();
        let run = RunFolder::new(dir.path());
        assert!(run.read_coverage().unwrap().is_none());
        let p = run.path(RunFolder::COVERAGE);
        std::fs::write(&p, "step,coverage\n1,0.25\n2,0.5\n").unwrap();
        assert_eq!(
            run.read_coverage().unwrap().unwrap(),
            vec![
                CoverageRow {
                    step: 1,
                    coverage: 0.25
                },
                CoverageRow {
                    step: 2,
                    coverage: 0.5
                }
            ]
        );
        std::fs::write(&p, "step,coverage\n1,0.25\n2;0.5\n").unwrap();
        let e = run.read_coverage().unwrap_err().to_string();
        assert!(e.contains("coverage.csv") && e.contains("line 3"), "{e}");
        std::fs::write(&p, "step,coverage\n1,1.5\n").unwrap();
        let e = run.read_coverage().unwrap_err().to_string();
        assert!(e.contains("outside [0, 1]"), "{e}");
    }

    #[test]
    fn missing_and_malformed_files_are_named() {
        let dir = tempfile::tempdir().unwrap();
        let run = RunFolder::new(dir.path());
        let e = run
            .read_trajectory(RunFolder::TRAJECTORY_EST)
            .unwrap_err()
            .to_string();
        assert!(e.contains("trajectory_est.tum: missing"), "{e}");
        std::fs::write(run.path(RunFolder::TRAJECTORY_EST), "").unwrap();
        let e = run
            .read_trajectory(RunFolder::TRAJECTORY_EST)
            .unwrap_err()
            .to_string();
        assert!(e.contains("no pose"), "{e}");
        std::fs::write(run.path(RunFolder::SUMMARY), "[1, 2]").unwrap();
        let e = run.read_summary().unwrap_err().to_string();
        assert!(e.contains("summary.json: malformed"), "{e}");
        std::fs::write(run.path(RunFolder::MAP), "ply\nnonsense").unwrap();
        let e = run.read_map().unwrap_err().to_string();
        assert!(e.contains("map.ply: malformed"), "{e}");
    }

    fn summary() -> Summary {
        Summary {
            steps: 301,
            coverage: Some(0.875),
            ate_m: Some(0.0021),
            ate_final_m: Some(0.0017),
            path_length_m: 7.25,
            forward_actions: 128,
            blocked_forwards: 2,
            episode: "Finished at step 301: done".into(),
            recording_present: true,
            map_gaussians: 77_000,
            scene: Some("house:7".into()),
            max_rooms: Some(3),
            max_area: None,
            up_axis: Some("z".into()),
            transform: Some(activemap_sim::Transform {
                scale: Some(0.01),
                rotate_deg: Some([0.0, 0.0, 90.0]),
                ..Default::default()
            }),
            floor: Some(activemap_sim::Floor::Auto),
            robot: Some(RobotModel {
                camera_height_m: 1.25,
                ..RobotModel::default()
            }),
            llm: Some(LlmSummary {
                queries: 3,
                calls: 4,
                fallbacks: 1,
                failures: [("timeout".to_string(), 1)].into(),
                prompt_tokens: 2400,
                completion_tokens: 90,
                latency_s: 7.5,
                cut: 1,
                follow_ups: 1,
                recovered: 1,
                model_decisions: 2,
                stale: 0,
                differed: 1,
                outcomes: Some(LlmOutcomes {
                    horizon_steps: 50,
                    differed: 1,
                    differed_gain_pp: Some(4.25),
                    same: 1,
                    same_gain_pp: Some(1.5),
                }),
            }),
            tracking: Some(TrackingSummary {
                lost_frames: 4,
                lost_runs: 2,
                lost_by_reason: [("motion_mismatch".to_string(), 4)].into(),
                relocalisations: 1,
                loop_closures: 0,
                max_error_jump_m: 0.031,
                unexplained_jumps: 2,
                max_unexplained_jump_m: 0.062,
                unexplained_jump_frames: vec![120, 344],
            }),
            map_depth_model: Some(DepthModel::Plane),
            warnings: Vec::new(),
        }
    }

    /// What the LLM decisions led to, on hand-made coverage rows (one every 10 steps, the
    /// coverage rising 1 point per 10 steps, 3 per 10 from step 100 on): the model's choice
    /// at step 100 differs from the fallback's and gains 3 × 5 = 15 points in the 50 steps
    /// after it; the model agreeing at step 20 and the fallback at step 160 gain 5 and 15
    /// points (mean 10); the decision at step 40 (inside step 20's window), the stale answer
    /// at step 150 (never applied; counted, it would have taken step 160's place), the one at
    /// step 200 (its window passes the last row, 240) and a record without a fallback target
    /// (an older run) are left out. Counted as differing: the model's differing choice only.
    #[test]
    fn llm_outcomes_split_the_coverage_gain_by_whether_the_model_differed() {
        let coverage: Vec<CoverageRow> = (0..=24)
            .map(|i| {
                let step = i * 10;
                let points = if step <= 100 {
                    step as f64 / 10.0
                } else {
                    10.0 + 3.0 * (step - 100) as f64 / 10.0
                };
                CoverageRow {
                    step,
                    coverage: points / 100.0,
                }
            })
            .collect();
        let record = |step, target: Option<i64>, decision, fallback_target| LlmRecord {
            step: Some(step),
            target,
            decision: Some(decision),
            fallback_target,
            ..LlmRecord::default()
        };
        let records = [
            record(20, Some(1), 1, Some(1)),
            record(40, Some(3), 3, Some(0)),
            record(100, Some(2), 2, Some(0)),
            LlmRecord {
                stale: Some("frontier 1 of frame 150 is gone".into()),
                ..record(150, Some(1), 1, Some(0))
            },
            record(160, None, 0, Some(0)),
            record(170, Some(4), 4, None),
            record(200, Some(1), 1, Some(0)),
        ];
        let summary = LlmSummary::of_run(&records, &coverage, 50);
        assert_eq!(
            (summary.model_decisions, summary.differed, summary.stale),
            (6, 4, 1)
        );
        let o = summary.outcomes.clone().unwrap();
        assert_eq!((o.horizon_steps, o.differed, o.same), (50, 1, 2));
        assert!((o.differed_gain_pp.unwrap() - 15.0).abs() < 1e-9, "{o:?}");
        assert!((o.same_gain_pp.unwrap() - 10.0).abs() < 1e-9, "{o:?}");
        let line = summary.line();
        assert!(
            line.contains("the model decided 6 times, 4 of them differently")
                && line.contains("1 answers not applied (stale)")
                && line.contains("+15.00 pp over 1 where the model differed")
                && line.contains("+10.00 pp over 2 where the decision was the fallback's"),
            "{line}"
        );
        // No coverage rows, or no whole window: no outcomes.
        assert_eq!(LlmOutcomes::of(&records, &[], 50), None);
        assert_eq!(LlmOutcomes::of(&records, &coverage, 1000), None);
    }

    /// The summary survives the file; its JSON keeps the field names and `null`s the evaluator
    /// always wrote; a partial one reads with defaults; a wrongly typed field names the file.
    #[test]
    fn summary_round_trips_through_the_file() {
        let dir = tempfile::tempdir().unwrap();
        let run = RunFolder::new(dir.path());
        assert!(!run.has_summary());
        let e = run.read_summary().unwrap_err().to_string();
        assert!(e.contains("summary.json: missing"), "{e}");
        run.write_summary(&summary()).unwrap();
        assert!(run.has_summary());
        assert_eq!(run.read_summary().unwrap(), summary());
        let text = std::fs::read_to_string(run.path(RunFolder::SUMMARY)).unwrap();
        for key in [
            "\"steps\": 301",
            "\"coverage\": 0.875",
            "\"scene\": \"house:7\"",
            "\"max_area\": null",
            "\"blocked_forwards\": 2",
            "\"floor\": \"auto\"",
            "\"scale\": 0.01",
        ] {
            assert!(text.contains(key), "{key} in {text}");
        }
        std::fs::write(run.path(RunFolder::SUMMARY), "{\"steps\": 3, \"extra\": 1}").unwrap();
        let partial = run.read_summary().unwrap();
        assert_eq!(
            (partial.steps, partial.scene, partial.coverage),
            (3, None, None)
        );
        // Summaries from before the placement keys: no transform, floor `none`.
        assert_eq!((partial.transform, partial.floor), (None, None));
        std::fs::write(run.path(RunFolder::SUMMARY), "{\"steps\": \"many\"}").unwrap();
        let e = run.read_summary().unwrap_err().to_string();
        assert!(e.contains("summary.json: malformed"), "{e}");
        std::fs::write(run.path(RunFolder::SUMMARY), "{\"steps\": 3").unwrap();
        let e = run.read_summary().unwrap_err().to_string();
        assert!(e.contains("summary.json: malformed"), "{e}");
        let rows = summary().rows();
        assert!(rows.contains(&("coverage", "0.8750".into())), "{rows:?}");
        assert!(rows.contains(&("max_area", "—".into())), "{rows:?}");
        assert!(rows.contains(&("floor", "auto".into())), "{rows:?}");
        assert!(rows.contains(&("valid", "yes".into())), "{rows:?}");
        assert!(
            rows.contains(&("map_depth_model", "plane".into())),
            "{rows:?}"
        );
        let tracking = &rows.iter().find(|(k, _)| *k == "tracking").unwrap().1;
        assert!(
            tracking.starts_with(
                "4 lost frame(s) in 2 run(s) (motion_mismatch 4), 1 relocalisation(s)"
            ),
            "{tracking}"
        );
    }

    /// A summary with warnings says `"valid": false` and lists them (code and message); it reads
    /// back the same; an older summary without `warnings` (or `valid`) reads as valid.
    #[test]
    fn summary_warnings_round_trip_and_old_summaries_read_as_valid() {
        use crate::validity::{RunWarning, code};
        let dir = tempfile::tempdir().unwrap();
        let run = RunFolder::new(dir.path());
        run.write_summary(&summary()).unwrap();
        let text = std::fs::read_to_string(run.path(RunFolder::SUMMARY)).unwrap();
        assert!(
            text.contains("\"valid\": true") && text.contains("\"warnings\": []"),
            "{text}"
        );
        let invalid = Summary {
            warnings: vec![
                RunWarning::new(code::ROBOT_CANNOT_MOVE, "206 of 206 forward moves blocked"),
                RunWarning::new(code::EMPTY_MAP, "0 observed Gaussians"),
            ],
            ..summary()
        };
        assert!(summary().is_valid() && !invalid.is_valid());
        run.write_summary(&invalid).unwrap();
        let text = std::fs::read_to_string(run.path(RunFolder::SUMMARY)).unwrap();
        assert!(text.contains("\"valid\": false"), "{text}");
        assert!(text.contains("\"code\": \"robot_cannot_move\""), "{text}");
        assert!(
            text.contains("\"message\": \"206 of 206 forward moves blocked\""),
            "{text}"
        );
        assert_eq!(run.read_summary().unwrap(), invalid);
        let rows = invalid.rows();
        assert!(
            rows.contains(&("valid", "NO: robot_cannot_move, empty_map".into())),
            "{rows:?}"
        );
        // A summary.json of an older evaluator: no `warnings`, no `valid`.
        std::fs::write(
            run.path(RunFolder::SUMMARY),
            "{\"steps\": 301, \"coverage\": 0.875, \"path_length_m\": 7.25, \"map_gaussians\": 77000}",
        )
        .unwrap();
        let old = run.read_summary().unwrap();
        assert!(old.warnings.is_empty() && old.is_valid(), "{old:?}");
        assert_eq!(old.steps, 301);
    }

    /// Each CSV is written with its header and 6-decimal numbers and reads back the same rows.
    #[test]
    fn csv_files_round_trip_with_their_headers() {
        let dir = tempfile::tempdir().unwrap();
        let run = RunFolder::new(dir.path());
        run.write_coverage(&[]).unwrap();
        assert_eq!(
            std::fs::read_to_string(run.path(RunFolder::COVERAGE)).unwrap(),
            "step,coverage\n"
        );
        assert_eq!(run.read_coverage().unwrap(), Some(vec![]));
        let coverage = [
            CoverageRow {
                step: 1,
                coverage: 0.1,
            },
            CoverageRow {
                step: 11,
                coverage: 0.42,
            },
        ];
        run.write_coverage(&coverage).unwrap();
        assert_eq!(
            std::fs::read_to_string(run.path(RunFolder::COVERAGE)).unwrap(),
            "step,coverage\n1,0.100000\n11,0.420000\n"
        );
        assert_eq!(run.read_coverage().unwrap().unwrap(), coverage);

        let timings = vec![
            StageTime {
                stage: "tracker".into(),
                seconds: 2.0,
                calls: 8,
            },
            StageTime {
                stage: "mapper".into(),
                seconds: 1.5,
                calls: 4,
            },
            StageTime {
                stage: "tracker".into(),
                seconds: 1.0,
                calls: 4,
            },
        ];
        assert!(run.read_timings().unwrap().is_none());
        run.write_timings(&timings).unwrap();
        assert_eq!(
            std::fs::read_to_string(run.path(RunFolder::TIMINGS)).unwrap(),
            "stage,seconds,calls\ntracker,2.000000,8\nmapper,1.500000,4\ntracker,1.000000,4\n"
        );
        let back = run.read_timings().unwrap().unwrap();
        assert_eq!(back, timings);
        let summed = StageTime::summed(&back);
        assert_eq!(summed.len(), 2);
        assert_eq!((summed[0].seconds, summed[0].calls), (3.0, 12));
        std::fs::write(
            run.path(RunFolder::TIMINGS),
            "stage,seconds,calls\n\n sim , 1.5 , 3 \n",
        )
        .unwrap();
        assert_eq!(
            run.read_timings().unwrap().unwrap(),
            vec![StageTime {
                stage: "sim".into(),
                seconds: 1.5,
                calls: 3
            }]
        );
        std::fs::write(
            run.path(RunFolder::TIMINGS),
            "stage,seconds,calls\nsim,-1,3\n",
        )
        .unwrap();
        let e = run.read_timings().unwrap_err().to_string();
        assert!(e.contains("timings.csv") && e.contains("line 2"), "{e}");
        std::fs::write(
            run.path(RunFolder::TIMINGS),
            "node,seconds,calls\nsim,1,3\n",
        )
        .unwrap();
        let e = run.read_timings().unwrap_err().to_string();
        assert!(
            e.contains("line 1") && e.contains("expected `stage,seconds,calls`"),
            "{e}"
        );

        std::fs::create_dir_all(run.eval_dir()).unwrap();
        let views = [
            ViewRow {
                view: 0,
                psnr_db: f64::INFINITY,
                ssim: 1.0,
                lpips: None,
                depth_mae_m: Some(0.012345),
            },
            ViewRow {
                view: 1,
                psnr_db: 21.5,
                ssim: 0.75,
                lpips: Some(0.25),
                depth_mae_m: None,
            },
        ];
        run.write_views(&views).unwrap();
        assert_eq!(
            std::fs::read_to_string(run.views_path()).unwrap(),
            "view,psnr_db,ssim,lpips,depth_mae_m\n0,inf,1.000000,,0.012345\n1,21.500000,0.750000,0.250000,\n"
        );
        assert_eq!(run.read_views().unwrap().unwrap(), views);
        assert_eq!(
            run.read_test_poses().unwrap(),
            None,
            "absent before it is written"
        );
        let poses = vec![TestPoseRow {
            view: 0,
            x_m: 1.5,
            y_m: -2.25,
            yaw_deg: 90.0,
        }];
        run.write_test_poses(&poses).unwrap();
        assert_eq!(run.read_test_poses().unwrap().unwrap(), poses);
    }

    fn fisher_rows() -> Vec<FisherRow> {
        vec![
            FisherRow {
                step: 20,
                refine: false,
                candidates: 180,
                paths: 20,
                chosen: 3,
                objective: Some(-41.25),
                eig_sum: Some(1.5e-3),
                eig_first: Some(1e-3),
                c_local_sum: Some(f64::INFINITY),
                actions: Some(27),
                total_ms: 812.5,
                model_reused: false,
                fallback: false,
            },
            FisherRow {
                step: 31,
                refine: true,
                candidates: 0,
                paths: 0,
                chosen: -1,
                objective: None,
                eig_sum: None,
                eig_first: None,
                c_local_sum: None,
                actions: None,
                total_ms: 3.0,
                model_reused: true,
                fallback: true,
            },
        ]
    }

    /// `fisher.csv` is absent until written, then holds its header, 6-decimal reals, `inf` for
    /// +∞ and empty chosen-path columns when no path was chosen, and reads back the same rows.
    #[test]
    fn fisher_rows_round_trip() {
        let dir = tempfile::tempdir().unwrap();
        let run = RunFolder::new(dir.path());
        assert!(run.read_fisher().unwrap().is_none());
        run.write_fisher(&[]).unwrap();
        assert_eq!(run.read_fisher().unwrap(), Some(vec![]));
        let rows = fisher_rows();
        run.write_fisher(&rows).unwrap();
        assert_eq!(
            std::fs::read_to_string(run.path(RunFolder::FISHER)).unwrap(),
            "step,refine,candidates,paths,chosen,objective,eig_sum,eig_first,c_local_sum,actions,total_ms,model_reused,fallback\n\
             20,false,180,20,3,-41.250000,0.001500,0.001000,inf,27,812.500000,false,false\n\
             31,true,0,0,-1,,,,,,3.000000,true,true\n"
        );
        assert_eq!(run.read_fisher().unwrap().unwrap(), rows);
    }

    /// A row that does not parse or does not hold together is named by file and line.
    #[test]
    fn malformed_fisher_rows_are_named_by_line() {
        let dir = tempfile::tempdir().unwrap();
        let run = RunFolder::new(dir.path());
        let header = FisherRow::HEADER.join(",");
        let good = "20,false,180,20,3,-41.25,0.0015,0.001,inf,27,812.5,false,false";
        for (bad, why) in [
            (
                "21,false,180,20,3,-41.25,NaN,0.001,inf,27,812.5,false,false",
                "eig_sum NaN must be finite",
            ),
            (
                "21,false,180,20,3,-41.25,-1,0.001,1,27,812.5,false,false",
                "eig_sum -1 must be finite and ≥ 0",
            ),
            (
                "21,false,180,20,3,inf,0.1,0.001,1,27,812.5,false,false",
                "objective inf must be finite",
            ),
            (
                "21,false,180,20,3,1,0.1,0.001,-inf,27,812.5,false,false",
                "c_local_sum -inf must be a real or +inf",
            ),
            (
                "21,false,180,20,20,1,0.1,0.001,1,27,812.5,false,false",
                "chosen 20 is not −1 or an index of the 20 path(s)",
            ),
            (
                "21,false,180,20,-1,1,,,,,812.5,false,false",
                "objective is given but no path was chosen",
            ),
            (
                "21,false,180,20,2,1,0.1,,,27,812.5,false,false",
                "c_local_sum is empty but path 2 was chosen",
            ),
            (
                "21,false,180,20,-1,,,,,,inf,false,false",
                "total_ms inf must be finite",
            ),
            (
                "21,maybe,180,20,-1,,,,,,1,false,false",
                "expected `step,refine,",
            ),
            ("21,false,180,20,-1,,,,,,1,false", "found 12 field(s)"),
        ] {
            std::fs::write(
                run.path(RunFolder::FISHER),
                format!("{header}\n{good}\n{bad}\n"),
            )
            .unwrap();
            let e = run.read_fisher().unwrap_err().to_string();
            assert!(
                e.contains("fisher.csv: malformed: line 3") && e.contains(why),
                "{bad}: {e}"
            );
        }
        // A chosen path that scored no pose has no first EIG.
        std::fs::write(
            run.path(RunFolder::FISHER),
            format!("{header}\n21,false,1,1,0,-2,0,,-2,4,1,false,false\n"),
        )
        .unwrap();
        assert_eq!(run.read_fisher().unwrap().unwrap()[0].eig_first, None);
    }

    /// Each row type's `HEADER` is what serde writes for its fields.
    #[test]
    fn headers_match_the_serde_fields() {
        fn header_of<T: CsvRow>(row: &T) -> String {
            let mut w = csv::Writer::from_writer(Vec::new());
            w.serialize(row).unwrap();
            let text = String::from_utf8(w.into_inner().unwrap()).unwrap();
            text.lines().next().unwrap().to_string()
        }
        let coverage = CoverageRow {
            step: 0,
            coverage: 0.0,
        };
        assert_eq!(header_of(&coverage), CoverageRow::HEADER.join(","));
        let timing = StageTime {
            stage: "a".into(),
            seconds: 0.0,
            calls: 0,
        };
        assert_eq!(header_of(&timing), StageTime::HEADER.join(","));
        let view = ViewRow {
            view: 0,
            psnr_db: 0.0,
            ssim: 0.0,
            lpips: None,
            depth_mae_m: None,
        };
        assert_eq!(header_of(&view), ViewRow::HEADER.join(","));
        assert_eq!(header_of(&fisher_rows()[0]), FisherRow::HEADER.join(","));
    }

    #[test]
    fn llm_lines_are_typed_and_bad_lines_named() {
        let dir = tempfile::tempdir().unwrap();
        let run = RunFolder::new(dir.path());
        assert!(run.read_llm().unwrap().is_none());
        std::fs::write(
            run.path(RunFolder::LLM),
            "{\"step\": 5, \"prompt\": \"p\", \"reply\": \"r\", \"target\": 1}\n\n{\"step\": 6}\n",
        )
        .unwrap();
        let records = run.read_llm().unwrap().unwrap();
        assert_eq!(records.len(), 2);
        assert_eq!((records[0].step, records[0].target), (Some(5), Some(1)));
        assert_eq!(records[1].prompt, None);
        std::fs::write(run.path(RunFolder::LLM), "{\"step\": 5}\n{oops\n").unwrap();
        let e = run.read_llm().unwrap_err().to_string();
        assert!(e.contains("llm.jsonl") && e.contains("line 2"), "{e}");
    }

    #[test]
    fn metrics_are_absent_until_written() {
        let dir = tempfile::tempdir().unwrap();
        let run = RunFolder::new(dir.path());
        assert!(run.read_metrics().unwrap().is_none());
        let report = MetricsReport {
            psnr_db: Some(21.0),
            ..Default::default()
        };
        run.write_metrics(&report, "# table\n").unwrap();
        assert_eq!(run.read_metrics().unwrap(), Some(report));
        std::fs::write(run.path(RunFolder::METRICS_JSON), "{\"psnr_db\": 1").unwrap();
        let e = run.read_metrics().unwrap_err().to_string();
        assert!(e.contains("metrics.json: malformed"), "{e}");
        assert_eq!(
            run.view_image(3, ViewImage::Truth),
            dir.path().join("eval/view_03_truth.png")
        );
        assert_eq!(
            run.worst_view_image(1, 417, ViewImage::DepthClasses),
            dir.path().join("eval/worst_01_view_0417_depth_classes.png")
        );
    }
}
