//! Whether a run's figures mean anything (issue 16): the checks that turn silent nonsense — a
//! start pose that sees nothing, a robot that cannot move, an empty map, no floor to explore,
//! image metrics on empty ground-truth views — into [`RunWarning`]s.
//!
//! Any warning makes the run **invalid**. `summary.json` (the `evaluator` node) and
//! `metrics.json` (`activemap eval`) list the warnings under `warnings` and say
//! `"valid": false`; `metrics.md` and `report.html` say INVALID with the reasons and strike the
//! figures; `activemap bench results` leaves invalid runs out of its means and counts them. The
//! evaluator node and `activemap eval` print each warning on stderr as
//! `warning: RUN_DIR: invalid run: CODE: MESSAGE` ([`RunWarning::log_line`]).
//!
//! | code | when | checked by |
//! | --- | --- | --- |
//! | `start_sees_nothing` | the first RGB-D frame has < [`START_MIN_VALID_DEPTH`] valid depth pixels | evaluator node (its `rgbd` input) |
//! | `robot_cannot_move` | ≥ [`BLOCKED_MIN_FORWARDS`] forward moves of which ≥ [`BLOCKED_MIN_SHARE`] blocked, or a true path shorter than one forward step after ≥ [`STATIONARY_MIN_STEPS`] steps | evaluator node, `activemap eval` |
//! | `empty_map` | the final map holds no observed Gaussian | evaluator node, `activemap eval` (`map.ply`) |
//! | `no_reachable_floor` | the floor reachable from the start is < [`MIN_REACHABLE_FLOOR_M2`] | evaluator node |
//! | `empty_test_views` | more than [`EMPTY_VIEWS_MAX_SHARE`] of the test views have an empty ground truth (< [`VIEW_MIN_VALID_DEPTH`] valid depth) | `activemap eval` |
//! | `infinite_psnr` | the mean PSNR is +∞ (renders identical to the ground truth) | `activemap eval` |

use serde::{Deserialize, Serialize};

/// One reason why a run is invalid: a stable `code` (one of [`code`]) and a message with the
/// numbers.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
pub struct RunWarning {
    /// Stable machine-readable code, e.g. `robot_cannot_move`.
    pub code: String,
    /// What was measured, with the numbers.
    pub message: String,
}

impl RunWarning {
    /// A warning with `code` and `message`.
    pub fn new(code: &str, message: impl Into<String>) -> Self {
        Self {
            code: code.to_string(),
            message: message.into(),
        }
    }

    /// The stderr line of this warning for the run folder `run_dir`:
    /// `warning: RUN_DIR: invalid run: CODE: MESSAGE`.
    pub fn log_line(&self, run_dir: &std::path::Path) -> String {
        format!(
            "warning: {}: invalid run: {}: {}",
            run_dir.display(),
            self.code,
            self.message
        )
    }
}

/// The stable warning codes.
pub mod code {
    /// The first RGB-D frame sees (almost) nothing.
    pub const START_SEES_NOTHING: &str = "start_sees_nothing";
    /// Nearly every forward move was blocked, or the robot never left its start.
    pub const ROBOT_CANNOT_MOVE: &str = "robot_cannot_move";
    /// The final map holds no observed Gaussian.
    pub const EMPTY_MAP: &str = "empty_map";
    /// (Almost) no floor is reachable from the start: coverage is a ratio of nothing.
    pub const NO_REACHABLE_FLOOR: &str = "no_reachable_floor";
    /// Too many test views have an empty ground truth.
    pub const EMPTY_TEST_VIEWS: &str = "empty_test_views";
    /// The mean PSNR is +∞.
    pub const INFINITE_PSNR: &str = "infinite_psnr";
}

/// Least fraction of valid depth pixels (finite, > 0) in the first frame: below it the start
/// pose sees nothing (a scene loaded wrongly, a camera inside a wall or outside the mesh).
pub const START_MIN_VALID_DEPTH: f64 = 0.01;
/// Forward moves needed before the blocked share is judged (fewer say too little).
pub const BLOCKED_MIN_FORWARDS: u64 = 20;
/// Share of blocked forward moves from which the robot counts as unable to move.
pub const BLOCKED_MIN_SHARE: f64 = 0.9;
/// Steps after which a true path shorter than one forward step means the robot never left its
/// start (a full look-around takes 72 steps of the default 5° turn, so a healthy run can turn in
/// place for a while).
pub const STATIONARY_MIN_STEPS: u64 = 200;
/// Least navigable floor reachable from the start, m², for an exploration to mean anything
/// (below it, e.g. a wrongly placed scene, 2D coverage reads 100 % of a patch).
pub const MIN_REACHABLE_FLOOR_M2: f64 = 1.0;
/// Least fraction of valid ground-truth depth pixels for a test view to hold anything; emptier
/// views are left out of the image metrics (an empty map renders them exactly: PSNR +∞).
pub const VIEW_MIN_VALID_DEPTH: f64 = 0.01;
/// Largest share of empty test views (left out of the image metrics) for a valid run.
pub const EMPTY_VIEWS_MAX_SHARE: f64 = 0.05;

/// Fraction of `depth` pixels that are valid (finite and > 0); 0 for an empty image.
pub fn valid_depth_fraction(depth: &[f32]) -> f64 {
    if depth.is_empty() {
        return 0.0;
    }
    let valid = depth.iter().filter(|d| d.is_finite() && **d > 0.0).count();
    valid as f64 / depth.len() as f64
}

/// `start_sees_nothing` when the first frame (`frame_id`) has less than
/// [`START_MIN_VALID_DEPTH`] valid depth.
pub fn start_view(frame_id: u64, valid_depth: f64) -> Option<RunWarning> {
    (valid_depth < START_MIN_VALID_DEPTH).then(|| {
        RunWarning::new(
            code::START_SEES_NOTHING,
            format!(
                "the first frame ({frame_id}) has {:.2} % valid depth pixels (< {:.0} %): the \
                 start pose sees nothing (scene loaded or placed wrongly?)",
                valid_depth * 100.0,
                START_MIN_VALID_DEPTH * 100.0
            ),
        )
    })
}

/// `robot_cannot_move` when at least [`BLOCKED_MIN_FORWARDS`] forward moves were judged and at
/// least [`BLOCKED_MIN_SHARE`] of them were blocked, or when the true path is shorter than one
/// forward step (`forward_step_m`) after at least [`STATIONARY_MIN_STEPS`] steps.
pub fn motion(
    steps: u64,
    path_length_m: f64,
    forward_actions: u64,
    blocked_forwards: u64,
    forward_step_m: f64,
) -> Option<RunWarning> {
    let blocked = forward_actions >= BLOCKED_MIN_FORWARDS
        && blocked_forwards as f64 >= BLOCKED_MIN_SHARE * forward_actions as f64;
    let stationary = steps >= STATIONARY_MIN_STEPS && path_length_m < forward_step_m;
    (blocked || stationary).then(|| {
        let share = if forward_actions > 0 {
            format!(
                " ({:.0} %)",
                100.0 * blocked_forwards as f64 / forward_actions as f64
            )
        } else {
            String::new()
        };
        RunWarning::new(
            code::ROBOT_CANNOT_MOVE,
            format!(
                "{blocked_forwards} of {forward_actions} forward moves blocked{share}, true path \
                 {path_length_m:.2} m over {steps} steps (forward step {forward_step_m:.2} m): the \
                 robot cannot move"
            ),
        )
    })
}

/// `empty_map` when the final map holds no observed Gaussian (`unknown_space`: how many
/// unknown-space Gaussians it holds besides, which stand for unobserved volume).
pub fn map(observed_gaussians: usize, unknown_space: usize) -> Option<RunWarning> {
    (observed_gaussians == 0).then(|| {
        RunWarning::new(
            code::EMPTY_MAP,
            format!(
                "the final map holds 0 observed Gaussians ({unknown_space} unknown-space): \
                 nothing was mapped"
            ),
        )
    })
}

/// `no_reachable_floor` when the navigable floor reachable from the start is smaller than
/// [`MIN_REACHABLE_FLOOR_M2`].
pub fn reachable_floor(area_m2: f64) -> Option<RunWarning> {
    (area_m2 < MIN_REACHABLE_FLOOR_M2).then(|| {
        RunWarning::new(
            code::NO_REACHABLE_FLOOR,
            format!(
                "{area_m2:.2} m² of navigable floor is reachable from the start (< \
                 {MIN_REACHABLE_FLOOR_M2:.0} m²): 2D coverage is a ratio of (almost) nothing"
            ),
        )
    })
}

/// `empty_test_views` when more than [`EMPTY_VIEWS_MAX_SHARE`] of the `total` test views (or
/// every one) have an empty ground truth (`empty` of them).
pub fn test_views(empty: usize, total: usize) -> Option<RunWarning> {
    let too_many =
        empty > 0 && (empty == total || empty as f64 > EMPTY_VIEWS_MAX_SHARE * total as f64);
    too_many.then(|| {
        RunWarning::new(
            code::EMPTY_TEST_VIEWS,
            format!(
                "{empty} of {total} test views have an empty ground truth (< {:.0} % valid \
                 depth), more than {:.0} %: the scene renders (almost) nothing at the test poses; \
                 they are left out of PSNR, SSIM, LPIPS and depth MAE",
                VIEW_MIN_VALID_DEPTH * 100.0,
                EMPTY_VIEWS_MAX_SHARE * 100.0
            ),
        )
    })
}

/// `infinite_psnr` when the mean PSNR is +∞ (`infinite` of the `views` averaged rendered
/// exactly as the ground truth).
pub fn psnr(mean_db: Option<f64>, infinite: usize, views: usize) -> Option<RunWarning> {
    (mean_db == Some(f64::INFINITY)).then(|| {
        RunWarning::new(
            code::INFINITE_PSNR,
            format!(
                "mean PSNR is +∞: {infinite} of {views} test views render identical to the \
                 ground truth (empty images?)"
            ),
        )
    })
}

/// Appends the warnings of `more` whose code `into` does not hold yet (the first of a code
/// wins, so a warning recorded by the evaluator node is not repeated by `activemap eval`).
pub fn merge(into: &mut Vec<RunWarning>, more: impl IntoIterator<Item = RunWarning>) {
    for w in more {
        if !into.iter().any(|x| x.code == w.code) {
            into.push(w);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn each_check_fires_past_its_threshold_only() {
        // Start view: 1 % valid depth is enough.
        assert_eq!(
            start_view(0, 0.0).unwrap().code,
            "start_sees_nothing",
            "no valid depth"
        );
        assert!(start_view(0, 0.009).is_some());
        assert!(start_view(0, 0.01).is_none());
        assert!(start_view(0, 0.8).is_none());
        let w = start_view(3, 0.0042).unwrap();
        assert!(
            w.message.contains("(3)") && w.message.contains("0.42 %"),
            "{w:?}"
        );

        // The user's run: 206 of 206 forward moves blocked, 0 m.
        let w = motion(412, 0.0, 206, 206, 0.05).unwrap();
        assert_eq!(w.code, code::ROBOT_CANNOT_MOVE);
        assert!(
            w.message
                .contains("206 of 206 forward moves blocked (100 %)")
                && w.message.contains("0.00 m over 412 steps"),
            "{w:?}"
        );
        // 18 of 20 = 90 % fires, 17 of 20 does not, 19 of 19 is too few to judge.
        assert!(motion(100, 3.0, 20, 18, 0.05).is_some());
        assert!(motion(100, 3.0, 20, 17, 0.05).is_none());
        assert!(motion(100, 3.0, 19, 19, 0.05).is_none());
        // Never left the start after 200 steps (no action input: no forward counts).
        assert!(motion(200, 0.04, 0, 0, 0.05).is_some());
        assert!(motion(199, 0.0, 0, 0, 0.05).is_none(), "a long look-around");
        assert!(motion(200, 0.05, 0, 0, 0.05).is_none());
        // A healthy run.
        assert!(motion(336, 7.2, 147, 2, 0.05).is_none());

        let w = map(0, 1200).unwrap();
        assert_eq!(w.code, code::EMPTY_MAP);
        assert!(w.message.contains("1200 unknown-space"), "{w:?}");
        assert!(map(1, 0).is_none());

        assert_eq!(
            reachable_floor(0.25).unwrap().code,
            code::NO_REACHABLE_FLOOR
        );
        assert!(reachable_floor(1.0).is_none());

        // 5 % of the views may be empty; more, or all, may not.
        assert!(test_views(0, 100).is_none());
        assert!(test_views(5, 100).is_none());
        let w = test_views(6, 100).unwrap();
        assert_eq!(w.code, code::EMPTY_TEST_VIEWS);
        assert!(w.message.contains("6 of 100 test views"), "{w:?}");
        assert!(test_views(1, 1).is_some());
        assert!(test_views(0, 0).is_none());

        assert_eq!(
            psnr(Some(f64::INFINITY), 2, 4).unwrap().code,
            code::INFINITE_PSNR
        );
        assert!(psnr(Some(30.0), 0, 4).is_none());
        assert!(psnr(None, 0, 0).is_none());
    }

    #[test]
    fn valid_depth_counts_finite_positive_pixels() {
        assert_eq!(valid_depth_fraction(&[]), 0.0);
        assert_eq!(
            valid_depth_fraction(&[0.0, 1.0, f32::NAN, f32::INFINITY, -1.0, 2.5, 0.0, 3.0]),
            0.375
        );
    }

    #[test]
    fn merge_keeps_the_first_warning_of_each_code() {
        let mut w = vec![RunWarning::new(code::EMPTY_MAP, "from the evaluator")];
        merge(
            &mut w,
            [
                RunWarning::new(code::EMPTY_MAP, "from eval"),
                RunWarning::new(code::INFINITE_PSNR, "∞"),
            ],
        );
        assert_eq!(
            w,
            [
                RunWarning::new(code::EMPTY_MAP, "from the evaluator"),
                RunWarning::new(code::INFINITE_PSNR, "∞"),
            ]
        );
        assert_eq!(
            w[0].log_line(std::path::Path::new("runs/demo")),
            "warning: runs/demo: invalid run: empty_map: from the evaluator"
        );
    }
}
