//! Structural similarity (SPEC §8) exactly as Wang et al. 2004 and scikit-image's
//! `structural_similarity(gaussian_weights=True, sigma=1.5, use_sample_covariance=False)`:
//! an 11-tap Gaussian window (σ = 1.5, radius 5 = int(3.5·σ + 0.5)), K1 = 0.01, K2 = 0.03,
//! population covariances, and
//! SSIM = ((2·μx·μy + C1)(2·σxy + C2)) / ((μx² + μy² + C1)(σx² + σy² + C2)),
//! C1 = (K1·R)², C2 = (K2·R)², R the data range.
//!
//! Borders: scikit-image filters the whole image (mode `reflect`) and then crops 5 pixels from
//! every side before averaging. Every kept pixel's window lies inside the image, so the padding
//! never reaches the mean; this module filters only those interior pixels and gives the same
//! number. Multichannel images: the mean of the per-channel SSIMs (`channel_axis=-1`).

use crate::error::EvalError;
use crate::image::{ImageView, check_same_shape};
use rayon::prelude::*;

/// Standard deviation of the Gaussian window, pixels (Wang et al. 2004).
pub const SSIM_SIGMA: f64 = 1.5;
/// Window radius: int(3.5·σ + 0.5) = 5, an 11-tap window (scikit-image's `truncate = 3.5`).
pub const SSIM_RADIUS: usize = 5;
/// Stabiliser constant for the luminance term.
pub const SSIM_K1: f64 = 0.01;
/// Stabiliser constant for the contrast-structure term.
pub const SSIM_K2: f64 = 0.03;

/// Normalised 1-D Gaussian taps, index 0 ↔ offset −radius (as `scipy.ndimage`).
fn gaussian_taps() -> [f64; 2 * SSIM_RADIUS + 1] {
    let mut taps = [0.0; 2 * SSIM_RADIUS + 1];
    for (i, t) in taps.iter_mut().enumerate() {
        let x = i as f64 - SSIM_RADIUS as f64;
        *t = (-0.5 * x * x / (SSIM_SIGMA * SSIM_SIGMA)).exp();
    }
    let sum: f64 = taps.iter().sum();
    taps.iter_mut().for_each(|t| *t /= sum);
    taps
}

/// Gaussian-filters `plane` (width × height) at the interior pixels only: output is
/// (width − 2r) × (height − 2r), row-major.
fn filter_interior(plane: &[f64], width: usize, height: usize, taps: &[f64]) -> Vec<f64> {
    let r = SSIM_RADIUS;
    let out_w = width - 2 * r;
    let out_h = height - 2 * r;
    // horizontal pass on every row, interior columns
    let mut horizontal = vec![0.0; height * out_w];
    for (y, row_out) in horizontal.chunks_mut(out_w).enumerate() {
        let row = &plane[y * width..(y + 1) * width];
        for (x, out) in row_out.iter_mut().enumerate() {
            *out = taps
                .iter()
                .zip(&row[x..x + 2 * r + 1])
                .map(|(t, v)| t * v)
                .sum();
        }
    }
    // vertical pass on interior rows
    let mut filtered = vec![0.0; out_h * out_w];
    for (y, row_out) in filtered.chunks_mut(out_w).enumerate() {
        for (k, t) in taps.iter().enumerate() {
            let src = &horizontal[(y + k) * out_w..(y + k + 1) * out_w];
            for (o, s) in row_out.iter_mut().zip(src) {
                *o += t * s;
            }
        }
    }
    filtered
}

/// Mean SSIM of one channel plane pair (f64, same size, both sides > 2r).
fn ssim_plane(x: &[f64], y: &[f64], width: usize, height: usize, data_range: f64) -> f64 {
    let taps = gaussian_taps();
    let products = |f: &dyn Fn(f64, f64) -> f64| -> Vec<f64> {
        x.iter().zip(y).map(|(&a, &b)| f(a, b)).collect()
    };
    let maps: Vec<Vec<f64>> = [
        products(&|a, _| a),
        products(&|_, b| b),
        products(&|a, _| a * a),
        products(&|_, b| b * b),
        products(&|a, b| a * b),
    ]
    .into_par_iter()
    .map(|m| filter_interior(&m, width, height, &taps))
    .collect();
    let (ux, uy, uxx, uyy, uxy) = (&maps[0], &maps[1], &maps[2], &maps[3], &maps[4]);
    let c1 = (SSIM_K1 * data_range).powi(2);
    let c2 = (SSIM_K2 * data_range).powi(2);
    let mut sum = 0.0;
    for i in 0..ux.len() {
        let (mx, my) = (ux[i], uy[i]);
        let vx = uxx[i] - mx * mx;
        let vy = uyy[i] - my * my;
        let vxy = uxy[i] - mx * my;
        let numerator = (2.0 * mx * my + c1) * (2.0 * vxy + c2);
        let denominator = (mx * mx + my * my + c1) * (vx + vy + c2);
        sum += numerator / denominator;
    }
    sum / ux.len() as f64
}

/// Mean SSIM of two images of the same shape (mean over channels), data range `data_range`
/// (1.0 for RGB in [0, 1]). Both sides must be at least 11 pixels, as in scikit-image.
pub fn ssim(
    rendered: ImageView<'_>,
    truth: ImageView<'_>,
    data_range: f64,
) -> Result<f64, EvalError> {
    check_same_shape("SSIM", &rendered, &truth)?;
    if !(data_range.is_finite() && data_range > 0.0) {
        return Err(EvalError::InvalidParameter {
            metric: "SSIM",
            detail: format!("data range must be finite and positive, got {data_range}"),
        });
    }
    let window = 2 * SSIM_RADIUS + 1;
    if rendered.width < window || rendered.height < window {
        return Err(EvalError::InvalidParameter {
            metric: "SSIM",
            detail: format!(
                "a {}×{} image is smaller than the {window}×{window} window",
                rendered.width, rendered.height
            ),
        });
    }
    rendered.check_finite("SSIM", "rendered")?;
    truth.check_finite("SSIM", "truth")?;
    let channels = rendered.channels;
    let plane = |img: &ImageView<'_>, c: usize| -> Vec<f64> {
        img.data
            .iter()
            .skip(c)
            .step_by(channels)
            .map(|&v| f64::from(v))
            .collect()
    };
    let total: f64 = (0..channels)
        .map(|c| {
            ssim_plane(
                &plane(&rendered, c),
                &plane(&truth, c),
                rendered.width,
                rendered.height,
                data_range,
            )
        })
        .sum();
    Ok(total / channels as f64)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn taps_are_the_normalised_gaussian() {
        let t = gaussian_taps();
        assert!((t.iter().sum::<f64>() - 1.0).abs() < 1e-15);
        // ratio of neighbouring taps is exp(-(2k+1)/(2σ²))
        let ratio = t[SSIM_RADIUS + 1] / t[SSIM_RADIUS];
        assert!((ratio - (-1.0 / (2.0 * 2.25f64)).exp()).abs() < 1e-15);
        assert_eq!(t[0], t[10]);
    }

    #[test]
    fn identical_images_give_one() {
        let w = 23;
        let h = 17;
        let a: Vec<f32> = (0..w * h * 3)
            .map(|i| ((i * 37) % 101) as f32 / 100.0)
            .collect();
        let img = ImageView::rgb(&a, w, h).unwrap();
        let s = ssim(img, img, 1.0).unwrap();
        assert!((s - 1.0).abs() < 1e-12, "{s}");
    }

    #[test]
    fn constant_images_match_closed_form() {
        // Constant images: σ = 0, so SSIM = (2ab + C1)/(a² + b² + C1) at every pixel.
        let (a, b) = (0.3f32, 0.6f32);
        let x = vec![a; 12 * 12];
        let y = vec![b; 12 * 12];
        let s = ssim(
            ImageView::depth(&x, 12, 12).unwrap(),
            ImageView::depth(&y, 12, 12).unwrap(),
            1.0,
        )
        .unwrap();
        let (a, b) = (f64::from(a), f64::from(b));
        let c1 = 1e-4;
        let expected = (2.0 * a * b + c1) / (a * a + b * b + c1);
        assert!((s - expected).abs() < 1e-12, "{s} vs {expected}");
    }

    #[test]
    fn small_or_mismatched_images_are_refused() {
        let a = vec![0.0f32; 10 * 20 * 3];
        let img = ImageView::rgb(&a, 10, 20).unwrap();
        let e = ssim(img, img, 1.0).unwrap_err().to_string();
        assert!(e.contains("SSIM") && e.contains("11×11"), "{e}");
        let b = vec![0.0f32; 20 * 20 * 3];
        let other = ImageView::rgb(&b, 20, 20).unwrap();
        assert!(
            ssim(img, other, 1.0)
                .unwrap_err()
                .to_string()
                .contains("size mismatch")
        );
    }
}
