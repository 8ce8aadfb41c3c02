//! One replan of the Fisher scorer end to end (SPEC §1 step 7, §5, §6): unknown-space
//! Gaussians above the frontier cells, the model Fisher `I(w)` (reused while the map is
//! unchanged, updated by id otherwise), K candidates around the goal (or the refine target),
//! their EIG, A* paths to the best, and the path that minimises the objective.
//!
//! The caller (the `scorer` operator, the benchmarks) owns the transport: it hands in the map
//! with its ids, the grid, the estimated pose and the goal, and gets the path with every
//! intermediate (candidates, per-pose terms, timings) for its report.

use std::sync::Arc;
use std::time::Instant;

use activemap_geometry::{Intrinsics, Isometry3, PlanarPose, RobotModel, planar_from_camera_pose};
use activemap_planning::clearance::{ClearanceConfig, ClearanceMap};
use activemap_planning::path::PlannedPath;
use activemap_planning::{Cell, OccupancyGrid};
use activemap_splat::Gaussians;
use nalgebra::Point2;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

use crate::ActiveError;
use crate::candidates::{sample_candidates, sample_free_space_poses};
use crate::config::{FisherConfig, ModelFisherSource, PathObjective};
use crate::information::{
    ScoringScene, ViewInformation, ViewParts, ViewSettings, eig, localisation_cost,
    view_information,
};
use crate::model::{ModelFisher, ModelSample};
use crate::paths::{FuturePath, future_path, objective, scored_steps, shared_path_terms};
use crate::refine::refine_target;
use crate::unknown::{UnknownSpace, frontier_region_cells, seed_unknown_space};

/// The map the scorer reads: the mapper's Gaussians with their stable ids (parallel arrays),
/// and the frame id of the snapshot (a new snapshot is a new version).
#[derive(Debug, Clone)]
pub struct ScoringMap {
    /// The Gaussians (real map only; the scorer adds the unknown-space ones itself).
    pub gaussians: Arc<Gaussians<f32>>,
    /// Stable id of each Gaussian (the mapper's; increasing as Gaussians are added).
    pub ids: Arc<Vec<u64>>,
    /// Frame id of the snapshot.
    pub frame_id: u64,
}

impl ScoringMap {
    /// Checks the arrays agree and every id is below [`crate::unknown::UNKNOWN_ID_BASE`].
    pub fn validate(&self) -> Result<(), ActiveError> {
        if self.ids.len() != self.gaussians.len() {
            return Err(ActiveError::Input {
                what: "scoring map",
                reason: format!(
                    "{} ids for {} Gaussians (frame {})",
                    self.ids.len(),
                    self.gaussians.len(),
                    self.frame_id
                ),
            });
        }
        if let Some(bad) = self
            .ids
            .iter()
            .find(|&&id| id >= crate::unknown::UNKNOWN_ID_BASE)
        {
            return Err(ActiveError::Input {
                what: "scoring map",
                reason: format!("id {bad} lies in the unknown-space id range"),
            });
        }
        Ok(())
    }
}

/// What the planner asked for.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum GoalRequest {
    /// Explore the frontier whose centroid (the goal's focus) is here, world metres.
    Frontier {
        /// The frontier's centroid.
        focus: Point2<f64>,
    },
    /// Refine what is mapped (no frontier left, or the planner answered −1).
    Refine,
}

/// The inputs of one replan.
#[derive(Debug, Clone)]
pub struct ReplanInput<'a> {
    /// Frame of the replan (mixed into the seed of every random draw).
    pub frame_id: u64,
    /// The occupancy grid of that frame.
    pub grid: &'a OccupancyGrid,
    /// The estimated camera pose `T_world_camera` of that frame (never ground truth).
    pub pose: Isometry3<f64>,
    /// The map snapshot the frame was gridded against.
    pub map: &'a ScoringMap,
    /// The goal.
    pub goal: GoalRequest,
}

/// A scored candidate goal pose.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct CandidateScore {
    /// The planar pose (facing the goal point).
    pub pose: PlanarPose,
    /// Its EIG against `I(w)`.
    pub eig: f64,
}

/// A path to one of the top candidates, with the terms of its objective.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct PathScore {
    /// The candidate it leads to.
    pub goal: PlanarPose,
    /// The waypoints (the path the follower would get).
    pub waypoints: Vec<PlanarPose>,
    /// Actions of the follower's rollout (before any cut).
    pub actions: usize,
    /// Index (1-based, in actions) of each scored pose.
    pub scored_steps: Vec<usize>,
    /// Path EIG of each scored pose, `EIG_i` against `I + Σ_{t<i} H(x_t)`.
    pub eig: Vec<f64>,
    /// `C_local` of each scored pose (+∞ where no Gaussian is seen or the information is
    /// degenerate).
    pub c_local: Vec<f64>,
    /// Low-opacity pixels of each scored pose's view, scaled to the frame camera (the
    /// release's coverage term, see [`FisherConfig::low_opacity_weight`]).
    #[serde(default)]
    pub low_opacity: Vec<f64>,
    /// The objective (lower is better; +∞ refuses the path).
    pub objective: f64,
}

/// Wall-clock milliseconds of each stage of a replan.
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize, Deserialize)]
pub struct StageTimings {
    /// Unknown-space seeding.
    pub unknown_ms: f64,
    /// Model Fisher update (0 when reused).
    pub model_ms: f64,
    /// Candidate sampling and their EIG.
    pub candidates_ms: f64,
    /// A* to the top candidates and the rollouts.
    pub paths_ms: f64,
    /// Path EIG and C_local along the paths.
    pub path_scores_ms: f64,
    /// The whole replan.
    pub total_ms: f64,
}

/// The localisation terms of one pose ([`FisherScorer::pose_localisation`]).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PoseLocalisation {
    /// `C_local = −log det` of the pose information (SPEC §5); +∞ for a degenerate view.
    pub c_local: f64,
    /// The pose information's smallest eigenvalue (0 for a view that sees nothing): the
    /// worst-constrained direction.
    pub smallest_eigenvalue: f64,
    /// Gaussians the view sees.
    pub visible_gaussians: usize,
    /// Pixels of the scoring render the map leaves uncovered (opacity below 0.5).
    pub low_opacity_pixels: u32,
}

/// What one replan decided, with every intermediate.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ReplanOutcome {
    /// Frame of the replan.
    pub frame_id: u64,
    /// Whether it refined (no frontier) rather than explored a frontier.
    pub refine: bool,
    /// The point the candidates face (frontier centroid or refine cluster centre).
    pub focus: Option<[f64; 2]>,
    /// The chosen path; `None` when no candidate has a finite objective.
    pub path: Option<PlannedPath>,
    /// Index into `paths` of the chosen one.
    pub chosen: Option<usize>,
    /// Every candidate that survived the free-space test, with its EIG (best first).
    pub candidates: Vec<CandidateScore>,
    /// The paths to the top candidates, with their terms.
    pub paths: Vec<PathScore>,
    /// Gaussians of the map and unknown-space Gaussians added for this replan.
    pub gaussians: usize,
    /// Unknown-space Gaussians of this replan.
    pub unknown_gaussians: usize,
    /// Whether `I(w)` was reused unchanged from the previous replan.
    pub model_reused: bool,
    /// Distinct poses rendered for the path scores (paths sharing their first moves share
    /// those views).
    #[serde(default)]
    pub distinct_path_views: usize,
    /// Why the replan fell back, when it did (no candidate, no path, no cluster).
    pub note: Option<String>,
    /// Stage timings.
    pub timings: StageTimings,
}

/// The scorer's state across replans: the model Fisher, the unknown-space Gaussians and the
/// previous candidates.
pub struct FisherScorer {
    config: FisherConfig,
    robot: RobotModel,
    camera: Intrinsics,
    view: ViewSettings,
    model: ModelFisher,
    /// `both`: the keyframe half of the model Fisher (`model` is the Monte-Carlo half).
    keyframe_model: Option<ModelFisher>,
    previous: Vec<PlanarPose>,
    unknown_cells: Vec<Cell>,
    unknown: UnknownSpace,
}

/// Actions a path's rollout may take at most (longer paths are followed, but scored only up
/// to here): 2000, the paper's whole episode.
const MAX_ROLLOUT: usize = 2000;

impl FisherScorer {
    /// A scorer for a robot whose camera has intrinsics `camera` (the frames' own; scoring
    /// renders scale them to `config.scoring_width`).
    pub fn new(
        config: FisherConfig,
        robot: RobotModel,
        camera: Intrinsics,
    ) -> Result<Self, ActiveError> {
        config.validate().map_err(ActiveError::Config)?;
        robot.validate().map_err(ActiveError::Config)?;
        if camera.width == 0 || camera.height == 0 || !(camera.fx > 0.0 && camera.fy > 0.0) {
            return Err(ActiveError::Config(format!(
                "camera intrinsics are unusable: {camera:?}"
            )));
        }
        Ok(Self {
            view: ViewSettings {
                localisation: config.localisation,
                ..ViewSettings::scaled(
                    &camera,
                    config.scoring_width,
                    config.far_m,
                    config.depth_weight,
                )
            },
            model: ModelFisher::new(&config),
            keyframe_model: (config.model_fisher == ModelFisherSource::Both)
                .then(|| ModelFisher::with_source(&config, ModelFisherSource::Keyframes)),
            config,
            robot,
            camera,
            previous: Vec::new(),
            unknown_cells: Vec::new(),
            unknown: UnknownSpace::default(),
        })
    }

    /// The settings.
    pub fn config(&self) -> &FisherConfig {
        &self.config
    }

    /// The frame camera the scorer was made for.
    pub fn camera(&self) -> &Intrinsics {
        &self.camera
    }

    /// The scoring views' settings (camera at the scoring resolution, far plane, depth weight).
    pub fn view_settings(&self) -> &ViewSettings {
        &self.view
    }

    /// The model Fisher as it stands.
    pub fn model(&self) -> &ModelFisher {
        &self.model
    }

    /// Tells the scorer that frame `frame_id` became a keyframe at the estimated pose `pose`
    /// (`T_world_camera`); the `keyframes` model Fisher adds its view on the next replan.
    pub fn add_keyframe(&mut self, frame_id: u64, pose: Isometry3<f64>) {
        match &mut self.keyframe_model {
            Some(k) => k.add_keyframe(frame_id, pose),
            None => self.model.add_keyframe(frame_id, pose),
        }
    }

    /// The scoring map of a replan: the map's Gaussians followed by the current unknown-space
    /// ones, with their ids.
    fn scoring_set(&self, map: &ScoringMap) -> (Gaussians<f32>, Vec<u64>) {
        let mut all = (*map.gaussians).clone();
        all.extend_from(&self.unknown.gaussians);
        let mut ids = Vec::with_capacity(all.len());
        ids.extend_from_slice(&map.ids);
        ids.extend_from_slice(&self.unknown.ids);
        (all, ids)
    }

    /// The views of `poses` (planar, on the floor at `floor_z`) on `map`, in order, with
    /// `parts` computed.
    fn views(
        &self,
        map: &ScoringScene<f32>,
        poses: &[PlanarPose],
        floor_z: f64,
        parts: ViewParts,
    ) -> Result<Vec<ViewInformation>, ActiveError> {
        poses
            .par_iter()
            .map(|p| view_information(map, &self.robot.camera_pose(p, floor_z), &self.view, parts))
            .collect()
    }

    /// Stages 1–2 of a replan: renews the unknown-space Gaussians when the frontier cells
    /// changed and brings the model Fisher up to date unless the map is unchanged.
    fn prepare(
        &mut self,
        input: &ReplanInput<'_>,
        rng: &mut ChaCha8Rng,
    ) -> Result<Prepared, ActiveError> {
        let mut timings = StageTimings::default();
        input.map.validate()?;
        let pose = &input.pose;
        if !(pose.translation.vector.iter().all(|v| v.is_finite())
            && pose.rotation.coords.iter().all(|v| v.is_finite()))
        {
            return Err(ActiveError::Input {
                what: "estimated pose",
                reason: format!("frame {} has a non-finite pose", input.frame_id),
            });
        }
        let grid = input.grid;
        let config = &self.config;
        let floor_z = pose.translation.z - self.robot.camera_height_m;
        let clearance = ClearanceConfig::for_disc(self.robot.radius_m, grid.geometry.resolution)?;
        let clear = ClearanceMap::new(grid, &clearance)?;

        // 1. Unknown space above the frontier cells, renewed when they change.
        let t = Instant::now();
        let start = planar_from_camera_pose(pose);
        let cells = frontier_region_cells(grid, &clear, Point2::new(start.x, start.y))?;
        if cells != self.unknown_cells || self.unknown.ids.is_empty() && !cells.is_empty() {
            let generation = self.unknown.generation.wrapping_add(1);
            let cam = floor_z + self.robot.camera_height_m;
            self.unknown = seed_unknown_space(
                grid,
                &cells,
                [cam - config.unknown_band_below_camera_m, cam],
                config.unknown_per_cell,
                config.unknown_max_scale_fraction,
                generation,
                rng.random::<u64>() ^ config.unknown_seed.wrapping_mul(0x9E37_79B9_7F4A_7C15),
            )?;
            self.unknown.generation = generation;
            self.unknown_cells = cells;
        }
        let (scoring, ids) = self.scoring_set(input.map);
        let scoring = ScoringScene::new(scoring);
        timings.unknown_ms = ms(t);

        // 2. The model Fisher, brought up to date unless the map is unchanged.
        let t = Instant::now();
        let generation = self.unknown.generation;
        let model_reused = self.model.is_current(input.map.frame_id, generation)
            && self
                .keyframe_model
                .as_ref()
                .is_none_or(|k| k.is_current(input.map.frame_id, generation));
        // The Monte-Carlo poses' own stream (one draw of the replan's, always taken so the
        // later draws do not depend on the model source), mixed with `model_seed`.
        let mut model_rng = ChaCha8Rng::seed_from_u64(
            rng.random::<u64>() ^ config.model_seed.wrapping_mul(0xD1B5_4A32_D192_ED03),
        );
        if !model_reused {
            // (planar pose, full pose of a keyframe, whether it goes to the keyframe half)
            let mut poses: Vec<(PlanarPose, Option<Isometry3<f64>>, bool)> =
                match self.model.source() {
                    ModelFisherSource::Keyframes => self
                        .model
                        .take_pending_keyframes()
                        .into_iter()
                        .map(|(_, p)| (planar_from_camera_pose(&p), Some(p), false))
                        .collect(),
                    _ => {
                        let n = if self.model.views() == 0 {
                            config.mc_poses
                        } else {
                            config.mc_refresh
                        };
                        sample_free_space_poses(&clear, n, &mut model_rng)
                            .into_iter()
                            .map(|p| (p, None, false))
                            .collect()
                    }
                };
            if let Some(k) = &mut self.keyframe_model {
                poses.extend(
                    k.take_pending_keyframes()
                        .into_iter()
                        .map(|(_, p)| (planar_from_camera_pose(&p), Some(p), true)),
                );
            }
            let samples: Vec<(ModelSample, bool)> = poses
                .par_iter()
                .map(|(planar, full, keyframe)| {
                    let camera = full.unwrap_or_else(|| self.robot.camera_pose(planar, floor_z));
                    view_information(&scoring, &camera, &self.view, ViewParts::Diagonal)
                        .map(|v| (ModelSample::from_view(&v, &ids, generation), *keyframe))
                })
                .collect::<Result<_, _>>()?;
            for (s, keyframe) in samples {
                match (&mut self.keyframe_model, keyframe) {
                    (Some(k), true) => k.push(s),
                    _ => self.model.push(s),
                }
            }
            self.model.mark_current(input.map.frame_id, generation);
            if let Some(k) = &mut self.keyframe_model {
                k.mark_current(input.map.frame_id, generation);
            }
        }
        let mut prior = self.model.prior(&ids, self.config.lambda);
        if let Some(k) = &self.keyframe_model {
            for (p, &id) in prior.iter_mut().zip(&ids) {
                for (p, v) in p.iter_mut().zip(k.information(id)) {
                    *p += v;
                }
            }
        }
        timings.model_ms = ms(t);
        Ok(Prepared {
            scoring,
            prior,
            clear,
            floor_z,
            model_reused,
            timings,
        })
    }

    /// The seeded generator of frame `frame_id`'s draws.
    fn rng(&self, frame_id: u64) -> ChaCha8Rng {
        ChaCha8Rng::seed_from_u64(self.config.seed ^ frame_id.wrapping_mul(0x9E37_79B9_7F4A_7C15))
    }

    /// The view EIG (against the model Fisher of this replan's map) of each of `poses` (planar,
    /// on the floor under the estimated camera): what a replan ranks its candidates by, for
    /// any poses (the EIG–PSNR benchmark samples them across the house).
    pub fn pose_eigs(
        &mut self,
        input: &ReplanInput<'_>,
        poses: &[PlanarPose],
    ) -> Result<Vec<f64>, ActiveError> {
        let (prepared, views) = self.prepared_views(input, poses, ViewParts::Diagonal)?;
        Ok(views
            .iter()
            .map(|v| eig(v, prepared.prior.as_slice()))
            .collect())
    }

    /// Stages 1–2 of a replan for `input`, then the views of `poses` (planar, on the floor
    /// under the estimated camera) with `parts`: what [`Self::pose_eigs`] and
    /// [`Self::pose_localisation`] evaluate at any poses.
    fn prepared_views(
        &mut self,
        input: &ReplanInput<'_>,
        poses: &[PlanarPose],
        parts: ViewParts,
    ) -> Result<(Prepared, Vec<ViewInformation>), ActiveError> {
        let mut rng = self.rng(input.frame_id);
        let prepared = self.prepare(input, &mut rng)?;
        let views = self.views(&prepared.scoring, poses, prepared.floor_z, parts)?;
        Ok((prepared, views))
    }

    /// What the map says of localisation at each of `poses` (planar, the camera at the robot's
    /// height above the estimated floor), as a replan's path scoring sees it: the views' pose
    /// information against the map's Gaussians (unknown space included, as in a replan), its
    /// `C_local` and the candidates `activemap bench clocal-error` compares it with.
    pub fn pose_localisation(
        &mut self,
        input: &ReplanInput<'_>,
        poses: &[PlanarPose],
    ) -> Result<Vec<PoseLocalisation>, ActiveError> {
        let (_, views) = self.prepared_views(input, poses, ViewParts::DiagonalAndPose)?;
        let ratio = self.config.degenerate_ratio;
        Ok(views
            .iter()
            .map(|v| {
                let (c_local, smallest) = match (&v.pose, v.is_empty()) {
                    (Some(pose), false) => {
                        let symmetric = (pose + pose.transpose()) * 0.5;
                        let smallest = nalgebra::SymmetricEigen::new(symmetric).eigenvalues.min();
                        (localisation_cost(pose, ratio), smallest)
                    }
                    _ => (f64::INFINITY, 0.0),
                };
                PoseLocalisation {
                    c_local,
                    smallest_eigenvalue: smallest,
                    visible_gaussians: v.diagonal.len(),
                    low_opacity_pixels: v.low_opacity_pixels,
                }
            })
            .collect())
    }

    /// One replan (see the module doc).
    pub fn replan(&mut self, input: &ReplanInput<'_>) -> Result<ReplanOutcome, ActiveError> {
        let started = Instant::now();
        let mut rng = self.rng(input.frame_id);
        let Prepared {
            scoring,
            prior,
            clear,
            floor_z,
            model_reused,
            timings,
        } = self.prepare(input, &mut rng)?;
        let config = self.config.clone();
        let grid = input.grid;
        let pose = &input.pose;
        let start = planar_from_camera_pose(pose);

        let mut outcome = ReplanOutcome {
            frame_id: input.frame_id,
            refine: matches!(input.goal, GoalRequest::Refine),
            focus: None,
            path: None,
            chosen: None,
            candidates: Vec::new(),
            paths: Vec::new(),
            gaussians: input.map.gaussians.len(),
            unknown_gaussians: self.unknown.ids.len(),
            model_reused,
            distinct_path_views: 0,
            note: None,
            timings,
        };

        // 3. The point to look at: the frontier's centroid, or the refine cluster's centre.
        let t = Instant::now();
        let focus = match input.goal {
            GoalRequest::Frontier { focus } => focus,
            GoalRequest::Refine => {
                let n = input.map.gaussians.len();
                let scores: Vec<f64> = prior[..n]
                    .iter()
                    .map(|p| p.iter().map(|v| 1.0 / v).sum())
                    .collect();
                match refine_target(
                    &input.map.gaussians.means,
                    &scores,
                    pose.translation.z,
                    &config,
                )? {
                    Some(target) => Point2::new(target.centre[0], target.centre[1]),
                    None => {
                        outcome.note = Some(format!(
                            "refine: no DBSCAN cluster among the top {:.0} % of {n} Gaussians",
                            100.0 * config.refine_top_fraction
                        ));
                        outcome.timings.total_ms = ms(started);
                        return Ok(outcome);
                    }
                }
            }
        };
        outcome.focus = Some([focus.x, focus.y]);

        // 4. Candidates around it, ranked by EIG.
        let mut poses = sample_candidates(
            &clear,
            focus,
            config.candidates,
            config.candidate_radius_m,
            config.candidate_radius_growth,
            config.candidate_retries,
            &mut rng,
        )?;
        if config.readd_previous {
            poses.extend(
                self.previous
                    .iter()
                    .copied()
                    .filter(|p| clear.is_clear(grid.geometry.cell_of(Point2::new(p.x, p.y)))),
            );
        }
        // Candidates are ranked by EIG alone: no pose information.
        let views = self.views(&scoring, &poses, floor_z, ViewParts::Diagonal)?;
        let mut candidates: Vec<CandidateScore> = poses
            .iter()
            .zip(&views)
            .map(|(p, v)| CandidateScore {
                pose: *p,
                eig: eig(v, prior.as_slice()),
            })
            .collect();
        // Best first; equal EIGs keep their draw order (a stable sort), so runs repeat.
        candidates.sort_by(|a, b| b.eig.total_cmp(&a.eig));
        outcome.timings.candidates_ms = ms(t);
        if candidates.is_empty() {
            outcome.note = Some(format!(
                "no candidate pose in the free space within {:.2} m of ({:.2}, {:.2}) after {} radius growths",
                config.candidate_radius_m[1]
                    * config
                        .candidate_radius_growth
                        .powi(config.candidate_retries as i32),
                focus.x,
                focus.y,
                config.candidate_retries
            ));
            outcome.candidates = candidates;
            outcome.timings.total_ms = ms(started);
            return Ok(outcome);
        }

        // 5. Paths to the top candidates and their future poses.
        let t = Instant::now();
        let top: Vec<PlanarPose> = candidates
            .iter()
            .take(config.top_candidates)
            .map(|c| c.pose)
            .collect();
        let futures: Vec<(PlanarPose, FuturePath)> = top
            .par_iter()
            .map(|goal| {
                future_path(grid, &clear, &start, goal, focus, &self.robot, MAX_ROLLOUT)
                    .map(|f| f.map(|f| (*goal, f)))
            })
            .collect::<Result<Vec<_>, _>>()?
            .into_iter()
            .flatten()
            .collect();
        outcome.timings.paths_ms = ms(t);

        // 6. Path EIG and C_local along each, and the objective. Paths to nearby candidates
        // share their first moves (the same rollout from the same start), so each distinct
        // scored pose is rendered once.
        let t = Instant::now();
        let steps: Vec<Vec<usize>> = futures
            .iter()
            .map(|(_, f)| scored_steps(f.poses.len(), config.stride, config.max_actions))
            .collect();
        let mut distinct: Vec<PlanarPose> = Vec::new();
        let mut slot_of: std::collections::HashMap<[u64; 3], usize> = Default::default();
        let slots: Vec<Vec<usize>> = futures
            .iter()
            .zip(&steps)
            .map(|((_, f), steps)| {
                steps
                    .iter()
                    .map(|s| {
                        let p = snap(f.poses[s - 1], config.path_snap);
                        *slot_of
                            .entry([p.x.to_bits(), p.y.to_bits(), p.yaw.to_bits()])
                            .or_insert_with(|| {
                                distinct.push(p);
                                distinct.len() - 1
                            })
                    })
                    .collect()
            })
            .collect();
        let distinct_views =
            self.views(&scoring, &distinct, floor_z, ViewParts::DiagonalAndPose)?;
        outcome.distinct_path_views = distinct.len();
        // Path EIG along each path, the work of shared prefixes done once.
        let terms = shared_path_terms(&distinct_views, &slots, &prior, config.degenerate_ratio);
        let pixel_scale =
            self.camera.pixel_count() as f64 / self.view.intrinsics.pixel_count() as f64;
        let scored: Vec<PathScore> = futures
            .iter()
            .zip(steps)
            .zip(&slots)
            .zip(terms)
            .map(|((((goal, f), steps), slots), (eig, c_local))| {
                let low_opacity: Vec<f64> = slots
                    .iter()
                    .map(|&k| distinct_views[k].low_opacity_pixels as f64 * pixel_scale)
                    .collect();
                let objective = objective(&eig, &c_local, &low_opacity, &config);
                PathScore {
                    goal: *goal,
                    waypoints: f.path.waypoints.clone(),
                    actions: f.poses.len(),
                    scored_steps: steps,
                    eig,
                    c_local,
                    low_opacity,
                    objective,
                }
            })
            .collect();
        outcome.timings.path_scores_ms = ms(t);
        // The lowest objective (the first of equals), or an ablation's choice among the paths
        // the objective does not refuse.
        let finite: Vec<usize> = (0..scored.len())
            .filter(|&i| scored[i].objective.is_finite())
            .collect();
        let chosen = match config.objective {
            PathObjective::Random => {
                (!finite.is_empty()).then(|| finite[rng.random_range(0..finite.len())])
            }
            PathObjective::First => finite.first().copied(),
            PathObjective::Paper | PathObjective::EigOnly | PathObjective::Release => finite
                .iter()
                .copied()
                .min_by(|&a, &b| scored[a].objective.total_cmp(&scored[b].objective)),
        };
        if let Some(i) = chosen {
            outcome.path = Some(futures[i].1.path.clone());
        } else {
            outcome.note = Some(format!(
                "none of the {} paths to the top {} candidates has a finite objective",
                scored.len(),
                top.len()
            ));
        }
        outcome.chosen = chosen;
        self.previous = top;
        if let Some(i) = chosen {
            self.previous.push(scored[i].goal);
        }
        outcome.candidates = candidates;
        outcome.paths = scored;
        outcome.timings.total_ms = ms(started);
        Ok(outcome)
    }
}

/// What stages 1–2 of a replan leave for the rest.
struct Prepared {
    /// Map plus unknown-space Gaussians, indexed for the views' culls.
    scoring: ScoringScene<f32>,
    /// `I + λ` per Gaussian of `scoring`.
    prior: Vec<crate::information::Diagonal>,
    clear: ClearanceMap,
    floor_z: f64,
    model_reused: bool,
    timings: StageTimings,
}

/// `pose` on the lattice `[metres, degrees]` (SPEC §5 path poses, see
/// [`FisherConfig::path_snap`]); unchanged without one.
pub fn snap(pose: PlanarPose, lattice: Option<[f64; 2]>) -> PlanarPose {
    let Some([m, deg]) = lattice else {
        return pose;
    };
    let step = deg.to_radians();
    // `+ 0.0` turns −0 into +0, so equal lattice points have equal bits (the view cache key).
    PlanarPose::new(
        (pose.x / m).round() * m + 0.0,
        (pose.y / m).round() * m + 0.0,
        activemap_geometry::robot::wrap_angle((pose.yaw / step).round() * step) + 0.0,
    )
}

/// Milliseconds since `t`.
fn ms(t: Instant) -> f64 {
    t.elapsed().as_secs_f64() * 1e3
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Snapping moves a pose to the nearest lattice point (within half a step), maps nearby
    /// poses to the same bits, and leaves poses alone without a lattice.
    #[test]
    fn snapped_poses_share_lattice_points() {
        let lattice = Some([0.1, 10.0]);
        let a = snap(PlanarPose::new(1.02, -0.04, 0.05), lattice);
        let b = snap(PlanarPose::new(0.97, 0.03, -0.06), lattice);
        assert_eq!(
            [a.x.to_bits(), a.y.to_bits(), a.yaw.to_bits()],
            [b.x.to_bits(), b.y.to_bits(), b.yaw.to_bits()]
        );
        assert!((a.x - 1.0).abs() < 1e-12 && a.y == 0.0 && a.yaw == 0.0);
        let c = snap(PlanarPose::new(0.26, 0.0, 0.2), lattice);
        assert!((c.x - 0.3).abs() < 1e-12 && (c.yaw - 10f64.to_radians()).abs() < 1e-12);
        let p = PlanarPose::new(0.123, 0.456, 0.789);
        assert_eq!(snap(p, None), p);
    }
}
