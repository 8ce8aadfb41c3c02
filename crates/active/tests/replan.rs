//! Whole replans of the Fisher scorer on a synthetic half-mapped room: a frontier goal and a
//! refine goal each get a path with finite objective, every stage leaves its intermediates,
//! the model Fisher is reused on an unchanged map, and a replan repeats exactly (seeded).

use std::sync::Arc;

use activemap_active::scorer::ScoringMap;
use activemap_active::{
    FisherConfig, FisherScorer, GoalRequest, ModelFisherSource, PathObjective, ReplanInput,
};
use activemap_geometry::{Intrinsics, PlanarPose, RobotModel};
use activemap_planning::{Cell, CellState, GridGeometry, OccupancyGrid};
use activemap_splat::Gaussians;
use nalgebra::Point2;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

/// A 4 × 3 m room: walls and floor of textured Gaussians over the mapped part x < 2.2 m;
/// the grid is free there, unknown beyond, walls occupied.
fn room() -> (OccupancyGrid, ScoringMap) {
    let geometry = GridGeometry::new(0.0, 0.0, 0.05, 80, 60).unwrap();
    let mut grid = OccupancyGrid::filled(geometry, CellState::Unknown);
    for y in 0..60 {
        for x in 0..80 {
            let c = Cell::new(x, y);
            let wall = x == 0 || y == 0 || y == 59 || x == 79;
            let state = if wall && x < 44 {
                CellState::Occupied
            } else if x < 44 {
                CellState::Free
            } else {
                CellState::Unknown
            };
            grid.set(c, state);
        }
    }
    let mut rng = ChaCha8Rng::seed_from_u64(3);
    let mut map = Gaussians::<f32>::new();
    let mut put = |p: [f64; 3], rng: &mut ChaCha8Rng| {
        let rgb = [
            rng.random::<f64>(),
            rng.random::<f64>(),
            rng.random::<f64>(),
        ];
        map.push(p, rgb, [1.0, 0.0, 0.0, 0.0], 0.8, [0.03; 3]);
    };
    let step = 0.06;
    for i in 0..(2.2f64 / step) as usize {
        let x = i as f64 * step;
        for k in 0..(2.0f64 / step) as usize {
            let z = k as f64 * step;
            put([x, 0.0, z], &mut rng);
            put([x, 3.0, z], &mut rng);
        }
        for k in 0..(3.0f64 / step) as usize {
            put([x, k as f64 * step, 0.0], &mut rng);
        }
    }
    for j in 0..(3.0f64 / step) as usize {
        for k in 0..(2.0f64 / step) as usize {
            put([0.0, j as f64 * step, k as f64 * step], &mut rng);
        }
    }
    let ids: Vec<u64> = (0..map.len() as u64).collect();
    (
        grid,
        ScoringMap {
            gaussians: Arc::new(map),
            ids: Arc::new(ids),
            frame_id: 40,
        },
    )
}

fn scorer(config: FisherConfig) -> FisherScorer {
    let camera = Intrinsics::from_hfov(160, 160, 90f64.to_radians());
    FisherScorer::new(config, RobotModel::default(), camera).unwrap()
}

fn config() -> FisherConfig {
    FisherConfig {
        model_fisher: ModelFisherSource::McFreeSpace,
        candidates: 64,
        top_candidates: 6,
        mc_poses: 8,
        mc_refresh: 4,
        unknown_per_cell: 20,
        ..FisherConfig::default()
    }
}

/// A frontier replan at frame 50 from (0.8, 1.5) facing +x, toward the unknown half at
/// (2.3, 1.5).
fn frontier_replan<'a>(grid: &'a OccupancyGrid, map: &'a ScoringMap) -> ReplanInput<'a> {
    ReplanInput {
        frame_id: 50,
        grid,
        pose: RobotModel::default().camera_pose(&PlanarPose::new(0.8, 1.5, 0.0), 0.0),
        map,
        goal: GoalRequest::Frontier {
            focus: Point2::new(2.3, 1.5),
        },
    }
}

#[test]
fn a_frontier_replan_leaves_every_stage_and_repeats_exactly() {
    let (grid, map) = room();
    let input = frontier_replan(&grid, &map);
    let mut a = scorer(config());
    let first = a.replan(&input).unwrap();
    assert!(!first.refine && !first.model_reused);
    assert!(first.unknown_gaussians > 0 && first.unknown_gaussians.is_multiple_of(20));
    assert!(!first.candidates.is_empty() && first.candidates.len() <= 64);
    assert!(first.candidates.windows(2).all(|w| w[0].eig >= w[1].eig));
    for c in &first.candidates {
        let d = (c.pose.x - 2.3).hypot(c.pose.y - 1.5);
        assert!((0.3 - 1e-9..=1.0 + 1e-9).contains(&d), "candidate at {d} m");
    }
    assert!(!first.paths.is_empty() && first.paths.len() <= 6);
    let chosen = first.chosen.expect("a path with a finite objective");
    let best = &first.paths[chosen];
    assert!(best.objective.is_finite());
    assert!(first.paths.iter().all(|p| p.objective >= best.objective));
    assert_eq!(best.eig.len(), best.scored_steps.len());
    assert!(best.eig.iter().all(|e| *e > 0.0));
    assert!(best.c_local.iter().all(|c| c.is_finite()));
    let path = first.path.as_ref().unwrap();
    assert_eq!(path.waypoints, best.waypoints);

    // The same replan on a fresh scorer repeats exactly; on the same scorer the model is
    // reused (same snapshot, same frontier).
    let mut b = scorer(config());
    let again = b.replan(&input).unwrap();
    assert_eq!(again.paths, first.paths);
    assert_eq!(again.candidates, first.candidates);
    let reused = a.replan(&input).unwrap();
    assert!(reused.model_reused);
    let newer = ScoringMap {
        frame_id: 45,
        ..map.clone()
    };
    let changed = a
        .replan(&ReplanInput {
            map: &newer,
            ..input.clone()
        })
        .unwrap();
    assert!(!changed.model_reused);
    assert_eq!(a.model().views(), 8, "N views kept after a refresh of 4");
}

#[test]
fn the_unknown_seed_redraws_unknown_space_on_the_same_candidates() {
    // `unknown_seed` changes the unknown-space draw only: the candidate poses stay (the
    // replan's other draws do not depend on it) while their EIGs move, since the unknown
    // space past the frontier is what the candidates look at.
    let (grid, map) = room();
    let input = frontier_replan(&grid, &map);
    let base = scorer(config()).replan(&input).unwrap();
    let other = scorer(FisherConfig {
        unknown_seed: 1,
        ..config()
    })
    .replan(&input)
    .unwrap();
    assert_eq!(other.unknown_gaussians, base.unknown_gaussians);
    let poses = |o: &activemap_active::ReplanOutcome| {
        let mut p: Vec<[u64; 3]> = o
            .candidates
            .iter()
            .map(|c| [c.pose.x.to_bits(), c.pose.y.to_bits(), c.pose.yaw.to_bits()])
            .collect();
        p.sort_unstable();
        p
    };
    assert_eq!(poses(&base), poses(&other), "the same candidate poses");
    let eig = |o: &activemap_active::ReplanOutcome, pose: &PlanarPose| {
        o.candidates.iter().find(|c| c.pose == *pose).unwrap().eig
    };
    let moved = base
        .candidates
        .iter()
        .filter(|c| eig(&other, &c.pose) != c.eig)
        .count();
    assert!(moved > base.candidates.len() / 2, "{moved} EIGs moved");
}

#[test]
fn refine_and_the_ablation_objectives_get_paths() {
    let (grid, map) = room();
    let robot = RobotModel::default();
    let pose = robot.camera_pose(&PlanarPose::new(0.8, 1.5, 0.3), 0.0);
    let refine = ReplanInput {
        frame_id: 60,
        grid: &grid,
        pose,
        map: &map,
        goal: GoalRequest::Refine,
    };
    let out = scorer(config()).replan(&refine).unwrap();
    assert!(out.refine);
    let focus = out.focus.expect("a refine cluster");
    assert!(focus[0] > -0.5 && focus[0] < 2.7 && focus[1] > -0.5 && focus[1] < 3.5);
    assert!(out.path.is_some(), "{:?}", out.note);
    for objective in [PathObjective::EigOnly, PathObjective::Release] {
        let out = scorer(FisherConfig {
            objective,
            ..config()
        })
        .replan(&ReplanInput {
            goal: GoalRequest::Frontier {
                focus: Point2::new(2.3, 1.0),
            },
            ..refine.clone()
        })
        .unwrap();
        assert!(out.path.is_some(), "{objective:?}: {:?}", out.note);
    }
}

/// The choice ablations: `first` takes the best-EIG candidate's path, `random` a path the paper
/// objective does not refuse, the same one for the same frame; both report the paper objective.
#[test]
fn the_first_and_random_ablations_choose_among_the_paper_scored_paths() {
    let (grid, map) = room();
    let robot = RobotModel::default();
    let input = ReplanInput {
        frame_id: 61,
        grid: &grid,
        pose: robot.camera_pose(&PlanarPose::new(0.8, 1.5, 0.3), 0.0),
        map: &map,
        goal: GoalRequest::Frontier {
            focus: Point2::new(2.3, 1.0),
        },
    };
    let run = |objective| {
        scorer(FisherConfig {
            objective,
            ..config()
        })
        .replan(&input)
        .unwrap()
    };
    let paper = run(PathObjective::Paper);
    let first = run(PathObjective::First);
    let objectives = |o: &activemap_active::ReplanOutcome| -> Vec<u64> {
        o.paths.iter().map(|p| p.objective.to_bits()).collect()
    };
    assert!(paper.paths.len() >= 2, "{:?}", paper.note);
    assert_eq!(objectives(&first), objectives(&paper), "scored alike");
    let finite: Vec<usize> = (0..paper.paths.len())
        .filter(|&i| paper.paths[i].objective.is_finite())
        .collect();
    assert_eq!(first.chosen, finite.first().copied());
    let best = finite.iter().copied().min_by(|&a, &b| {
        paper.paths[a]
            .objective
            .total_cmp(&paper.paths[b].objective)
    });
    assert_eq!(paper.chosen, best);
    let random = run(PathObjective::Random);
    let pick = random.chosen.expect("a finite path exists");
    assert!(finite.contains(&pick));
    assert_eq!(
        run(PathObjective::Random).chosen,
        Some(pick),
        "seeded per frame"
    );
    // Over frames, the random choice is not always the same path.
    let picks: std::collections::BTreeSet<usize> = (0..6)
        .filter_map(|k| {
            scorer(FisherConfig {
                objective: PathObjective::Random,
                ..config()
            })
            .replan(&ReplanInput {
                frame_id: 100 + k,
                ..input.clone()
            })
            .unwrap()
            .chosen
        })
        .collect();
    assert!(picks.len() >= 2, "{picks:?}");
}
