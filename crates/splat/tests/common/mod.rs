//! Shared helpers of the integration tests: seeded random scenes and cameras.

#![allow(dead_code)]

use activemap_geometry::Intrinsics;
use activemap_splat::{Camera, Gaussians, PixelGrads, Real, Render};
use nalgebra::{Isometry3, Translation3, UnitQuaternion, Vector3};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

pub fn rng(seed: u64) -> ChaCha8Rng {
    ChaCha8Rng::seed_from_u64(seed)
}

/// A camera at `T_world_camera` built from a position and a rotation vector.
pub fn camera(
    width: u32,
    height: u32,
    hfov_deg: f64,
    position: [f64; 3],
    rotvec: [f64; 3],
) -> Camera {
    let k = Intrinsics::from_hfov(width, height, hfov_deg.to_radians());
    let pose = Isometry3::from_parts(
        Translation3::new(position[0], position[1], position[2]),
        UnitQuaternion::from_scaled_axis(Vector3::new(rotvec[0], rotvec[1], rotvec[2])),
    );
    Camera::from_world_pose(k, &pose)
}

/// Random Gaussians in the view of the camera at the origin looking along +z: depth in
/// [1.5, 3], inside ±0.35 of the view direction, scales 0.04–0.15 m, opacity in `opacity`.
pub fn random_scene<T: Real>(seed: u64, n: usize, opacity: (f64, f64)) -> Gaussians<T> {
    let mut r = rng(seed);
    let mut g = Gaussians::new();
    for _ in 0..n {
        let z = r.random_range(1.5..3.0);
        let mean = [
            r.random_range(-0.35..0.35) * z,
            r.random_range(-0.3..0.3) * z,
            z,
        ];
        let rgb = [
            r.random_range(0.0..1.0),
            r.random_range(0.0..1.0),
            r.random_range(0.0..1.0),
        ];
        let q = [
            r.random_range(-1.0..1.0),
            r.random_range(-1.0..1.0),
            r.random_range(-1.0..1.0),
            r.random_range(-1.0..1.0),
        ];
        let scale = [
            r.random_range(0.04..0.15),
            r.random_range(0.04..0.15),
            r.random_range(0.04..0.15),
        ];
        g.push(mean, rgb, q, r.random_range(opacity.0..opacity.1), scale);
    }
    g
}

/// Random per-pixel loss weights: L = Σ wc·C + wd·D + wo·O.
pub fn random_pixel_grads<T: Real>(seed: u64, pixels: usize) -> PixelGrads<T> {
    let mut r = rng(seed);
    let mut g = PixelGrads::zeros(pixels);
    for i in 0..pixels {
        g.colour[i] = [0; 3].map(|_| T::of(r.random_range(-1.0..1.0)));
        g.depth[i] = T::of(r.random_range(-1.0..1.0));
        g.opacity[i] = T::of(r.random_range(-1.0..1.0));
    }
    g
}

/// The linear loss of `random_pixel_grads` evaluated on a render.
pub fn linear_loss(r: &Render<f64>, w: &PixelGrads<f64>) -> f64 {
    let mut l = 0.0;
    for i in 0..r.colour.len() {
        for ch in 0..3 {
            l += w.colour[i][ch] * r.colour[i][ch];
        }
        l += w.depth[i] * r.depth[i] + w.opacity[i] * r.opacity[i];
    }
    l
}

/// Peak signal-to-noise ratio of two RGB images in [0, 1].
pub fn psnr(a: &[[f32; 3]], b: &[[f32; 3]]) -> f64 {
    let mut se = 0.0;
    for (x, y) in a.iter().zip(b) {
        for ch in 0..3 {
            let d = (x[ch] - y[ch]) as f64;
            se += d * d;
        }
    }
    let mse = se / (3 * a.len()) as f64;
    -10.0 * mse.log10()
}
