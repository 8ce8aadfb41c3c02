//! Settings of the Fisher scorer (SPEC §5–§6). Every field has the paper's value as its
//! default; the authors' release variant, where it differs, is a named option. The `scorer`
//! operator reads this struct from its `fisher:` config block (unknown fields are refused).
//!
//! # Normalisation of H and what λ means
//! A view's Fisher diagonal is the MEAN over the scoring image's pixels of the squared
//! per-pixel gradients, `H(x) = (1/P)·Σ_px (∂f/∂w)²` (colour per channel plus
//! `depth_weight` × depth), and the 6×6 pose information likewise `(1/P)·J_τᵀJ_τ`. So λ and
//! every EIG and C_local keep their meaning at every image size: halving the scoring
//! resolution leaves them unchanged up to sampling. The release instead scales per-pixel
//! gradients by 1e-3 before squaring (`H_release = 1e-6·Σ_px g²`): at 800×800 (P = 640 000)
//! that is 0.64 × our per-pixel mean, so the release's λ = 1e-6 there is about our
//! λ = 1.6e-6; on unscaled sums (no normalisation) the release's λ = 1e-6 acts like λ = 1.

use serde::{Deserialize, Serialize};

/// Where the model Fisher `I(w)` comes from (SPEC §5). The default is the paper's Monte-Carlo
/// sum. Its ranking is unstable (`activemap bench scorer`'s `scorer model_tau`, Kendall τ of the
/// top-20 candidates' EIG between two independent draws, 150k-Gaussian house: 0.25–0.32 with 32
/// poses, −0.11 with 128, 0.32 for `both`; the keyframe sum draws nothing, τ = 1, and costs 38 ms
/// against 1.1 s), but the release's keyframe sum did worse in episodes: `fisher` with
/// `keyframes` against `mc_free_space` on houses 1 and 9, seeds 1–2, 300 steps at 96×96 (the
/// smoke settings), lost all 4 pairs on ATE (7.1 against 2.8 mm) and depth MAE, and 3 of 4 on
/// PSNR. So the paper's stays the default until longer paired runs say otherwise.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum ModelFisherSource {
    /// The paper: a Monte-Carlo sum of `H` over `mc_poses` poses drawn uniformly in the
    /// current estimated free space (eroded by the robot radius), random yaw.
    #[default]
    McFreeSpace,
    /// The release: the sum of `H` over the keyframes (FisherRF's empirical Fisher).
    Keyframes,
    /// Both sums added: the keyframes' `H` (what was observed) plus the Monte-Carlo estimate
    /// (`mc_poses` free-space poses, what could be observed).
    Both,
}

/// How a path's poses are turned into one number (SPEC §5).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum PathObjective {
    /// The paper: minimise `Σ_i [C_local(x_i) − η·log EIG_i(x_i)]`.
    #[default]
    Paper,
    /// The paper's "w/o localisation" ablation: minimise `−η·Σ_i log EIG_i(x_i)`.
    EigOnly,
    /// The release: maximise `mean_i(−0.2·C_local(x_i) + 1.0·log EIG_i(x_i)) + 60·EIG(x_T)`
    /// (reported as its negative, so lower is better for every objective).
    Release,
    /// Ablation (issue 34): a uniformly random path among those with a finite `paper`
    /// objective (drawn from the replan's seeded generator), to show whether the objective's
    /// choice matters. Paths are scored and reported with the `paper` objective.
    Random,
    /// Ablation (issue 34): the path to the best-EIG candidate (the first with a finite `paper`
    /// objective, candidates in EIG order), i.e. the objective ignored. Scored as `paper`.
    First,
}

/// Which DBSCAN cluster a refine replan aims at (SPEC §6).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum RefineCluster {
    /// The paper: the largest cluster.
    #[default]
    Largest,
    /// The release: the cluster holding the best-scoring Gaussian.
    Best,
}

/// Which pose information the localisation cost `C_local = −log det` is taken of (SPEC §5).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum LocalisationInformation {
    /// The paper: the photometric and depth Jacobians of the map's render for the pose.
    #[default]
    Paper,
    /// The dense depth alignment's: point-to-plane Jacobians of the map's rendered depth,
    /// weighted by the sensor's depth noise at each range
    /// ([`crate::information::depth_pose_information`]); what `activemap bench clocal-error`
    /// found to predict the tracker's error under the realistic sensor.
    Depth,
}

/// The whole Fisher scorer configuration.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct FisherConfig {
    /// Source of the model Fisher `I(w)`.
    pub model_fisher: ModelFisherSource,
    /// `mc_free_space`: poses in the Monte-Carlo sum (N).
    pub mc_poses: usize,
    /// `mc_free_space`: fresh poses drawn per update when the map changed (the oldest of the
    /// N are replaced; every Gaussian's estimate is rescaled to N poses, so a Gaussian added
    /// since the oldest pose is estimated from the poses drawn after it appeared).
    pub mc_refresh: usize,
    /// Laplace prior λ added to `I(w)` (SPEC §5: 1e-6; per-pixel normalised H, see the module
    /// doc).
    pub lambda: f64,
    /// Weight of the depth output against the colour channels in `H` and `J_τᵀJ_τ`.
    pub depth_weight: f64,
    /// Width of the scoring image, pixels (the camera's field of view kept; the height
    /// follows the camera's aspect). A pyramid level of the frame: Fisher scoring may work at
    /// its own resolution while frames, map and evaluation keep theirs.
    pub scoring_width: u32,
    /// Far plane of the scoring renders, metres (Gaussians farther away are left out).
    pub far_m: f64,
    /// Candidate poses around the goal (K).
    pub candidates: usize,
    /// Candidate distance range from the goal point, metres (paper [0.3, 1.0]; release
    /// [0.5, 1.0]).
    pub candidate_radius_m: [f64; 2],
    /// Radius growth factor when no candidate survives (release: ×1.5).
    pub candidate_radius_growth: f64,
    /// How many times the radius may grow before the replan gives up on candidates.
    pub candidate_retries: usize,
    /// Candidates kept by EIG for path planning (top 20).
    pub top_candidates: usize,
    /// The release's option: re-add the previous goal and the previous top candidates.
    pub readd_previous: bool,
    /// Objective of the path selection.
    pub objective: PathObjective,
    /// η: weight of the information term (5).
    pub eta: f64,
    /// Every `stride`-th future pose of a path is scored (plus the last); 1 = every pose.
    pub stride: usize,
    /// Paths are cut after this many actions for scoring (`None`: whole paths, the paper's
    /// sum over the path, its end pose included; release: 30). The follower drives the whole
    /// path either way. Default 30 by measurement (`activemap bench scorer --fisher
    /// max_actions=null --compare max_actions=30`, 150k-Gaussian house): whole paths render
    /// 204 distinct path poses every 5th action (112 every 10th, 64 every 20th) against 6
    /// for the cut, 2–3× the views of a replan, and still tie within 1 % in a third to all of
    /// the replans (the cut: all).
    pub max_actions: Option<usize>,
    /// Lattice the scored path poses are snapped to before rendering, `[metres, degrees]`
    /// (`None`: exact poses). Paths to nearby candidates that run side by side then share
    /// their views (each distinct snapped pose is rendered once); a snapped pose lies within
    /// half a cell and half an angle step of the true one.
    pub path_snap: Option<[f64; 2]>,
    /// Weight of the end pose's own term, counted on top of its place in the sum (SPEC §5
    /// "Path objective"; the release adds 60× the end pose's score): the `paper` family adds
    /// `end_weight·(C_local(x_T) − η·ln EIG_T)`. 0 (the paper) leaves the sum alone. The
    /// `release` objective keeps its own `60·EIG_T`.
    pub end_weight: f64,
    /// Weight of the release's coverage term (release: 1e-4): every scored pose subtracts
    /// `low_opacity_weight × n_low` from the objective (`release`: adds it to the score), `n_low`
    /// the pixels whose rendered opacity is below 0.5, counted at the scoring resolution and
    /// scaled to the frame camera's pixel count (so the weight means what the release's does
    /// at any `scoring_width`). 0 (the paper): no such term.
    pub low_opacity_weight: f64,
    /// A 6×6 pose information whose smallest eigenvalue is at most this fraction of its
    /// largest counts as degenerate (C_local = +∞).
    pub degenerate_ratio: f64,
    /// Which pose information `C_local` is taken of: `paper` (default) or `depth`.
    pub localisation: LocalisationInformation,
    /// Unknown-space Gaussians per frontier cell (200). Part of the objective, not only a
    /// sampling density: with 100 the candidates' EIG ranking agrees with 200's at τ 0.71,
    /// against 0.86 for another draw of 200 (`docs/src/fisher.md`).
    pub unknown_per_cell: usize,
    /// Height band of the unknown-space Gaussians above the floor, as offsets from the camera
    /// height, metres (release: [cam_h − 1, cam_h)).
    pub unknown_band_below_camera_m: f64,
    /// Largest unknown-space scale as a fraction of the cell side (release: 0.05).
    pub unknown_max_scale_fraction: f64,
    /// Refine mode: the share of Gaussians (by `Σ 1/(I + λ)`) clustered (20 %).
    pub refine_top_fraction: f64,
    /// Refine mode: DBSCAN neighbourhood radius, metres (0.5).
    pub dbscan_eps_m: f64,
    /// Refine mode: DBSCAN minimum points (20).
    pub dbscan_min_points: usize,
    /// Refine mode: which cluster to aim at.
    pub refine_cluster: RefineCluster,
    /// Refine mode (release): only Gaussians within this height of the camera, metres
    /// (`None`: all).
    pub refine_height_band_m: Option<f64>,
    /// Seed of every random draw (Monte-Carlo poses, candidates, unknown space), mixed with
    /// the frame id, so a run is reproducible.
    pub seed: u64,
    /// Mixed into the Monte-Carlo pose draws of `mc_free_space` only: two scorers that differ
    /// in it draw independent model Fisher estimates on the same candidates and unknown space
    /// (`bench scorer`'s `model_tau`).
    pub model_seed: u64,
    /// Mixed into the unknown-space draw only: two scorers that differ in it seed independent
    /// unknown-space Gaussians on the same candidates and model poses (`bench scorer
    /// --compare unknown_seed=1`: the ranking noise of the draw itself, the yardstick for a
    /// smaller `unknown_per_cell`).
    pub unknown_seed: u64,
}

impl Default for FisherConfig {
    fn default() -> Self {
        Self {
            model_fisher: ModelFisherSource::McFreeSpace,
            mc_poses: 32,
            mc_refresh: 8,
            lambda: 1e-6,
            depth_weight: 1.0,
            scoring_width: 40,
            far_m: 6.0,
            candidates: 256,
            candidate_radius_m: [0.3, 1.0],
            candidate_radius_growth: 1.5,
            candidate_retries: 3,
            top_candidates: 20,
            readd_previous: false,
            objective: PathObjective::Paper,
            eta: 5.0,
            stride: 5,
            max_actions: Some(30),
            path_snap: None,
            end_weight: 0.0,
            low_opacity_weight: 0.0,
            degenerate_ratio: 1e-9,
            localisation: LocalisationInformation::Paper,
            unknown_per_cell: 200,
            unknown_band_below_camera_m: 1.0,
            unknown_max_scale_fraction: 0.05,
            refine_top_fraction: 0.2,
            dbscan_eps_m: 0.5,
            dbscan_min_points: 20,
            refine_cluster: RefineCluster::Largest,
            refine_height_band_m: None,
            seed: 0,
            model_seed: 0,
            unknown_seed: 0,
        }
    }
}

impl FisherConfig {
    /// The release's variant (SPEC §5 "Release facts"): keyframe Fisher, candidates at
    /// [0.5, 1.0] m with the previous ones re-added, the release objective every 5th pose of
    /// paths cut at 30 actions with its low-opacity coverage term (1e-4 per pixel), refine on
    /// the best cluster within ±0.8 m of the camera.
    pub fn release() -> Self {
        Self {
            model_fisher: ModelFisherSource::Keyframes,
            candidate_radius_m: [0.5, 1.0],
            readd_previous: true,
            objective: PathObjective::Release,
            stride: 5,
            max_actions: Some(30),
            low_opacity_weight: 1e-4,
            refine_cluster: RefineCluster::Best,
            refine_height_band_m: Some(0.8),
            ..Self::default()
        }
    }

    /// Checks every field; the message names the field and what is wrong.
    pub fn validate(&self) -> Result<(), String> {
        let positive = |name: &str, v: f64| {
            if v.is_finite() && v > 0.0 {
                Ok(())
            } else {
                Err(format!(
                    "fisher.{name} must be finite and positive, got {v}"
                ))
            }
        };
        let at_least_one = |name: &str, v: usize| {
            if v >= 1 {
                Ok(())
            } else {
                Err(format!("fisher.{name} must be at least 1"))
            }
        };
        positive("lambda", self.lambda)?;
        if !(self.depth_weight.is_finite() && self.depth_weight >= 0.0) {
            return Err(format!(
                "fisher.depth_weight must be finite and non-negative, got {}",
                self.depth_weight
            ));
        }
        if self.scoring_width < 8 {
            return Err(format!(
                "fisher.scoring_width must be at least 8 pixels, got {}",
                self.scoring_width
            ));
        }
        positive("far_m", self.far_m)?;
        at_least_one("mc_poses", self.mc_poses)?;
        at_least_one("mc_refresh", self.mc_refresh)?;
        if self.mc_refresh > self.mc_poses {
            return Err(format!(
                "fisher.mc_refresh ({}) must not exceed fisher.mc_poses ({})",
                self.mc_refresh, self.mc_poses
            ));
        }
        at_least_one("candidates", self.candidates)?;
        at_least_one("top_candidates", self.top_candidates)?;
        let [r0, r1] = self.candidate_radius_m;
        if !(r0.is_finite() && r1.is_finite() && r0 >= 0.0 && r1 > r0) {
            return Err(format!(
                "fisher.candidate_radius_m must be [min, max] with 0 <= min < max, got [{r0}, {r1}]"
            ));
        }
        if !(self.candidate_radius_growth.is_finite() && self.candidate_radius_growth > 1.0) {
            return Err(format!(
                "fisher.candidate_radius_growth must be above 1, got {}",
                self.candidate_radius_growth
            ));
        }
        positive("eta", self.eta)?;
        at_least_one("stride", self.stride)?;
        if self.max_actions == Some(0) {
            return Err("fisher.max_actions must be at least 1 (or left out)".into());
        }
        if let Some([m, deg]) = self.path_snap
            && !(m.is_finite() && m > 0.0 && deg.is_finite() && deg > 0.0)
        {
            return Err(format!(
                "fisher.path_snap must be [metres, degrees], both positive, got [{m}, {deg}]"
            ));
        }
        for (name, v) in [
            ("end_weight", self.end_weight),
            ("low_opacity_weight", self.low_opacity_weight),
        ] {
            if !(v.is_finite() && v >= 0.0) {
                return Err(format!(
                    "fisher.{name} must be finite and non-negative, got {v}"
                ));
            }
        }
        if !(self.degenerate_ratio.is_finite()
            && self.degenerate_ratio >= 0.0
            && self.degenerate_ratio < 1.0)
        {
            return Err(format!(
                "fisher.degenerate_ratio must be in [0, 1), got {}",
                self.degenerate_ratio
            ));
        }
        positive(
            "unknown_band_below_camera_m",
            self.unknown_band_below_camera_m,
        )?;
        positive(
            "unknown_max_scale_fraction",
            self.unknown_max_scale_fraction,
        )?;
        if !(self.refine_top_fraction > 0.0 && self.refine_top_fraction <= 1.0) {
            return Err(format!(
                "fisher.refine_top_fraction must be in (0, 1], got {}",
                self.refine_top_fraction
            ));
        }
        positive("dbscan_eps_m", self.dbscan_eps_m)?;
        at_least_one("dbscan_min_points", self.dbscan_min_points)?;
        if let Some(band) = self.refine_height_band_m {
            positive("refine_height_band_m", band)?;
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The paper's defaults and the release variant are valid; a bad value is refused naming
    /// its field; unknown fields are refused when read.
    #[test]
    fn defaults_and_variants_validate_and_bad_fields_are_named() {
        let paper = FisherConfig::default();
        paper.validate().unwrap();
        assert_eq!(paper.model_fisher, ModelFisherSource::McFreeSpace);
        assert_eq!((paper.candidates, paper.top_candidates), (256, 20));
        assert_eq!((paper.lambda, paper.eta), (1e-6, 5.0));
        let release = FisherConfig::release();
        release.validate().unwrap();
        assert_eq!(release.candidate_radius_m, [0.5, 1.0]);
        for (bad, field) in [
            (
                FisherConfig {
                    lambda: 0.0,
                    ..FisherConfig::default()
                },
                "fisher.lambda",
            ),
            (
                FisherConfig {
                    mc_refresh: 40,
                    ..FisherConfig::default()
                },
                "fisher.mc_refresh",
            ),
            (
                FisherConfig {
                    candidate_radius_m: [1.0, 0.3],
                    ..FisherConfig::default()
                },
                "fisher.candidate_radius_m",
            ),
            (
                FisherConfig {
                    max_actions: Some(0),
                    ..FisherConfig::default()
                },
                "fisher.max_actions",
            ),
        ] {
            let e = bad.validate().unwrap_err();
            assert!(e.contains(field), "{e}");
        }
        let read: FisherConfig =
            serde_json::from_value(serde_json::json!({ "objective": "eig_only", "stride": 1 }))
                .unwrap();
        assert_eq!(read.objective, PathObjective::EigOnly);
        assert_eq!(read.stride, 1);
        assert!(serde_json::from_value::<FisherConfig>(serde_json::json!({ "etta": 5 })).is_err());
    }
}
