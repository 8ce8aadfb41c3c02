//! `activemap eval RUN_DIR` and `activemap report RUN_DIR`: the paper's metrics of a finished run
//! (SPEC §8) and its self-contained `report.html`, both from `activemap-eval`.

use std::path::Path;

use activemap_eval::run_eval::{EvalOptions, LpipsSource, evaluate_run};

/// Options of `activemap eval`.
#[derive(clap::Args)]
pub struct EvalArgs {
    /// Number of seeded test views on the navigable plane (SPEC §8: 2000).
    #[arg(long, default_value_t = 2000)]
    pub views: usize,
    /// Test render width, pixels.
    #[arg(long, default_value_t = 160)]
    pub width: u32,
    /// Test render height, pixels.
    #[arg(long, default_value_t = 160)]
    pub height: u32,
    /// Horizontal field of view of the test camera, degrees (the paper: 90).
    #[arg(long, default_value_t = 90.0)]
    pub hfov_deg: f64,
    /// Skip LPIPS even when its weights are present.
    #[arg(long)]
    pub no_lpips: bool,
    /// Save this many test views of largest depth MAE as PNGs (map, truth, depth error classes:
    /// eval/worst_RR_view_NNNN_*.png).
    #[arg(long, default_value_t = 4)]
    pub worst_views: usize,
}

impl Default for EvalArgs {
    fn default() -> Self {
        let d = EvalOptions::default();
        Self {
            views: d.test_views,
            width: d.width,
            height: d.height,
            hfov_deg: d.hfov_deg,
            no_lpips: false,
            worst_views: d.worst_views,
        }
    }
}

/// Evaluates a run folder (and each of its checkpoints first), writes `metrics.json`,
/// `metrics.md` and `report.html`, and prints the table.
pub fn eval(run_dir: &Path, args: &EvalArgs) -> anyhow::Result<()> {
    let options = EvalOptions {
        test_views: args.views,
        width: args.width,
        height: args.height,
        hfov_deg: args.hfov_deg,
        worst_views: args.worst_views,
        lpips: if args.no_lpips {
            LpipsSource::Off
        } else {
            LpipsSource::Default
        },
        ..EvalOptions::default()
    };
    // Checkpoints first: the run's own metrics.json, written last, marks everything evaluated.
    for (step, checkpoint) in activemap_eval::RunFolder::new(run_dir).checkpoints()? {
        let m = evaluate_run(checkpoint.dir(), &options)?;
        let pct = |v: Option<f64>| v.map_or("n/a".to_string(), |v| format!("{:.1} %", 100.0 * v));
        eprintln!(
            "checkpoint at step {step}: completeness {}, 2D coverage {}, ATE {} → {}",
            pct(m.completeness),
            pct(m.coverage_2d),
            m.ate_rmse_m
                .map_or("n/a".to_string(), |a| format!("{:.2} cm", 100.0 * a)),
            checkpoint
                .path(activemap_eval::RunFolder::METRICS_MD)
                .display()
        );
    }
    let metrics = evaluate_run(run_dir, &options)?;
    // An invalid run says so on stderr too (issue 16), one line per reason.
    for w in &metrics.warnings {
        eprintln!("{}", w.log_line(run_dir));
    }
    println!("{}", metrics.to_markdown());
    report(run_dir)
}

/// Writes `report.html` for a run folder and prints its path.
pub fn report(run_dir: &Path) -> anyhow::Result<()> {
    let path = activemap_eval::html::write_report(run_dir)?;
    println!("report: {}", path.display());
    Ok(())
}
