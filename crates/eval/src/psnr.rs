//! Peak signal-to-noise ratio (SPEC §8): PSNR = 10·log10(R² / MSE), MSE over every sample of
//! every channel, R the data range (1 for RGB in [0, 1]). Identical images give +∞
//! (`f64::INFINITY`); [`crate::report`] writes it to JSON as the string `"inf"`.

use crate::error::EvalError;
use crate::image::{ImageView, check_same_shape};

/// Mean squared error over all samples, in f64.
pub fn mean_squared_error(rendered: ImageView<'_>, truth: ImageView<'_>) -> Result<f64, EvalError> {
    check_same_shape("MSE", &rendered, &truth)?;
    rendered.check_finite("MSE", "rendered")?;
    truth.check_finite("MSE", "truth")?;
    if rendered.data.is_empty() {
        return Err(EvalError::Empty {
            metric: "MSE",
            detail: "the images hold no pixel".into(),
        });
    }
    let sum: f64 = rendered
        .data
        .iter()
        .zip(truth.data)
        .map(|(&a, &b)| {
            let d = f64::from(a) - f64::from(b);
            d * d
        })
        .sum();
    Ok(sum / rendered.data.len() as f64)
}

/// PSNR in dB for data range `data_range` (1.0 for RGB in [0, 1]); +∞ when the images are equal.
pub fn psnr(
    rendered: ImageView<'_>,
    truth: ImageView<'_>,
    data_range: f64,
) -> Result<f64, EvalError> {
    if !(data_range.is_finite() && data_range > 0.0) {
        return Err(EvalError::InvalidParameter {
            metric: "PSNR",
            detail: format!("data range must be finite and positive, got {data_range}"),
        });
    }
    let mse = mean_squared_error(rendered, truth).map_err(|e| rename(e, "PSNR"))?;
    if mse == 0.0 {
        return Ok(f64::INFINITY);
    }
    Ok(10.0 * (data_range * data_range / mse).log10())
}

/// Re-labels an error raised by a helper with the metric the caller asked for.
fn rename(e: EvalError, metric: &'static str) -> EvalError {
    match e {
        EvalError::SizeMismatch { detail, .. } => EvalError::SizeMismatch { metric, detail },
        EvalError::NonFinite {
            input, location, ..
        } => EvalError::NonFinite {
            metric,
            input,
            location,
        },
        EvalError::Empty { detail, .. } => EvalError::Empty { metric, detail },
        other => other,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn identical_images_give_infinity() {
        let a = vec![0.25f32; 5 * 4 * 3];
        let img = ImageView::rgb(&a, 5, 4).unwrap();
        assert_eq!(psnr(img, img, 1.0).unwrap(), f64::INFINITY);
    }

    #[test]
    fn constant_offset_matches_closed_form() {
        // every sample off by 0.1: MSE = 0.01 → PSNR = 10·log10(1/0.01) = 20 dB (0.1 as f32 is
        // 0.100000001490116, hence the tolerance).
        let a = vec![0.5f32; 6 * 3 * 3];
        let b: Vec<f32> = a.iter().map(|v| v + 0.1).collect();
        let p = psnr(
            ImageView::rgb(&a, 6, 3).unwrap(),
            ImageView::rgb(&b, 6, 3).unwrap(),
            1.0,
        )
        .unwrap();
        assert!((p - 20.0).abs() < 1e-5, "{p}");
        // data range 255 shifts by 20·log10(255)
        let p255 = psnr(
            ImageView::rgb(&a, 6, 3).unwrap(),
            ImageView::rgb(&b, 6, 3).unwrap(),
            255.0,
        )
        .unwrap();
        assert!((p255 - p - 20.0 * 255f64.log10()).abs() < 1e-9);
    }

    #[test]
    fn bad_inputs_are_named() {
        let a = vec![0.0f32; 4 * 4 * 3];
        let b = vec![0.0f32; 4 * 2 * 3];
        let e = psnr(
            ImageView::rgb(&a, 4, 4).unwrap(),
            ImageView::rgb(&b, 4, 2).unwrap(),
            1.0,
        )
        .unwrap_err()
        .to_string();
        assert!(
            e.starts_with("PSNR: size mismatch") && e.contains("4×2×3"),
            "{e}"
        );
        let mut c = a.clone();
        c[3 * (4 + 1) + 2] = f32::NAN;
        let e = psnr(
            ImageView::rgb(&c, 4, 4).unwrap(),
            ImageView::rgb(&a, 4, 4).unwrap(),
            1.0,
        )
        .unwrap_err()
        .to_string();
        assert!(
            e.contains("PSNR") && e.contains("rendered") && e.contains("(x 1, y 1) channel 2"),
            "{e}"
        );
        let img = ImageView::rgb(&a, 4, 4).unwrap();
        assert!(psnr(img, img, 0.0).is_err());
    }
}
