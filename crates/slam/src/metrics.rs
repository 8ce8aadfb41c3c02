//! The two metrics the scripted evaluation needs, kept local (SPEC §8 definitions):
//! ATE RMSE after a Umeyama (1991) SE(3) alignment without scale, and colour PSNR.

use crate::error::SlamError;
use nalgebra::{Matrix3, Vector3};

/// RMSE of `‖R·e_i + t − r_i‖` after the least-squares rigid alignment of the estimated
/// positions `e` onto the reference `r` (Umeyama, no scale), metres.
pub fn ate_rmse(reference: &[Vector3<f64>], estimate: &[Vector3<f64>]) -> Result<f64, SlamError> {
    if reference.len() != estimate.len() || reference.is_empty() {
        return Err(SlamError::Input {
            what: "ATE positions",
            reason: format!(
                "{} reference vs {} estimate (need equal, > 0)",
                reference.len(),
                estimate.len()
            ),
        });
    }
    let n = reference.len() as f64;
    let mean_r = reference.iter().sum::<Vector3<f64>>() / n;
    let mean_e = estimate.iter().sum::<Vector3<f64>>() / n;
    let cov = reference
        .iter()
        .zip(estimate)
        .map(|(r, e)| (r - mean_r) * (e - mean_e).transpose())
        .sum::<Matrix3<f64>>()
        / n;
    let svd = cov.svd(true, true);
    let (Some(u), Some(v_t)) = (svd.u, svd.v_t) else {
        return Err(SlamError::Input {
            what: "ATE positions",
            reason: "SVD failed".into(),
        });
    };
    let mut s = Matrix3::identity();
    if u.determinant() * v_t.determinant() < 0.0 {
        s[(2, 2)] = -1.0;
    }
    let rotation = u * s * v_t;
    let t = mean_r - rotation * mean_e;
    let sq: f64 = reference
        .iter()
        .zip(estimate)
        .map(|(r, e)| (rotation * e + t - r).norm_squared())
        .sum();
    Ok((sq / n).sqrt())
}

/// PSNR (dB) of two RGB images in [0, 1] over all samples; +∞ when equal.
pub fn psnr(rendered: &[[f32; 3]], truth: &[[f32; 3]]) -> f64 {
    let n = (rendered.len().min(truth.len()) * 3).max(1) as f64;
    let mse: f64 = rendered
        .iter()
        .zip(truth)
        .flat_map(|(a, b)| (0..3).map(move |c| (a[c] as f64 - b[c] as f64).powi(2)))
        .sum::<f64>()
        / n;
    if mse == 0.0 {
        f64::INFINITY
    } else {
        10.0 * (1.0 / mse).log10()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::{Rotation3, Vector3};

    #[test]
    fn ate_is_zero_for_a_rigidly_moved_copy_and_rmse_otherwise() {
        let r: Vec<Vector3<f64>> = (0..20)
            .map(|i| {
                Vector3::new(
                    (i as f64 * 0.3).cos(),
                    (i as f64 * 0.7).sin(),
                    0.1 * i as f64,
                )
            })
            .collect();
        let rot = Rotation3::from_euler_angles(0.3, -0.2, 1.0);
        let e: Vec<Vector3<f64>> = r
            .iter()
            .map(|p| rot * p + Vector3::new(1.0, 2.0, -3.0))
            .collect();
        assert!(ate_rmse(&r, &e).unwrap() < 1e-9);
        // Square corners; the estimate lifts them by +,−,+,− 1 cm (a saddle): uncorrelated
        // with x and y, so no rigid motion reduces it and the RMSE is exactly 0.01.
        let line: Vec<Vector3<f64>> = [(1.0, 1.0), (-1.0, 1.0), (-1.0, -1.0), (1.0, -1.0)]
            .iter()
            .map(|&(x, y)| Vector3::new(x, y, 0.0))
            .collect();
        let noisy: Vec<Vector3<f64>> = line
            .iter()
            .enumerate()
            .map(|(i, p)| p + Vector3::new(0.0, 0.0, if i % 2 == 0 { 0.01 } else { -0.01 }))
            .collect();
        assert!((ate_rmse(&line, &noisy).unwrap() - 0.01).abs() < 1e-6);
    }

    #[test]
    fn psnr_of_a_uniform_offset() {
        // MSE 0.01 → 20 dB.
        let a = vec![[0.5f32; 3]; 16];
        let b = vec![[0.6f32; 3]; 16];
        assert!((psnr(&a, &b) - 20.0).abs() < 1e-4);
        assert!(psnr(&a, &a).is_infinite());
    }
}
