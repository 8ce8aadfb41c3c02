//! Reading a run folder (written by the `evaluator` operator, operators/src/evaluator.rs):
//! `trajectory_est.tum` (map frame = the robot's start frame), `trajectory_true.tum` (world),
//! `map.ply` (3DGS PLY of the last map, map frame), `coverage.csv` (`step,coverage`),
//! `summary.json` (steps, coverage, ATE, …, and the scene when the evaluator records it) and the
//! `dataflow.yaml` copy the launcher puts there. Every error names the file and what is wrong.

use activemap_geometry::tum::Trajectory;
use std::path::{Path, PathBuf};

/// File names inside a run folder.
pub mod files {
    /// Estimated trajectory (TUM, map frame).
    pub const TRAJECTORY_EST: &str = "trajectory_est.tum";
    /// True trajectory (TUM, world frame).
    pub const TRAJECTORY_TRUE: &str = "trajectory_true.tum";
    /// Final map (3DGS PLY, map frame).
    pub const MAP: &str = "map.ply";
    /// 2D coverage per step (`step,coverage`).
    pub const COVERAGE: &str = "coverage.csv";
    /// The evaluator's summary.
    pub const SUMMARY: &str = "summary.json";
    /// The launcher's copy of the dataflow.
    pub const DATAFLOW: &str = "dataflow.yaml";
    /// Bird's-eye PNG of the last occupancy grid with both trajectories and the frontiers.
    pub const BEV: &str = "bev.png";
    /// Metrics written by `evaluate_run`.
    pub const METRICS_JSON: &str = "metrics.json";
    /// The metrics as a Markdown table.
    pub const METRICS_MD: &str = "metrics.md";
    /// Folder of the test renders `evaluate_run` keeps for the report.
    pub const EVAL_DIR: &str = "eval";
    /// Per-stage time breakdown (`stage,seconds,calls`), when the run records it.
    pub const TIMINGS: &str = "timings.csv";
    /// LLM exchanges, one JSON object per line, when the run had any.
    pub const LLM: &str = "llm.jsonl";
    /// The report page.
    pub const REPORT: &str = "report.html";
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
        /// What is wrong, with the line when known.
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
    /// A benchmark setting is invalid (e.g. a method given as something other than
    /// `NAME=DATAFLOW`).
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

/// Reads a TUM trajectory of the run folder; empty files are refused.
pub fn read_trajectory(dir: &Path, name: &str) -> Result<Trajectory, RunError> {
    let path = dir.join(name);
    let text = read_text(&path, "TUM trajectory `t tx ty tz qx qy qz qw`")?;
    let trajectory =
        Trajectory::parse(&text, &path.display().to_string()).map_err(|e| RunError::Malformed {
            path: path.clone(),
            detail: e.to_string(),
        })?;
    if trajectory.is_empty() {
        return Err(RunError::Malformed {
            path,
            detail: "the trajectory holds no pose".into(),
        });
    }
    Ok(trajectory)
}

/// Reads `coverage.csv` (`step,coverage` header, then one row per scored grid); `None` when the
/// file is absent.
pub fn read_coverage(dir: &Path) -> Result<Option<Vec<(u64, f64)>>, RunError> {
    let path = dir.join(files::COVERAGE);
    let text = match read_text(&path, "2D coverage per step") {
        Ok(t) => t,
        Err(RunError::Missing { .. }) => return Ok(None),
        Err(e) => return Err(e),
    };
    let mut rows = Vec::new();
    for (n, line) in text.lines().enumerate() {
        let line = line.trim();
        if line.is_empty() || (n == 0 && line.starts_with("step")) {
            continue;
        }
        let bad = |detail: String| RunError::Malformed {
            path: path.clone(),
            detail: format!("line {}: {detail}", n + 1),
        };
        let (step, value) = line
            .split_once(',')
            .ok_or_else(|| bad(format!("expected `step,coverage`, found `{line}`")))?;
        let step: u64 = step
            .trim()
            .parse()
            .map_err(|e| bad(format!("step `{step}`: {e}")))?;
        let value: f64 = value
            .trim()
            .parse()
            .map_err(|e| bad(format!("coverage `{value}`: {e}")))?;
        if !(0.0..=1.0).contains(&value) {
            return Err(bad(format!("coverage {value} is outside [0, 1]")));
        }
        rows.push((step, value));
    }
    Ok(Some(rows))
}

/// Reads `summary.json` as free-form JSON (its fields grow with the pipeline).
pub fn read_summary(dir: &Path) -> Result<serde_json::Value, RunError> {
    let path = dir.join(files::SUMMARY);
    let text = read_text(&path, "the evaluator's summary")?;
    let value: serde_json::Value =
        serde_json::from_str(&text).map_err(|e| RunError::Malformed {
            path: path.clone(),
            detail: e.to_string(),
        })?;
    if !value.is_object() {
        return Err(RunError::Malformed {
            path,
            detail: "expected a JSON object".into(),
        });
    }
    Ok(value)
}

/// Reads `map.ply` (every Gaussian; the PLY layout stores no flags, see the crate docs of
/// `activemap-splat`).
pub fn read_map(dir: &Path) -> Result<activemap_splat::Gaussians<f32>, RunError> {
    let path = dir.join(files::MAP);
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

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn coverage_rows_are_parsed_and_bad_rows_named() {
        let dir = tempfile::tempdir().unwrap();
        assert!(read_coverage(dir.path()).unwrap().is_none());
        let p = dir.path().join(files::COVERAGE);
        std::fs::write(&p, "step,coverage\n1,0.25\n2,0.5\n").unwrap();
        assert_eq!(
            read_coverage(dir.path()).unwrap().unwrap(),
            vec![(1, 0.25), (2, 0.5)]
        );
        std::fs::write(&p, "step,coverage\n1,0.25\n2;0.5\n").unwrap();
        let e = read_coverage(dir.path()).unwrap_err().to_string();
        assert!(e.contains("coverage.csv") && e.contains("line 3"), "{e}");
        std::fs::write(&p, "step,coverage\n1,1.5\n").unwrap();
        let e = read_coverage(dir.path()).unwrap_err().to_string();
        assert!(e.contains("outside [0, 1]"), "{e}");
    }

    #[test]
    fn missing_and_malformed_files_are_named() {
        let dir = tempfile::tempdir().unwrap();
        let e = read_trajectory(dir.path(), files::TRAJECTORY_EST)
            .unwrap_err()
            .to_string();
        assert!(e.contains("trajectory_est.tum: missing"), "{e}");
        std::fs::write(dir.path().join(files::TRAJECTORY_EST), "").unwrap();
        let e = read_trajectory(dir.path(), files::TRAJECTORY_EST)
            .unwrap_err()
            .to_string();
        assert!(e.contains("no pose"), "{e}");
        std::fs::write(dir.path().join(files::SUMMARY), "[1, 2]").unwrap();
        let e = read_summary(dir.path()).unwrap_err().to_string();
        assert!(e.contains("summary.json: malformed"), "{e}");
        std::fs::write(dir.path().join(files::MAP), "ply\nnonsense").unwrap();
        let e = read_map(dir.path()).unwrap_err().to_string();
        assert!(e.contains("map.ply: malformed"), "{e}");
    }
}
