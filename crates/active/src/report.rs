//! The wire report of one Fisher replan ([`FisherReport`], recorded with every run) made from
//! the library's [`ReplanOutcome`]: the one conversion between the two definitions.

use activemap_schemas::{FisherCandidate, FisherPath, FisherReport, FisherTimings, PlanarPose2};

use crate::scorer::{ReplanOutcome, StageTimings};

/// One Fisher replan as its wire report, without a fallback (the caller that sends something
/// else than the Fisher path sets [`FisherReport::fallback`]).
impl From<&ReplanOutcome> for FisherReport {
    fn from(outcome: &ReplanOutcome) -> Self {
        let count = |n: usize| u32::try_from(n).unwrap_or(u32::MAX);
        let StageTimings {
            unknown_ms,
            model_ms,
            candidates_ms,
            paths_ms,
            path_scores_ms,
            total_ms,
        } = outcome.timings;
        FisherReport {
            frame_id: outcome.frame_id,
            refine: outcome.refine,
            focus: outcome.focus,
            candidates: outcome
                .candidates
                .iter()
                .map(|c| FisherCandidate {
                    x: c.pose.x,
                    y: c.pose.y,
                    yaw: c.pose.yaw,
                    eig: c.eig,
                })
                .collect(),
            paths: outcome
                .paths
                .iter()
                .map(|p| FisherPath {
                    goal: PlanarPose2 {
                        x: p.goal.x,
                        y: p.goal.y,
                        yaw: p.goal.yaw,
                    },
                    waypoints: count(p.waypoints.len()),
                    actions: count(p.actions),
                    scored_steps: p.scored_steps.iter().map(|&s| count(s)).collect(),
                    eig: p.eig.clone(),
                    c_local: p.c_local.clone(),
                    objective: p.objective,
                })
                .collect(),
            chosen: outcome
                .chosen
                .and_then(|i| i32::try_from(i).ok())
                .unwrap_or(-1),
            gaussians: outcome.gaussians as u64,
            unknown_gaussians: outcome.unknown_gaussians as u64,
            model_reused: outcome.model_reused,
            note: outcome.note.clone(),
            timings: FisherTimings {
                unknown_ms,
                model_ms,
                candidates_ms,
                paths_ms,
                path_scores_ms,
                total_ms,
            },
            fallback: None,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use activemap_geometry::PlanarPose;

    /// The report carries every candidate, path term and timing of the outcome, −1 when none
    /// was chosen, +∞ terms unchanged, and the fallback; it goes through the wire as it is.
    #[test]
    fn the_report_mirrors_the_outcome() {
        use crate::scorer::{CandidateScore, PathScore};
        let pose = PlanarPose::new(1.0, 2.0, 0.5);
        let mut outcome = ReplanOutcome {
            frame_id: 80,
            refine: true,
            focus: Some([1.5, 2.5]),
            path: None,
            chosen: None,
            candidates: vec![CandidateScore { pose, eig: 3.5 }],
            paths: vec![PathScore {
                goal: pose,
                waypoints: vec![pose, pose],
                actions: 14,
                scored_steps: vec![5, 10, 14],
                eig: vec![3.0, 2.0, 1.0],
                c_local: vec![-20.0, f64::INFINITY, -19.0],
                low_opacity: vec![0.0; 3],
                objective: f64::INFINITY,
            }],
            gaussians: 1200,
            unknown_gaussians: 200,
            model_reused: false,
            distinct_path_views: 3,
            note: Some("no path has a finite objective".into()),
            timings: StageTimings {
                unknown_ms: 1.0,
                model_ms: 2.0,
                candidates_ms: 3.0,
                paths_ms: 4.0,
                path_scores_ms: 5.0,
                total_ms: 15.0,
            },
        };
        let r = FisherReport {
            fallback: Some("look-around".into()),
            ..FisherReport::from(&outcome)
        };
        assert_eq!(
            (r.frame_id, r.refine, r.focus, r.chosen),
            (80, true, Some([1.5, 2.5]), -1)
        );
        assert_eq!(
            r.candidates,
            vec![FisherCandidate {
                x: 1.0,
                y: 2.0,
                yaw: 0.5,
                eig: 3.5
            }]
        );
        let p = &r.paths[0];
        assert_eq!(
            (p.waypoints, p.actions, p.scored_steps.clone()),
            (2, 14, vec![5, 10, 14])
        );
        assert_eq!(p.c_local[1], f64::INFINITY);
        assert_eq!(p.objective, f64::INFINITY);
        assert_eq!(
            (r.gaussians, r.unknown_gaussians, r.model_reused),
            (1200, 200, false)
        );
        assert_eq!(r.timings.path_scores_ms, 5.0);
        assert_eq!(r.timings.total_ms, 15.0);
        assert_eq!(r.fallback.as_deref(), Some("look-around"));
        let back: FisherReport = activemap_schemas::Payload::from_bytes(
            &activemap_schemas::Payload::to_bytes(&r).unwrap(),
        )
        .unwrap();
        assert_eq!(back, r);
        outcome.chosen = Some(0);
        assert_eq!(FisherReport::from(&outcome).chosen, 0);
    }
}
