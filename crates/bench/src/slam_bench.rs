//! `activemap bench slam`: the scripted loop of [`crate::slam_loop`] over 500 frames at 200×200
//! and 400×400, one row per case, with the SLAM settings of the dataflow's `tracker` and
//! `mapper` nodes (the caller builds them, see `activemap bench slam --flow`).

use crate::slam_loop::{LoopConfig, LoopResult, run_loop};
use activemap_sim::NoiseConfig;
use activemap_slam::SlamConfig;

/// One benchmark case and its metrics.
#[derive(Debug, Clone, PartialEq)]
pub struct BenchRow {
    /// Case name, e.g. `loop500_200`.
    pub case: String,
    /// The loop's metrics.
    pub result: LoopResult,
}

impl std::fmt::Display for BenchRow {
    /// `slam <case> ate_cm <x> psnr_train <y> psnr_test <z> track_fps <f>` plus mapping time,
    /// Gaussian count, keyframes and lost frames, then held-out depth MAE and the surface offset
    /// (issue 33): `surface_offset_cm` (opacity-weighted median signed distance of the centres,
    /// positive in front), `surface_p90_cm` (90th percentile of its magnitude), the share within
    /// 2 cm, and the same on the floor (`nan` without floor centres).
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let r = &self.result;
        let floor = r.surface.floor.unwrap_or(activemap_eval::OffsetStats {
            median_cm: f64::NAN,
            p90_abs_cm: f64::NAN,
            within_2cm: f64::NAN,
            count: 0,
        });
        write!(
            f,
            "slam {} ate_cm {:.3} psnr_train {:.2} psnr_test {:.2} track_fps {:.2} map_s_per_kf {:.3} gaussians {} keyframes {} lost {} lost_unrecovered {} depth_mae_test_cm {:.2} surface_offset_cm {:.2} surface_p90_cm {:.2} surface_within_2cm {:.3} floor_offset_cm {:.2} floor_p90_cm {:.2} floor_within_2cm {:.3}",
            self.case,
            r.ate_cm,
            r.psnr_train,
            r.psnr_test,
            r.track_fps,
            r.map_seconds_per_keyframe,
            r.gaussians,
            r.keyframes,
            r.lost,
            r.lost_unrecovered,
            r.depth_mae_test_cm,
            r.surface.all.median_cm,
            r.surface.all.p90_abs_cm,
            r.surface.all.within_2cm,
            floor.median_cm,
            floor.p90_abs_cm,
            floor.within_2cm,
        )
    }
}

/// Runs the loop for each `(resolution, frames)` case (issue 5: `[(200, 500), (400, 500)]`)
/// with the SLAM settings `slam_for(resolution)` gives, under the simulator noise `noise`
/// (`noise_name` names it in the case, e.g. `loop500_200_realistic`; `None` for no noise).
pub fn run(
    cases: &[(u32, usize)],
    noise: &NoiseConfig,
    noise_name: Option<&str>,
    slam_for: impl Fn(u32) -> anyhow::Result<SlamConfig>,
) -> anyhow::Result<Vec<BenchRow>> {
    cases
        .iter()
        .map(|&(resolution, frames)| {
            let mut config = LoopConfig::new(resolution, frames, slam_for(resolution)?);
            config.noise = *noise;
            let result = run_loop(&config)?;
            let suffix = noise_name.map(|n| format!("_{n}")).unwrap_or_default();
            Ok(BenchRow {
                case: format!("loop{frames}_{resolution}{suffix}"),
                result,
            })
        })
        .collect()
}

/// The cases of issue 5.
pub const DEFAULT_CASES: [(u32, usize); 2] = [(200, 500), (400, 500)];
