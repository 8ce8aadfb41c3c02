//! Trajectories in the TUM RGB-D text format, one pose per line: `t tx ty tz qx qy qz qw`
//! (`T_world_camera`), `#` comments allowed. `evo` reads and writes the same format.

use nalgebra::{Isometry3, Quaternion, Translation3, UnitQuaternion};
use std::fmt::Write as _;
use std::path::Path;

/// A timestamped pose sequence.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Trajectory {
    /// Timestamps, seconds.
    pub stamps: Vec<f64>,
    /// Poses `T_world_camera`, one per stamp.
    pub poses: Vec<Isometry3<f64>>,
}

/// Why a TUM file could not be read.
#[derive(Debug, thiserror::Error)]
pub enum TumError {
    /// The file could not be read.
    #[error("{path}: {source}")]
    Io {
        /// The file.
        path: String,
        /// The I/O error.
        source: std::io::Error,
    },
    /// A line does not hold 8 numbers, or a quaternion is degenerate.
    #[error("{path}:{line}: {message}")]
    Parse {
        /// The file (or `<text>`).
        path: String,
        /// 1-based line number.
        line: usize,
        /// What is wrong.
        message: String,
    },
}

impl Trajectory {
    /// Number of poses.
    pub fn len(&self) -> usize {
        self.poses.len()
    }

    /// True when the trajectory holds no pose.
    pub fn is_empty(&self) -> bool {
        self.poses.is_empty()
    }

    /// Appends a pose.
    pub fn push(&mut self, stamp: f64, pose: Isometry3<f64>) {
        self.stamps.push(stamp);
        self.poses.push(pose);
    }

    /// Parses TUM text; `origin` names the source in errors.
    pub fn parse(text: &str, origin: &str) -> Result<Self, TumError> {
        let mut out = Self::default();
        for (i, raw) in text.lines().enumerate() {
            let line = raw.trim();
            if line.is_empty() || line.starts_with('#') {
                continue;
            }
            let err = |message: String| TumError::Parse {
                path: origin.to_string(),
                line: i + 1,
                message,
            };
            let values: Vec<f64> = line
                .split_whitespace()
                .map(|s| {
                    s.parse::<f64>()
                        .map_err(|e| err(format!("`{s}` is not a number ({e})")))
                })
                .collect::<Result<_, _>>()?;
            if values.len() != 8 {
                return Err(err(format!(
                    "expected 8 values `t tx ty tz qx qy qz qw`, found {}",
                    values.len()
                )));
            }
            if values.iter().any(|v| !v.is_finite()) {
                return Err(err("non-finite value".into()));
            }
            let q = Quaternion::new(values[7], values[4], values[5], values[6]);
            if q.norm() < 1e-9 {
                return Err(err("zero quaternion".into()));
            }
            out.push(
                values[0],
                Isometry3::from_parts(
                    Translation3::new(values[1], values[2], values[3]),
                    UnitQuaternion::from_quaternion(q),
                ),
            );
        }
        Ok(out)
    }

    /// Reads a TUM file.
    pub fn read(path: &Path) -> Result<Self, TumError> {
        let name = path.display().to_string();
        let text = std::fs::read_to_string(path).map_err(|source| TumError::Io {
            path: name.clone(),
            source,
        })?;
        Self::parse(&text, &name)
    }

    /// Formats as TUM text with full f64 precision.
    pub fn to_tum_string(&self) -> String {
        let mut s = String::new();
        for (t, p) in self.stamps.iter().zip(&self.poses) {
            let q = p.rotation.quaternion();
            let v = p.translation.vector;
            let _ = writeln!(
                s,
                "{t} {} {} {} {} {} {} {}",
                v.x, v.y, v.z, q.i, q.j, q.k, q.w
            );
        }
        s
    }

    /// Writes a TUM file.
    pub fn write(&self, path: &Path) -> std::io::Result<()> {
        std::fs::write(path, self.to_tum_string())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn round_trip_is_exact() {
        let text = "# c\n1.5 1 2 3 0 0 0 1\n2.25 -0.125 0.5 1e-3 0.2 0.3 0.4 0.8\n";
        let t = Trajectory::parse(text, "x").unwrap();
        assert_eq!(t.len(), 2);
        let again = Trajectory::parse(&t.to_tum_string(), "y").unwrap();
        assert_eq!(t, again);
    }

    #[test]
    fn errors_name_the_line() {
        let e = Trajectory::parse("0 1 2 3 0 0 0 1\n1 2 3\n", "f.txt")
            .unwrap_err()
            .to_string();
        assert!(e.starts_with("f.txt:2:"), "{e}");
        let e = Trajectory::parse("0 1 2 x 0 0 0 1\n", "g")
            .unwrap_err()
            .to_string();
        assert!(e.contains("g:1") && e.contains("`x`"), "{e}");
    }

    #[test]
    fn reads_shared_trajectories_when_present() {
        let dir = std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
            .join("../../../shared/data/trajectories");
        if !dir.exists() {
            eprintln!("skipping: {} is absent", dir.display());
            return;
        }
        let gt = Trajectory::read(&dir.join("groundtruth.txt")).unwrap();
        let est = Trajectory::read(&dir.join("estimated.txt")).unwrap();
        assert_eq!(gt.len(), 612);
        assert_eq!(est.len(), 612);
    }
}
