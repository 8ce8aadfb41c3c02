//! Pinhole intrinsics in the OpenCV optical frame (SPEC §2). Pixel (u, v) = (0, 0) is the
//! centre of the top-left pixel: a camera-frame point projects to `u = fx·x/z + cx`,
//! `v = fy·y/z + cy`, and pixel column `i` covers `u ∈ [i − 0.5, i + 0.5)`.

use nalgebra::{Point3, Vector2};
use serde::{Deserialize, Serialize};

/// Image size and pinhole parameters of a camera.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Intrinsics {
    /// Image width in pixels.
    pub width: u32,
    /// Image height in pixels.
    pub height: u32,
    /// Focal length along x, pixels.
    pub fx: f64,
    /// Focal length along y, pixels.
    pub fy: f64,
    /// Principal point x, pixels (pixel-centre convention of this module).
    pub cx: f64,
    /// Principal point y, pixels.
    pub cy: f64,
}

impl Intrinsics {
    /// A centred pinhole with the given horizontal field of view (radians) and square pixels,
    /// as a simulator sensor is specified (SPEC §1: 90° by default).
    pub fn from_hfov(width: u32, height: u32, hfov: f64) -> Self {
        let fx = 0.5 * width as f64 / (0.5 * hfov).tan();
        Self {
            width,
            height,
            fx,
            fy: fx,
            cx: 0.5 * width as f64 - 0.5,
            cy: 0.5 * height as f64 - 0.5,
        }
    }

    /// The same camera at a different resolution (scales focal lengths and principal point).
    pub fn scaled(&self, width: u32, height: u32) -> Self {
        let sx = width as f64 / self.width as f64;
        let sy = height as f64 / self.height as f64;
        Self {
            width,
            height,
            fx: self.fx * sx,
            fy: self.fy * sy,
            cx: (self.cx + 0.5) * sx - 0.5,
            cy: (self.cy + 0.5) * sy - 0.5,
        }
    }

    /// Projects a camera-frame point to pixel coordinates; `None` at or behind the camera.
    pub fn project(&self, p: &Point3<f64>) -> Option<Vector2<f64>> {
        (p.z > 0.0)
            .then(|| Vector2::new(self.fx * p.x / p.z + self.cx, self.fy * p.y / p.z + self.cy))
    }

    /// Back-projects pixel (u, v) at z-depth `depth` (metres) to a camera-frame point.
    pub fn unproject(&self, u: f64, v: f64, depth: f64) -> Point3<f64> {
        Point3::new(
            (u - self.cx) / self.fx * depth,
            (v - self.cy) / self.fy * depth,
            depth,
        )
    }

    /// Number of pixels.
    pub fn pixel_count(&self) -> usize {
        self.width as usize * self.height as usize
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn project_unproject_round_trip() {
        let k = Intrinsics::from_hfov(200, 100, std::f64::consts::FRAC_PI_2);
        assert!((k.fx - 100.0).abs() < 1e-12);
        let p = k.unproject(12.25, 77.5, 2.5);
        let uv = k.project(&p).unwrap();
        assert!((uv.x - 12.25).abs() < 1e-12 && (uv.y - 77.5).abs() < 1e-12);
        assert!(k.project(&Point3::new(0.0, 0.0, -1.0)).is_none());
    }

    #[test]
    fn hfov_edges_map_to_image_border() {
        // A ray at 45° lands on the outer edge of the last pixel column.
        let k = Intrinsics::from_hfov(64, 64, std::f64::consts::FRAC_PI_2);
        let uv = k.project(&Point3::new(1.0, 0.0, 1.0)).unwrap();
        assert!((uv.x - 63.5).abs() < 1e-12);
        let s = k.scaled(128, 128);
        let uv2 = s.project(&Point3::new(1.0, 0.0, 1.0)).unwrap();
        assert!((uv2.x - 127.5).abs() < 1e-12);
    }
}
