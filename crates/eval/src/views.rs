//! Per-view image metrics and their mean over the test views (SPEC §8: the paper averages
//! PSNR, SSIM, LPIPS and depth MAE over 2000 test poses). A view whose ground-truth depth has
//! no valid pixel has no depth MAE and is left out of that mean only.

use crate::depth::depth_mae;
use crate::error::EvalError;
use crate::image::ImageView;
use crate::lpips::LpipsAlex;
use crate::psnr::psnr;
use crate::report::MetricsReport;
use crate::ssim::ssim;

/// The image metrics of one test view.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ViewMetrics {
    /// PSNR, dB (+∞ for an exact render).
    pub psnr_db: f64,
    /// SSIM.
    pub ssim: f64,
    /// LPIPS (AlexNet), when the network was given.
    pub lpips: Option<f64>,
    /// Depth MAE, metres, when the ground truth has a valid pixel.
    pub depth_mae_m: Option<f64>,
}

/// Computes every image metric of one view: RGB in [0, 1] (data range 1), depth in metres.
pub fn evaluate_view(
    rendered_rgb: ImageView<'_>,
    truth_rgb: ImageView<'_>,
    rendered_depth: ImageView<'_>,
    truth_depth: ImageView<'_>,
    lpips: Option<&LpipsAlex>,
) -> Result<ViewMetrics, EvalError> {
    let depth = match depth_mae(rendered_depth, truth_depth) {
        Ok(v) => Some(v),
        Err(EvalError::Empty { .. }) => None,
        Err(e) => return Err(e),
    };
    Ok(ViewMetrics {
        psnr_db: psnr(rendered_rgb, truth_rgb, 1.0)?,
        ssim: ssim(rendered_rgb, truth_rgb, 1.0)?,
        lpips: lpips
            .map(|net| net.distance(rendered_rgb, truth_rgb))
            .transpose()?,
        depth_mae_m: depth,
    })
}

/// Running means of [`ViewMetrics`].
#[derive(Debug, Clone, Default, PartialEq)]
pub struct ViewMeans {
    views: usize,
    psnr_sum: f64,
    ssim_sum: f64,
    lpips: (f64, usize),
    depth: (f64, usize),
}

impl ViewMeans {
    /// Adds one view.
    pub fn push(&mut self, v: &ViewMetrics) {
        self.views += 1;
        self.psnr_sum += v.psnr_db;
        self.ssim_sum += v.ssim;
        if let Some(l) = v.lpips {
            self.lpips = (self.lpips.0 + l, self.lpips.1 + 1);
        }
        if let Some(d) = v.depth_mae_m {
            self.depth = (self.depth.0 + d, self.depth.1 + 1);
        }
    }

    /// Number of views added.
    pub fn views(&self) -> usize {
        self.views
    }

    /// Writes the means into `report` (PSNR, SSIM, LPIPS, depth MAE, view count); a metric no
    /// view had becomes `None` with a reason in `report.missing`.
    pub fn fill(&self, report: &mut MetricsReport) {
        report.test_views = self.views;
        let mean = |sum: f64, n: usize| (n > 0).then(|| sum / n as f64);
        report.psnr_db = mean(self.psnr_sum, self.views);
        report.ssim = mean(self.ssim_sum, self.views);
        report.lpips = mean(self.lpips.0, self.lpips.1);
        report.depth_mae_m = mean(self.depth.0, self.depth.1);
        if self.views == 0 {
            for m in ["psnr_db", "ssim", "lpips", "depth_mae_m"] {
                report.mark_missing(m, "no test view was evaluated");
            }
            return;
        }
        if self.lpips.1 == 0 {
            report.mark_missing("lpips", "LPIPS was not computed (weights not loaded)");
        }
        if self.depth.1 == 0 {
            report.mark_missing("depth_mae_m", "no test view had valid ground-truth depth");
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn evaluates_and_averages_views() {
        let (w, h) = (12, 12);
        let truth: Vec<f32> = (0..w * h * 3).map(|i| (i % 7) as f32 / 7.0).collect();
        let off: Vec<f32> = truth.iter().map(|v| v + 0.1).collect();
        let depth = vec![2.0f32; w * h];
        let near = vec![1.5f32; w * h];
        let no_depth = vec![0.0f32; w * h];
        let rgb = |d| ImageView::rgb(d, w, h).unwrap();
        let dep = |d| ImageView::depth(d, w, h).unwrap();
        let a = evaluate_view(rgb(&off), rgb(&truth), dep(&near), dep(&depth), None).unwrap();
        assert!((a.psnr_db - 20.0).abs() < 1e-5 && (a.depth_mae_m.unwrap() - 0.5).abs() < 1e-12);
        assert_eq!(a.lpips, None);
        let b = evaluate_view(rgb(&truth), rgb(&truth), dep(&near), dep(&no_depth), None).unwrap();
        assert_eq!((b.psnr_db, b.depth_mae_m), (f64::INFINITY, None));
        let mut means = ViewMeans::default();
        means.push(&a);
        means.push(&a);
        let mut report = MetricsReport::default();
        means.fill(&mut report);
        assert_eq!(report.test_views, 2);
        assert!((report.psnr_db.unwrap() - a.psnr_db).abs() < 1e-12);
        assert!((report.depth_mae_m.unwrap() - 0.5).abs() < 1e-12);
        assert!(report.lpips.is_none() && report.missing.contains_key("lpips"));
        means.push(&b);
        means.fill(&mut report);
        assert_eq!(report.psnr_db, Some(f64::INFINITY));
        assert!(
            (report.depth_mae_m.unwrap() - 0.5).abs() < 1e-12,
            "view b has no depth"
        );
        assert!((report.ssim.unwrap() - (2.0 * a.ssim + 1.0) / 3.0).abs() < 1e-12);
    }

    #[test]
    fn no_views_means_all_missing() {
        let mut report = MetricsReport::default();
        ViewMeans::default().fill(&mut report);
        assert!(report.psnr_db.is_none() && report.missing.len() == 4);
    }
}
