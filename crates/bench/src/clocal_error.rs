//! `activemap bench clocal-error` (issue 34), the localisation counterpart of `bench eig-psnr`:
//! does the scorer's localisation cost `C_local` (SPEC §5) predict where the tracker errs?
//!
//! In a partly mapped house ([`crate::house_map`], built with a tracking session beside it),
//! `paths` goal poses are drawn uniformly in the estimated free space; to each, the shortest
//! path of the planning library is planned from the robot's pose and driven by the path
//! executor on the simulator (steered by the true pose, so every path is the planned one
//! whatever the tracking does), while a copy of the house's tracking session tracks every frame
//! with the commanded action as its motion prior and the house's map as its snapshot: the very
//! session the `tracker` operator holds, moved on from the robot's current pose.
//!
//! Every `window` frames along a path the tracking error is the error of the estimated motion
//! over the last `window` frames against the true one (`(T_{i−w}⁻¹ T_i)⁻¹ (E_{i−w}⁻¹ E_i)`:
//! translation in cm, rotation in degrees): what the frames near the pose cost, not the drift
//! accumulated before them. At the same (true) pose the scorer's view of the map gives `C_local`
//! ([`FisherScorer::pose_localisation`]) and the other candidates: the smallest eigenvalue of
//! the pose information, the Gaussians in view, the uncovered pixels, and the information a dense
//! depth alignment gets from the map's rendered depth there
//! ([`depth_pose_information`]: point-to-plane Jacobians weighted by the sensor's depth noise). Spearman ρ of each with
//! the error says which one predicts it; a useful cost is positively correlated (high cost,
//! high error).

use std::fmt::Write as _;
use std::sync::Arc;

use activemap_active::candidates::sample_free_space_poses;
use activemap_active::information::{DepthNoiseModel, depth_pose_information, surface_depth};
use activemap_active::{FisherConfig, FisherScorer, GoalRequest, PoseLocalisation};
use activemap_geometry::frames::planar_from_camera_pose;
use activemap_geometry::se3::pose_error;
use activemap_geometry::{Isometry3, PlanarPose};
use activemap_planning::astar::AstarConfig;
use activemap_planning::clearance::{ClearanceConfig, ClearanceMap};
use activemap_planning::executor::{Decision, ExecutorConfig, PathExecutor};
use activemap_planning::path::shortest_path_on;
use activemap_sim::Action as SimAction;
use activemap_slam::{Frame, MotionPrior};
use activemap_splat::{Camera, FLAG_UNKNOWN_SPACE, RenderOptions, render};
use anyhow::Context as _;
use nalgebra::Matrix6;
use nalgebra::{Point2, Vector2};
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use rayon::prelude::*;

use crate::house_map::HouseMap;
use crate::scatter::{self, Scatter};
use crate::stats::{quantile, quantile_table, quartiles_by, spearman};

/// How the benchmark samples.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ClocalConfig {
    /// Goal poses, one path each.
    pub paths: usize,
    /// Seed of the goal draw (and of each path's actuation and sensor noise).
    pub seed: u64,
    /// Frames per error window, and the spacing of the sampled poses along a path.
    pub window: usize,
    /// Most steps driven along one path.
    pub max_steps_per_path: usize,
}

impl Default for ClocalConfig {
    fn default() -> Self {
        Self {
            paths: 40,
            seed: 2025,
            window: 5,
            max_steps_per_path: 150,
        }
    }
}

/// One sampled pose along a path.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Sample {
    /// The path it lies on.
    pub path: usize,
    /// Its frame along the path (from 1).
    pub step: usize,
    /// The true planar pose.
    pub pose: PlanarPose,
    /// The map's localisation terms there (the scorer's view).
    pub localisation: PoseLocalisation,
    /// Translation error of the estimated motion over the window ending here, metres.
    pub error_m: f64,
    /// Its rotation error, degrees.
    pub error_deg: f64,
    /// Frames of the window the tracker reported lost.
    pub lost: usize,
    /// log det of the depth alignment's pose information at the pose
    /// ([`depth_pose_information`] of the map's rendered depth).
    pub depth_log_det: f64,
    /// Its smallest eigenvalue.
    pub depth_smallest_eigenvalue: f64,
}

/// One candidate predictor of the error and how it ranks with it.
#[derive(Debug, Clone, PartialEq)]
pub struct Predictor {
    /// Its name in the table.
    pub name: &'static str,
    /// Spearman ρ with the translation error over the samples where it is finite.
    pub spearman: Option<f64>,
    /// Samples with a finite value.
    pub finite: usize,
}

/// What the benchmark measured.
#[derive(Debug, Clone, PartialEq)]
pub struct ClocalError {
    /// Every sampled pose.
    pub samples: Vec<Sample>,
    /// The candidates, `C_local` first.
    pub predictors: Vec<Predictor>,
    /// Paths driven (goals with no path are skipped).
    pub paths: usize,
    /// Frames tracked along them.
    pub frames: usize,
    /// Of which reported lost.
    pub lost_frames: usize,
    /// Gaussians of the map.
    pub gaussians: usize,
}

/// The frames of one driven path: true and estimated camera poses, per frame lost or not
/// (index 0: the start).
struct Drive {
    truth: Vec<Isometry3<f64>>,
    estimates: Vec<Isometry3<f64>>,
    lost: Vec<bool>,
}

/// Drives the path `waypoints` from the house's last pose on a fresh simulator of the house
/// (noise seed `seed`) with a copy of the house's tracking session.
fn drive(
    house: &HouseMap,
    waypoints: &[PlanarPose],
    config: &ClocalConfig,
    seed: u64,
) -> anyhow::Result<Drive> {
    let session = house
        .tracking
        .as_ref()
        .context("the house map was built without a tracking session")?;
    let mut session = session.clone();
    let mut sim_config = house.sim_config.clone();
    sim_config.seed = seed;
    let mut sim = house.scene.simulator(sim_config)?;
    sim.set_planar_pose(house.sim.true_planar_pose())?;
    let robot = house.sim_config.robot;
    let mut executor = PathExecutor::new(
        ExecutorConfig {
            initial_spin_steps: 0,
            ..ExecutorConfig::default()
        },
        robot,
    )?;
    executor.set_path(waypoints)?;
    let map = house.gaussians.clone();
    let mut frame_id = house.frame_id;
    let mut out = Drive {
        truth: vec![house.pose],
        estimates: vec![session.pose()],
        lost: vec![false],
    };
    for _ in 0..config.max_steps_per_path {
        let here = planar_from_camera_pose(&sim.true_pose());
        let action = match executor.decide(&here, &house.grid, false)? {
            Decision::Act(a) => a,
            // Replan: the path is done (or blocked).
            Decision::Replan(_) => break,
        };
        session.add_motion(frame_id, MotionPrior::Relative(robot.camera_motion(action)));
        sim.step(match action {
            activemap_planning::dynamics::Action::Forward => SimAction::Forward,
            activemap_planning::dynamics::Action::TurnLeft => SimAction::TurnLeft,
            activemap_planning::dynamics::Action::TurnRight => SimAction::TurnRight,
        });
        session.add_map(frame_id, Arc::clone(&map));
        frame_id += 1;
        let rgbd = sim.render();
        let frame = Frame::from_rgb8(
            rgbd.intrinsics,
            &rgbd.rgb,
            rgbd.depth,
            frame_id as f64 * 0.1,
        )?;
        session.add_frame(frame_id, frame);
        let tracked = session.process_ready()?;
        let t = tracked
            .last()
            .context("the tracking session returned no estimate for a complete frame")?;
        out.truth.push(sim.true_pose());
        out.estimates.push(t.pose);
        out.lost.push(t.status.is_lost());
    }
    Ok(out)
}

/// Runs the benchmark on `house` (built with a tracking session) with the scorer settings
/// `fisher`.
pub fn run(
    house: &HouseMap,
    fisher: &FisherConfig,
    config: &ClocalConfig,
) -> anyhow::Result<ClocalError> {
    anyhow::ensure!(
        config.paths >= 1 && config.window >= 1,
        "bench clocal-error: --paths and --window must be at least 1"
    );
    let robot = house.sim_config.robot;
    let grid = &house.grid;
    let clear = ClearanceMap::new(
        grid,
        &ClearanceConfig::for_disc(robot.radius_m, grid.geometry.resolution)?,
    )?;
    let mut rng = ChaCha8Rng::seed_from_u64(config.seed);
    let goals = sample_free_space_poses(&clear, config.paths, &mut rng);
    let start = planar_from_camera_pose(&house.pose);
    let astar = AstarConfig::default();
    let mut plans = Vec::new();
    for (k, goal) in goals.iter().enumerate() {
        let Ok(cell) = grid
            .geometry
            .require_cell(Point2::new(goal.x, goal.y), "goal")
        else {
            continue;
        };
        let look_at = Point2::new(goal.x, goal.y) + Vector2::new(goal.yaw.cos(), goal.yaw.sin());
        if let Some(path) = shortest_path_on(
            &clear,
            grid,
            Point2::new(start.x, start.y),
            cell,
            look_at,
            &astar,
        )? {
            plans.push((k, path.waypoints));
        }
    }
    anyhow::ensure!(
        !plans.is_empty(),
        "bench clocal-error: no goal drawn in the free space has a path from the robot"
    );
    let drives: Vec<(usize, Drive)> = plans
        .par_iter()
        .map(|(k, waypoints)| {
            drive(house, waypoints, config, config.seed + 1 + *k as u64)
                .map(|d| (*k, d))
                .with_context(|| format!("bench clocal-error: path {k}"))
        })
        .collect::<anyhow::Result<_>>()?;
    let mut samples = Vec::new();
    let mut poses = Vec::new();
    let (mut frames, mut lost_frames) = (0, 0);
    for (k, d) in &drives {
        frames += d.truth.len() - 1;
        lost_frames += d.lost.iter().filter(|l| **l).count();
        let w = config.window;
        let mut i = w;
        while i < d.truth.len() {
            let truth = d.truth[i - w].inverse() * d.truth[i];
            let estimate = d.estimates[i - w].inverse() * d.estimates[i];
            let (metres, radians) = pose_error(&estimate, &truth);
            let pose = planar_from_camera_pose(&d.truth[i]);
            poses.push(pose);
            samples.push(Sample {
                path: *k,
                step: i,
                pose,
                localisation: PoseLocalisation {
                    c_local: f64::NAN,
                    smallest_eigenvalue: f64::NAN,
                    visible_gaussians: 0,
                    low_opacity_pixels: 0,
                },
                error_m: metres,
                error_deg: radians.to_degrees(),
                lost: d.lost[i + 1 - w..=i].iter().filter(|l| **l).count(),
                depth_log_det: f64::NAN,
                depth_smallest_eigenvalue: f64::NAN,
            });
            i += w;
        }
    }
    anyhow::ensure!(
        !samples.is_empty(),
        "bench clocal-error: the paths are shorter than one window of {} frames",
        config.window
    );
    let map = house.scoring_map();
    let input = house.replan_input(&map, GoalRequest::Refine);
    let camera = house.sim_config.intrinsics;
    let mut scorer =
        FisherScorer::new(fisher.clone(), robot, camera).context("bench clocal-error")?;
    let terms = scorer
        .pose_localisation(&input, &poses)
        .context("bench clocal-error: localisation terms")?;
    for (s, t) in samples.iter_mut().zip(terms) {
        s.localisation = t;
    }
    // The depth alignment's information at each pose, from the map's rendered depth (the
    // composited depth over the opacity where the map covers the pixel).
    let floor_z = house.pose.translation.z - robot.camera_height_m;
    let options = RenderOptions {
        exclude_flags: FLAG_UNKNOWN_SPACE,
        ..RenderOptions::default()
    };
    let noise = DepthNoiseModel::default();
    let depth_info: Vec<Matrix6<f64>> = samples
        .par_iter()
        .map(|s| {
            let pose = robot.camera_pose(&s.pose, floor_z);
            let out = render(
                &house.gaussians,
                &Camera::from_world_pose(camera, &pose),
                &options,
            )?;
            Ok(depth_pose_information(
                &surface_depth(&out),
                &camera,
                &noise,
            ))
        })
        .collect::<anyhow::Result<_>>()?;
    for (s, info) in samples.iter_mut().zip(&depth_info) {
        let symmetric = (info + info.transpose()) * 0.5;
        let values = nalgebra::SymmetricEigen::new(symmetric).eigenvalues;
        s.depth_log_det = values.iter().map(|v| v.max(1e-300).ln()).sum();
        s.depth_smallest_eigenvalue = values.min();
    }
    let predictor = |name, value: &dyn Fn(&Sample) -> f64| {
        let (x, y): (Vec<f64>, Vec<f64>) = samples
            .iter()
            .map(|s| (value(s), s.error_m))
            .filter(|(x, _)| x.is_finite())
            .unzip();
        Predictor {
            name,
            spearman: spearman(&x, &y),
            finite: x.len(),
        }
    };
    let predictors = vec![
        predictor("c_local", &|s| s.localisation.c_local),
        predictor("-log_smallest_eigenvalue", &|s| {
            -s.localisation.smallest_eigenvalue.ln()
        }),
        predictor("-visible_gaussians", &|s| {
            -(s.localisation.visible_gaussians as f64)
        }),
        predictor("low_opacity_pixels", &|s| {
            f64::from(s.localisation.low_opacity_pixels)
        }),
        predictor("-log_det_depth_information", &|s| -s.depth_log_det),
        predictor("-log_smallest_depth_eigenvalue", &|s| {
            -s.depth_smallest_eigenvalue.ln()
        }),
    ];
    Ok(ClocalError {
        samples,
        predictors,
        paths: drives.len(),
        frames,
        lost_frames,
        gaussians: house.gaussians.len(),
    })
}

impl ClocalError {
    /// The summary line `clocal_error spearman <ρ> poses <n>` (ρ of `C_local`, `nan` when
    /// undefined).
    pub fn summary(&self) -> String {
        format!(
            "clocal_error spearman {} poses {}",
            self.predictors[0]
                .spearman
                .map_or("nan".to_string(), |r| format!("{r:.3}")),
            self.samples.len()
        )
    }

    /// The table: quantiles of the error and of `C_local`, the error by `C_local` quartile,
    /// and the rank correlation of every candidate predictor.
    pub fn table(&self) -> String {
        let error_cm: Vec<f64> = self.samples.iter().map(|s| 100.0 * s.error_m).collect();
        let error_deg: Vec<f64> = self.samples.iter().map(|s| s.error_deg).collect();
        let finite: Vec<&Sample> = self
            .samples
            .iter()
            .filter(|s| s.localisation.c_local.is_finite())
            .collect();
        let c_local: Vec<f64> = finite.iter().map(|s| s.localisation.c_local).collect();
        let mut s = String::new();
        let _ = writeln!(
            s,
            "# {} poses every window along {} paths ({} frames tracked, {} lost); map of {} \
             Gaussians; {} poses where C_local is +inf (degenerate view)",
            self.samples.len(),
            self.paths,
            self.frames,
            self.lost_frames,
            self.gaussians,
            self.samples.len() - finite.len()
        );
        s.push_str(&quantile_table(
            &[
                ("error_cm", &error_cm),
                ("error_deg", &error_deg),
                ("c_local", &c_local),
            ],
            14,
            3,
        ));
        let _ = writeln!(
            s,
            "{:<18} {:>5} {:>12} {:>14} {:>12}",
            "c_local_quartile", "poses", "c_local_med", "error_cm_med", "error_cm_q90"
        );
        for (k, part) in quartiles_by(&c_local).iter().enumerate() {
            let c: Vec<f64> = part.iter().map(|&i| c_local[i]).collect();
            let e: Vec<f64> = part.iter().map(|&i| 100.0 * finite[i].error_m).collect();
            let _ = writeln!(
                s,
                "{:<18} {:>5} {:>12.3} {:>14.3} {:>12.3}",
                format!("Q{} (low→high)", k + 1),
                part.len(),
                quantile(&c, 0.5).unwrap_or(f64::NAN),
                quantile(&e, 0.5).unwrap_or(f64::NAN),
                quantile(&e, 0.9).unwrap_or(f64::NAN)
            );
        }
        let _ = writeln!(s, "{:<26} {:>8} {:>8}", "predictor", "spearman", "poses");
        for p in &self.predictors {
            let _ = writeln!(
                s,
                "{:<26} {:>8} {:>8}",
                p.name,
                p.spearman.map_or("nan".to_string(), |r| format!("{r:.3}")),
                p.finite
            );
        }
        s
    }

    /// Writes the scatter plot (x = C_local, y = error in cm) to `path`; poses whose C_local
    /// is +∞ are left out of the plot (and of ρ).
    pub fn write_plot(&self, path: &std::path::Path) -> anyhow::Result<()> {
        let points: Vec<(f64, f64)> = self
            .samples
            .iter()
            .map(|s| (s.localisation.c_local, 100.0 * s.error_m))
            .collect();
        let title = format!(
            "C-LOCAL VS TRACKING ERROR   {} POSES   SPEARMAN {}",
            self.samples.len(),
            self.predictors[0]
                .spearman
                .map_or("NAN".to_string(), |r| format!("{r:.3}"))
        );
        scatter::write_png(
            &Scatter {
                title: &title,
                x_label: "C-LOCAL",
                y_label: "ERROR OVER THE WINDOW (CM)",
                points: &points,
            },
            path,
        )
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::house_map::{HouseMapConfig, build};

    /// A tiny house (48² frames, 40 steps) built with a tracking session, three paths: the
    /// tracked frames along them are counted, each sample's window error is measured against
    /// the simulator's true poses (noise-free, the dense tracker's error is millimetres), every
    /// candidate predictor is ranked, and the summary line has the format. Without a
    /// tracking session the benchmark says so.
    #[test]
    fn the_tracking_session_is_driven_along_paths_and_its_error_ranked_against_c_local() {
        let mut mapping = activemap_slam::MappingConfig::default();
        mapping.mapper.iterations = 2;
        mapping.mapper.coarse_iterations = 1;
        let mut config = HouseMapConfig {
            tracking: Some(activemap_slam::TrackingConfig::default()),
            ..HouseMapConfig::new(1, 48, 40, mapping)
        };
        let house = build(&config).unwrap();
        assert!(house.describe(&config).contains("tracking session"));
        let session = house.tracking.as_ref().unwrap();
        assert_eq!(
            session.next_frame(),
            40,
            "every frame of the build was tracked"
        );
        let (drift, _) = pose_error(&session.pose(), &house.pose);
        assert!(drift < 0.05, "the build's tracking drifted {drift} m");
        let fisher = FisherConfig {
            mc_poses: 2,
            mc_refresh: 1,
            scoring_width: 8,
            ..FisherConfig::default()
        };
        let bench = ClocalConfig {
            paths: 3,
            seed: 7,
            window: 4,
            max_steps_per_path: 30,
        };
        let result = run(&house, &fisher, &bench).unwrap();
        assert!(result.paths >= 1 && result.frames >= 4, "{result:?}");
        assert_eq!(
            result.samples.len(),
            result
                .samples
                .iter()
                .map(|s| (s.path, s.step))
                .collect::<std::collections::BTreeSet<_>>()
                .len()
        );
        assert!(
            result
                .samples
                .iter()
                .all(|s| s.step % 4 == 0 && s.lost <= 4)
        );
        let errors: Vec<f64> = result.samples.iter().map(|s| s.error_m).collect();
        assert!(errors.iter().all(|e| e.is_finite() && *e >= 0.0));
        assert!(quantile(&errors, 0.5).unwrap() < 0.02, "{errors:?}");
        let names: Vec<&str> = result.predictors.iter().map(|p| p.name).collect();
        assert_eq!(
            names,
            [
                "c_local",
                "-log_smallest_eigenvalue",
                "-visible_gaussians",
                "low_opacity_pixels",
                "-log_det_depth_information",
                "-log_smallest_depth_eigenvalue"
            ]
        );
        let summary = result.summary();
        let fields: Vec<&str> = summary.split(' ').collect();
        assert_eq!(
            (fields[0], fields[1], fields[3]),
            ("clocal_error", "spearman", "poses")
        );
        assert_eq!(fields[4], result.samples.len().to_string());
        assert!(result.table().contains("c_local_quartile"));
        // The same draw gives the same result.
        assert_eq!(run(&house, &fisher, &bench).unwrap(), result);

        config.tracking = None;
        config.max_steps = 5;
        let untracked = build(&config).unwrap();
        let e = run(&untracked, &fisher, &bench).unwrap_err();
        assert!(
            format!("{e:#}").contains("without a tracking session"),
            "{e:#}"
        );
    }
}
