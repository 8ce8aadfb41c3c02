//! Absolute trajectory error (SPEC §8): RMSE of the translation error of associated poses,
//! after an optional Umeyama SE(3) alignment (rotation and translation, no scale) of the
//! estimate onto the reference. Association and alignment follow `evo` (`evo_ape tum REF EST
//! [-a]`): each pose of the shorter trajectory is paired with the reference-time-nearest pose of
//! the other when the stamps differ by at most `max_time_diff` (evo's default 0.01 s).

use crate::error::EvalError;
use activemap_geometry::tum::Trajectory;
use nalgebra::{Isometry3, Matrix3, Rotation3, Translation3, UnitQuaternion, Vector3};

/// evo's default association tolerance, seconds.
pub const DEFAULT_MAX_TIME_DIFF: f64 = 0.01;

/// How to compute the ATE.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct AteOptions {
    /// Largest |t_ref − t_est| for two poses to be paired, seconds.
    pub max_time_diff: f64,
    /// Align the estimate onto the reference with Umeyama SE(3) first (SPEC §8 does).
    pub align: bool,
}

impl Default for AteOptions {
    /// SPEC §8: aligned, evo's 0.01 s tolerance.
    fn default() -> Self {
        Self {
            max_time_diff: DEFAULT_MAX_TIME_DIFF,
            align: true,
        }
    }
}

/// Translation-error statistics over the associated poses, metres.
#[derive(Debug, Clone, PartialEq)]
pub struct AteResult {
    /// √(mean e²): the number the paper reports.
    pub rmse: f64,
    /// Mean error.
    pub mean: f64,
    /// Median error (mean of the two middle ones for an even count, as numpy).
    pub median: f64,
    /// Population standard deviation of the errors (numpy's `std`, as evo reports).
    pub std: f64,
    /// Smallest error.
    pub min: f64,
    /// Largest error.
    pub max: f64,
    /// Number of associated pose pairs.
    pub pairs: usize,
    /// The transform applied to the estimate (identity when not aligned): `T_ref_est`.
    pub alignment: Isometry3<f64>,
}

/// Index pairs `(reference, estimate)` of poses whose stamps match, as evo's
/// `associate_trajectories` (nearest stamp, ties to the earlier one, at most `max_time_diff`).
pub fn associate(
    reference: &Trajectory,
    estimate: &Trajectory,
    max_time_diff: f64,
) -> Result<Vec<(usize, usize)>, EvalError> {
    if !(max_time_diff.is_finite() && max_time_diff >= 0.0) {
        return Err(EvalError::InvalidParameter {
            metric: "ATE",
            detail: format!("max time difference must be finite and ≥ 0, got {max_time_diff}"),
        });
    }
    for (name, t) in [("reference", reference), ("estimate", estimate)] {
        if t.is_empty() {
            return Err(EvalError::Empty {
                metric: "ATE",
                detail: format!("the {name} trajectory holds no pose"),
            });
        }
        if let Some(i) = t.stamps.iter().position(|s| !s.is_finite()) {
            return Err(EvalError::NonFinite {
                metric: "ATE",
                input: if name == "reference" {
                    "reference"
                } else {
                    "estimate"
                },
                location: format!("timestamp of pose {i}"),
            });
        }
    }
    // evo starts from the trajectory with fewer poses (the estimate on a tie).
    let reference_is_short = reference.len() < estimate.len();
    let (short, long) = if reference_is_short {
        (&reference.stamps, &estimate.stamps)
    } else {
        (&estimate.stamps, &reference.stamps)
    };
    let sorted = long.windows(2).all(|w| w[1] >= w[0]);
    let mut pairs = Vec::new();
    for (i, &stamp) in short.iter().enumerate() {
        let best = if sorted {
            nearest_sorted(long, stamp, max_time_diff)
        } else {
            nearest_linear(long, stamp, max_time_diff)
        };
        if let Some(j) = best {
            pairs.push(if reference_is_short { (i, j) } else { (j, i) });
        }
    }
    if pairs.is_empty() {
        return Err(EvalError::NoCommonTimestamps {
            reference_len: reference.len(),
            estimate_len: estimate.len(),
            max_time_diff,
        });
    }
    Ok(pairs)
}

/// Nearest stamp in sorted `stamps` within `max_diff` (evo's binary-search rule).
fn nearest_sorted(stamps: &[f64], stamp: f64, max_diff: f64) -> Option<usize> {
    let last = *stamps.last()?;
    if stamp < stamps[0] - max_diff || stamp > last + max_diff {
        return None;
    }
    // insertion index after equal elements (numpy searchsorted side="right"), clamped
    let upper = stamps
        .partition_point(|&s| s <= stamp)
        .min(stamps.len() - 1);
    let diff_upper = stamps[upper] - stamp;
    let diff_lower = if upper > 0 {
        stamp - stamps[upper - 1]
    } else {
        f64::INFINITY
    };
    if diff_upper <= max_diff && diff_upper < diff_lower {
        Some(upper)
    } else if diff_lower <= max_diff && diff_lower <= diff_upper {
        Some(upper - 1)
    } else {
        None
    }
}

/// Nearest stamp by linear search (evo's fallback for unsorted stamps; first minimum wins).
fn nearest_linear(stamps: &[f64], stamp: f64, max_diff: f64) -> Option<usize> {
    let (j, d) = stamps.iter().map(|s| (s - stamp).abs()).enumerate().fold(
        (0, f64::INFINITY),
        |best, (j, d)| if d < best.1 { (j, d) } else { best },
    );
    (d <= max_diff).then_some(j)
}

/// Umeyama (1991) least-squares rigid transform `T` (rotation + translation, no scale) with
/// `T·source[i] ≈ target[i]`, as evo's `umeyama_alignment(with_scale=False)`.
///
/// One difference: evo refuses positions spanning fewer than 2 directions (a single pose, or a
/// robot that has only driven straight). The optimal transform is then not unique, but every
/// optimum leaves the same residuals, so this returns one of them (U·S·Vᵀ stays a maximiser of
/// tr(Rᵀ·Σxy) for a rank-deficient Σxy) and the ATE stays defined early in a run.
pub fn umeyama_se3(
    source: &[Vector3<f64>],
    target: &[Vector3<f64>],
) -> Result<Isometry3<f64>, EvalError> {
    if source.len() != target.len() {
        return Err(EvalError::SizeMismatch {
            metric: "ATE",
            detail: format!(
                "alignment needs paired points: {} source, {} target",
                source.len(),
                target.len()
            ),
        });
    }
    if source.is_empty() {
        return Err(EvalError::Empty {
            metric: "ATE",
            detail: "no point pair to align".into(),
        });
    }
    let n = source.len() as f64;
    let mean_source = source.iter().sum::<Vector3<f64>>() / n;
    let mean_target = target.iter().sum::<Vector3<f64>>() / n;
    let covariance = source
        .iter()
        .zip(target)
        .map(|(s, t)| (t - mean_target) * (s - mean_source).transpose())
        .sum::<Matrix3<f64>>()
        / n;
    let svd = covariance.svd(true, true);
    let (Some(u), Some(v_t)) = (svd.u, svd.v_t) else {
        return Err(EvalError::DegenerateAlignment {
            detail: "the SVD of the covariance did not converge".into(),
        });
    };
    let mut s = Matrix3::identity();
    if u.determinant() * v_t.determinant() < 0.0 {
        s[(2, 2)] = -1.0;
    }
    let rotation = Rotation3::from_matrix_unchecked(u * s * v_t);
    let translation = mean_target - rotation * mean_source;
    Ok(Isometry3::from_parts(
        Translation3::from(translation),
        UnitQuaternion::from_rotation_matrix(&rotation),
    ))
}

/// ATE of `estimate` against `reference` (SPEC §8), translation only, metres.
pub fn ate(
    reference: &Trajectory,
    estimate: &Trajectory,
    options: AteOptions,
) -> Result<AteResult, EvalError> {
    for (input, t) in [("reference", reference), ("estimate", estimate)] {
        if let Some(i) = t.poses.iter().position(|p| {
            !p.translation
                .vector
                .iter()
                .chain(p.rotation.coords.iter())
                .all(|v| v.is_finite())
        }) {
            return Err(EvalError::NonFinite {
                metric: "ATE",
                input,
                location: format!("pose {i}"),
            });
        }
        if t.stamps.len() != t.poses.len() {
            return Err(EvalError::SizeMismatch {
                metric: "ATE",
                detail: format!(
                    "the {input} trajectory has {} stamps but {} poses",
                    t.stamps.len(),
                    t.poses.len()
                ),
            });
        }
    }
    let pairs = associate(reference, estimate, options.max_time_diff)?;
    let reference_positions: Vec<Vector3<f64>> = pairs
        .iter()
        .map(|&(r, _)| reference.poses[r].translation.vector)
        .collect();
    let estimate_positions: Vec<Vector3<f64>> = pairs
        .iter()
        .map(|&(_, e)| estimate.poses[e].translation.vector)
        .collect();
    let alignment = if options.align {
        umeyama_se3(&estimate_positions, &reference_positions)?
    } else {
        Isometry3::identity()
    };
    let errors: Vec<f64> = estimate_positions
        .iter()
        .zip(&reference_positions)
        .map(|(e, r)| (alignment.transform_vector(e) + alignment.translation.vector - r).norm())
        .collect();
    let n = errors.len() as f64;
    let mean = errors.iter().sum::<f64>() / n;
    let mut sorted = errors.clone();
    sorted.sort_by(f64::total_cmp);
    let middle = sorted.len() / 2;
    let median = if sorted.len() % 2 == 1 {
        sorted[middle]
    } else {
        0.5 * (sorted[middle - 1] + sorted[middle])
    };
    Ok(AteResult {
        rmse: (errors.iter().map(|e| e * e).sum::<f64>() / n).sqrt(),
        mean,
        median,
        std: (errors.iter().map(|e| (e - mean).powi(2)).sum::<f64>() / n).sqrt(),
        min: sorted[0],
        max: sorted[sorted.len() - 1],
        pairs: errors.len(),
        alignment,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn trajectory(stamps: &[f64], positions: &[Vector3<f64>]) -> Trajectory {
        let mut t = Trajectory::default();
        for (s, p) in stamps.iter().zip(positions) {
            t.push(*s, Isometry3::translation(p.x, p.y, p.z));
        }
        t
    }

    #[test]
    fn umeyama_recovers_a_known_transform() {
        let truth = Isometry3::from_parts(
            Translation3::new(0.4, -1.2, 2.0),
            UnitQuaternion::from_euler_angles(0.3, -0.7, 1.9),
        );
        let source: Vec<Vector3<f64>> = (0..20)
            .map(|i| {
                let f = f64::from(i);
                Vector3::new(f.sin(), (0.7 * f).cos(), 0.1 * f)
            })
            .collect();
        let target: Vec<Vector3<f64>> = source
            .iter()
            .map(|p| truth.transform_vector(p) + truth.translation.vector)
            .collect();
        let found = umeyama_se3(&source, &target).unwrap();
        assert!(
            (found.to_homogeneous() - truth.to_homogeneous())
                .abs()
                .max()
                < 1e-12
        );
    }

    #[test]
    fn aligned_ate_removes_a_rigid_offset_but_not_noise() {
        let stamps: Vec<f64> = (0..30).map(|i| f64::from(i) * 0.1).collect();
        let reference: Vec<Vector3<f64>> = stamps
            .iter()
            .map(|&t| Vector3::new(t.cos(), t.sin(), 0.2 * t))
            .collect();
        let motion = Isometry3::new(Vector3::new(1.0, 2.0, 3.0), Vector3::new(0.1, 0.2, 0.3));
        let moved: Vec<Vector3<f64>> = reference
            .iter()
            .map(|p| motion.transform_vector(p) + motion.translation.vector)
            .collect();
        let r = trajectory(&stamps, &reference);
        let e = trajectory(&stamps, &moved);
        let aligned = ate(&r, &e, AteOptions::default()).unwrap();
        assert!(aligned.rmse < 1e-12, "{}", aligned.rmse);
        assert_eq!(aligned.pairs, 30);
        // unaligned: a pure translation offset of (0.3, 0, 0.4) has error 0.5 everywhere
        let shifted: Vec<Vector3<f64>> = reference
            .iter()
            .map(|p| p + Vector3::new(0.3, 0.0, 0.4))
            .collect();
        let raw = ate(
            &r,
            &trajectory(&stamps, &shifted),
            AteOptions {
                align: false,
                ..AteOptions::default()
            },
        )
        .unwrap();
        assert!((raw.rmse - 0.5).abs() < 1e-12 && (raw.max - 0.5).abs() < 1e-12);
    }

    #[test]
    fn collinear_and_single_poses_still_align() {
        // Reference on the x axis at 0, 1, 2; estimate on the y axis at 5 + (0, 1.2, 2.4): the
        // best rigid fit lays the lines on each other with centres matched, leaving errors
        // 0.2, 0, 0.2 → RMSE √(0.08/3). (evo refuses rank-1 positions.)
        let stamps = [0.0, 1.0, 2.0];
        let r = trajectory(
            &stamps,
            &[Vector3::zeros(), Vector3::x(), 2.0 * Vector3::x()],
        );
        let e = trajectory(
            &stamps,
            &[
                Vector3::new(0.0, 5.0, 0.0),
                Vector3::new(0.0, 6.2, 0.0),
                Vector3::new(0.0, 7.4, 0.0),
            ],
        );
        let result = ate(&r, &e, AteOptions::default()).unwrap();
        assert!(
            (result.rmse - (0.08f64 / 3.0).sqrt()).abs() < 1e-12,
            "{}",
            result.rmse
        );
        let one = trajectory(&[0.0], &[Vector3::new(1.0, 2.0, 3.0)]);
        let other = trajectory(&[0.0], &[Vector3::new(-4.0, 0.5, 9.0)]);
        assert!(ate(&one, &other, AteOptions::default()).unwrap().rmse < 1e-12);
    }

    #[test]
    fn association_follows_evo() {
        let r = trajectory(&[0.0, 1.0, 2.0, 3.0], &[Vector3::zeros(); 4]);
        // 0.995 → 1.0 (|0.005|); 2.02 is 0.02 from 2.0 → dropped; 2.995 → 3.0
        let e = trajectory(&[0.995, 2.02, 2.995], &[Vector3::zeros(); 3]);
        assert_eq!(associate(&r, &e, 0.01).unwrap(), vec![(1, 0), (3, 2)]);
        // equal lengths: the estimate is the short side; tie goes to the earlier stamp
        let e2 = trajectory(&[0.5, 1.005, 2.0, 10.0], &[Vector3::zeros(); 4]);
        assert_eq!(
            associate(&r, &e2, 0.5).unwrap(),
            vec![(0, 0), (1, 1), (2, 2)]
        );
        // unsorted reference uses the linear search and finds the same pairs
        let unsorted = trajectory(&[3.0, 1.0, 2.0, 0.0], &[Vector3::zeros(); 4]);
        assert_eq!(
            associate(&unsorted, &e, 0.01).unwrap(),
            vec![(1, 0), (0, 2)]
        );
    }

    #[test]
    fn bad_inputs_are_named() {
        let r = trajectory(&[0.0, 1.0], &[Vector3::zeros(), Vector3::x()]);
        let e = ate(&r, &Trajectory::default(), AteOptions::default())
            .unwrap_err()
            .to_string();
        assert!(e.contains("estimate trajectory holds no pose"), "{e}");
        let far = trajectory(&[5.0, 6.0], &[Vector3::zeros(), Vector3::x()]);
        let e = ate(&r, &far, AteOptions::default())
            .unwrap_err()
            .to_string();
        assert!(e.contains("no common timestamps"), "{e}");
        let mut nan = r.clone();
        nan.poses[1].translation.vector.y = f64::NAN;
        let e = ate(&r, &nan, AteOptions::default())
            .unwrap_err()
            .to_string();
        assert!(e.contains("estimate") && e.contains("pose 1"), "{e}");
    }
}
