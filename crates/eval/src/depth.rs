//! Depth mean absolute error (SPEC §8): mean |D̂ − D| in metres over the pixels where the
//! ground truth holds a reading (D > 0; SPEC §2: 0 = no reading). A rendered depth of 0 (the map
//! shows nothing there) counts with its full error.

use crate::error::EvalError;
use crate::image::{ImageView, check_depth_images};

/// Mean |rendered − truth| over pixels with truth > 0, metres. Both images must be 1-channel.
pub fn depth_mae(rendered: ImageView<'_>, truth: ImageView<'_>) -> Result<f64, EvalError> {
    check_depth_images("depth MAE", &[("rendered", &rendered)], &truth)?;
    let (sum, count) = rendered
        .data
        .iter()
        .zip(truth.data)
        .filter(|&(_, &d)| d > 0.0)
        .fold((0.0f64, 0usize), |(s, n), (&r, &d)| {
            (s + (f64::from(r) - f64::from(d)).abs(), n + 1)
        });
    if count == 0 {
        return Err(EvalError::Empty {
            metric: "depth MAE",
            detail: format!(
                "the {}×{} ground-truth depth has no valid pixel (all ≤ 0)",
                truth.width, truth.height
            ),
        });
    }
    Ok(sum / count as f64)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn ignores_invalid_truth_and_counts_empty_renders() {
        // truth: [1, 0, 2, 4]; rendered: [1.5, 9, 0, 4] → |.5| + |−2| + 0 over 3 valid = 2.5/3
        let truth = [1.0f32, 0.0, 2.0, 4.0];
        let rendered = [1.5f32, 9.0, 0.0, 4.0];
        let m = depth_mae(
            ImageView::depth(&rendered, 2, 2).unwrap(),
            ImageView::depth(&truth, 2, 2).unwrap(),
        )
        .unwrap();
        assert!((m - 2.5 / 3.0).abs() < 1e-12, "{m}");
    }

    #[test]
    fn bad_inputs_are_named() {
        let truth = [0.0f32; 4];
        let e = depth_mae(
            ImageView::depth(&truth, 2, 2).unwrap(),
            ImageView::depth(&truth, 2, 2).unwrap(),
        )
        .unwrap_err()
        .to_string();
        assert!(e.contains("no valid pixel"), "{e}");
        let nan = [1.0f32, f32::NAN, 1.0, 1.0];
        let e = depth_mae(
            ImageView::depth(&nan, 2, 2).unwrap(),
            ImageView::depth(&[1.0; 4], 2, 2).unwrap(),
        )
        .unwrap_err()
        .to_string();
        assert!(e.contains("rendered") && e.contains("(x 1, y 0)"), "{e}");
        let e = depth_mae(
            ImageView::depth(&[1.0; 4], 4, 1).unwrap(),
            ImageView::depth(&[1.0; 4], 2, 2).unwrap(),
        )
        .unwrap_err()
        .to_string();
        assert!(e.contains("size mismatch"), "{e}");
    }
}
