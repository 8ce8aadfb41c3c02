//! The RGB-D frame the library consumes: RGB in [0, 1] (f32), depth in metres (f32, 0 = no
//! reading, SPEC §2), its pinhole [`Intrinsics`] (OpenCV optical frame) and a time stamp.
//!
//! [`Frame::new`] checks sizes and sanitises values: non-finite or negative depth becomes 0
//! (no reading; depth drivers commonly mark missing returns NaN or ±inf), non-finite colour
//! becomes 0, both are counted, and colour is clamped to [0, 1]. [`Frame::usability`] then
//! decides whether the frame can be tracked at all (enough depth, neither black nor saturated,
//! colour not mostly NaN); unusable frames give a `Skipped` tracking status instead of an
//! error or a NaN pose.

use crate::error::SlamError;
use activemap_geometry::Intrinsics;

/// Smallest fraction of pixels with a depth reading for a frame to be tracked.
pub const MIN_VALID_DEPTH_FRACTION: f64 = 0.05;
/// A frame whose mean `R + G + B` is below this is "black" and skipped.
pub const BLACK_MEAN_RGB_SUM: f64 = 0.01;
/// A frame whose mean `R + G + B` is above this is "saturated" (blown-out white) and skipped.
pub const SATURATED_MEAN_RGB_SUM: f64 = 3.0 - BLACK_MEAN_RGB_SUM;
/// Largest fraction of non-finite colour samples before a frame is skipped. Non-finite depth
/// only means "no reading": depth is judged by [`MIN_VALID_DEPTH_FRACTION`].
pub const MAX_NON_FINITE_FRACTION: f64 = 0.05;

/// One RGB-D frame, row-major, `width × height` pixels.
#[derive(Debug, Clone, PartialEq)]
pub struct Frame {
    /// Camera model (image size, pinhole, OpenCV optical frame).
    pub intrinsics: Intrinsics,
    /// Colour per pixel, each channel in [0, 1].
    pub rgb: Vec<[f32; 3]>,
    /// Depth per pixel, metres along the optical axis; 0 = no reading.
    pub depth: Vec<f32>,
    /// Time stamp, seconds.
    pub stamp: f64,
    /// Number of non-finite samples (colour channels and depth) replaced on construction.
    pub non_finite_samples: usize,
    /// How many of `non_finite_samples` were depth readings (now 0, no reading).
    pub non_finite_depth: usize,
}

/// Why a frame cannot be tracked.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum SkipReason {
    /// Too few pixels carry a depth reading (e.g. an all-zero depth image).
    NoDepth,
    /// The colour image is (nearly) black.
    Black,
    /// The colour image is (nearly) all white: blown out, it carries no texture.
    Saturated,
    /// Too many colour samples were NaN or infinite.
    NonFinite,
}

impl std::fmt::Display for SkipReason {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let text = match self {
            SkipReason::NoDepth => "too few valid depth pixels",
            SkipReason::Black => "black colour image",
            SkipReason::Saturated => "saturated (all-white) colour image",
            SkipReason::NonFinite => "too many NaN/inf colour samples",
        };
        f.write_str(text)
    }
}

/// Checks that the intrinsics describe a usable pinhole camera.
pub fn validate_intrinsics(k: &Intrinsics) -> Result<(), SlamError> {
    if k.width == 0 || k.height == 0 {
        return Err(SlamError::Intrinsics(format!(
            "image size {}×{} is empty",
            k.width, k.height
        )));
    }
    let finite = [k.fx, k.fy, k.cx, k.cy].iter().all(|v| v.is_finite());
    if !finite || k.fx == 0.0 || k.fy == 0.0 {
        return Err(SlamError::Intrinsics(format!(
            "focal lengths/principal point must be finite, non-zero focal: {k:?}"
        )));
    }
    Ok(())
}

impl Frame {
    /// A frame from float colour and depth; checks sizes and sanitises non-finite values.
    pub fn new(
        intrinsics: Intrinsics,
        mut rgb: Vec<[f32; 3]>,
        mut depth: Vec<f32>,
        stamp: f64,
    ) -> Result<Self, SlamError> {
        validate_intrinsics(&intrinsics)?;
        let expected = intrinsics.pixel_count();
        let size_error = |what, got| SlamError::FrameSize {
            what,
            got,
            expected,
            width: intrinsics.width,
            height: intrinsics.height,
        };
        if rgb.len() != expected {
            return Err(size_error("rgb", rgb.len()));
        }
        if depth.len() != expected {
            return Err(size_error("depth", depth.len()));
        }
        let mut non_finite_rgb = 0;
        for c in rgb.iter_mut().flat_map(|p| p.iter_mut()) {
            if c.is_finite() {
                *c = c.clamp(0.0, 1.0);
            } else {
                *c = 0.0;
                non_finite_rgb += 1;
            }
        }
        let mut non_finite_depth = 0;
        for d in depth.iter_mut() {
            if !d.is_finite() {
                non_finite_depth += 1;
                *d = 0.0;
            } else if *d < 0.0 {
                *d = 0.0;
            }
        }
        Ok(Self {
            intrinsics,
            rgb,
            depth,
            stamp: if stamp.is_finite() { stamp } else { 0.0 },
            non_finite_samples: non_finite_rgb + non_finite_depth,
            non_finite_depth,
        })
    }

    /// A frame from 8-bit interleaved RGB (`3·width·height` bytes) and depth in metres.
    pub fn from_rgb8(
        intrinsics: Intrinsics,
        rgb8: &[u8],
        depth: Vec<f32>,
        stamp: f64,
    ) -> Result<Self, SlamError> {
        let expected = intrinsics.pixel_count() * 3;
        if rgb8.len() != expected {
            return Err(SlamError::FrameSize {
                what: "rgb8 bytes",
                got: rgb8.len(),
                expected,
                width: intrinsics.width,
                height: intrinsics.height,
            });
        }
        let rgb = rgb8
            .chunks_exact(3)
            .map(|c| [c[0], c[1], c[2]].map(|v| v as f32 / 255.0))
            .collect();
        Self::new(intrinsics, rgb, depth, stamp)
    }

    /// Image width, pixels.
    pub fn width(&self) -> usize {
        self.intrinsics.width as usize
    }

    /// Image height, pixels.
    pub fn height(&self) -> usize {
        self.intrinsics.height as usize
    }

    /// The pixel (rounded) that camera-frame point `p` falls on, when it lies in front of the
    /// camera and at least `border` pixels inside the image.
    pub fn pixel_of(&self, p: &nalgebra::Point3<f64>, border: usize) -> Option<(usize, usize)> {
        let uv = self.intrinsics.project(p)?;
        let (u, v) = (uv.x.round(), uv.y.round());
        let (b, w, h) = (border as f64, self.width() as f64, self.height() as f64);
        if u < b || v < b || u + b >= w || v + b >= h {
            return None;
        }
        Some((u as usize, v as usize))
    }

    /// Whether the frame can be tracked; `Err(reason)` means it must be skipped.
    pub fn usability(&self) -> Result<(), SkipReason> {
        let n = self.depth.len().max(1) as f64;
        let non_finite_rgb = self
            .non_finite_samples
            .saturating_sub(self.non_finite_depth);
        if non_finite_rgb as f64 > MAX_NON_FINITE_FRACTION * 3.0 * n {
            return Err(SkipReason::NonFinite);
        }
        let valid = self.depth.iter().filter(|&&d| d > 0.0).count() as f64;
        if valid < MIN_VALID_DEPTH_FRACTION * n {
            return Err(SkipReason::NoDepth);
        }
        let mean_sum = self
            .rgb
            .iter()
            .map(|c| (c[0] + c[1] + c[2]) as f64)
            .sum::<f64>()
            / n;
        if mean_sum < BLACK_MEAN_RGB_SUM {
            return Err(SkipReason::Black);
        }
        if mean_sum > SATURATED_MEAN_RGB_SUM {
            return Err(SkipReason::Saturated);
        }
        Ok(())
    }

    /// The frame at `1/factor` resolution (integer `factor ≥ 1`): colour is the block mean;
    /// depth is the mean of the block's valid readings when they agree within 5 % of the
    /// nearest, else 0 (a depth edge: averaging would invent a surface in mid-air). The
    /// intrinsics are rescaled with [`Intrinsics::scaled`], whose pixel-centre convention
    /// matches block averaging.
    pub fn downscale(&self, factor: usize) -> Frame {
        if factor <= 1 {
            return self.clone();
        }
        let (w, h) = (self.width(), self.height());
        let (nw, nh) = ((w / factor).max(1), (h / factor).max(1));
        // Keep the principal point consistent: crop to a multiple of the factor first.
        let k = Intrinsics {
            width: (nw * factor) as u32,
            height: (nh * factor) as u32,
            ..self.intrinsics
        }
        .scaled(nw as u32, nh as u32);
        let mut rgb = vec![[0f32; 3]; nw * nh];
        let mut depth = vec![0f32; nw * nh];
        for by in 0..nh {
            for bx in 0..nw {
                let mut c = [0f32; 3];
                let (mut dsum, mut dmin, mut dmax, mut dn) = (0f32, f32::MAX, 0f32, 0u32);
                for y in by * factor..(by + 1) * factor {
                    for x in bx * factor..(bx + 1) * factor {
                        let i = y * w + x;
                        for ch in 0..3 {
                            c[ch] += self.rgb[i][ch];
                        }
                        let d = self.depth[i];
                        if d > 0.0 {
                            dsum += d;
                            dmin = dmin.min(d);
                            dmax = dmax.max(d);
                            dn += 1;
                        }
                    }
                }
                let inv = 1.0 / (factor * factor) as f32;
                rgb[by * nw + bx] = c.map(|v| v * inv);
                if dn * 2 >= (factor * factor) as u32 && dmax - dmin <= 0.05 * dmin {
                    depth[by * nw + bx] = dsum / dn as f32;
                }
            }
        }
        Frame {
            intrinsics: k,
            rgb,
            depth,
            stamp: self.stamp,
            non_finite_samples: self.non_finite_samples,
            non_finite_depth: self.non_finite_depth,
        }
    }

    /// Median of the valid depth readings (metres), `None` without any.
    pub fn median_depth(&self) -> Option<f64> {
        let mut d: Vec<f32> = self.depth.iter().copied().filter(|&d| d > 0.0).collect();
        if d.is_empty() {
            return None;
        }
        let mid = d.len() / 2;
        let (_, m, _) = d.select_nth_unstable_by(mid, |a, b| a.total_cmp(b));
        Some(*m as f64)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn k(w: u32, h: u32) -> Intrinsics {
        Intrinsics::from_hfov(w, h, std::f64::consts::FRAC_PI_2)
    }

    #[test]
    fn size_mismatch_is_an_error_naming_the_buffer() {
        let e = Frame::new(k(4, 4), vec![[0.5; 3]; 16], vec![1.0; 15], 0.0)
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("depth") && e.contains("15") && e.contains("16"),
            "{e}"
        );
        let e = Frame::from_rgb8(k(4, 4), &[0; 47], vec![1.0; 16], 0.0)
            .unwrap_err()
            .to_string();
        assert!(e.contains("rgb8"), "{e}");
    }

    #[test]
    fn usability_flags_black_empty_and_nan_frames() {
        let good = Frame::new(k(8, 8), vec![[0.4; 3]; 64], vec![2.0; 64], 0.0).unwrap();
        assert_eq!(good.usability(), Ok(()));
        let no_depth = Frame::new(k(8, 8), vec![[0.4; 3]; 64], vec![0.0; 64], 0.0).unwrap();
        assert_eq!(no_depth.usability(), Err(SkipReason::NoDepth));
        let black = Frame::new(k(8, 8), vec![[0.0; 3]; 64], vec![2.0; 64], 0.0).unwrap();
        assert_eq!(black.usability(), Err(SkipReason::Black));
        let nan = Frame::new(k(8, 8), vec![[f32::NAN; 3]; 64], vec![f32::NAN; 64], 0.0).unwrap();
        assert_eq!(nan.usability(), Err(SkipReason::NonFinite));
        assert!(
            nan.depth.iter().all(|d| *d == 0.0)
                && nan.rgb.iter().all(|c| c.iter().all(|v| *v == 0.0))
        );
    }

    /// Bad numbers: all-NaN or all-±inf depth is "no depth", all-white colour is saturated;
    /// a minority of NaN/inf depth pixels is only missing readings (the frame stays usable),
    /// and out-of-range colour is clamped to [0, 1].
    #[test]
    fn non_finite_depth_is_no_reading_and_white_frames_are_saturated() {
        let rgb = || vec![[0.4f32; 3]; 64];
        for bad in [f32::NAN, f32::INFINITY, f32::NEG_INFINITY] {
            let f = Frame::new(k(8, 8), rgb(), vec![bad; 64], 0.0).unwrap();
            assert_eq!(f.usability(), Err(SkipReason::NoDepth), "depth {bad}");
            assert_eq!((f.non_finite_samples, f.non_finite_depth), (64, 64));
            assert!(f.depth.iter().all(|d| *d == 0.0) && f.median_depth().is_none());
        }
        let white = Frame::from_rgb8(k(8, 8), &[255; 192], vec![2.0; 64], 0.0).unwrap();
        assert_eq!(white.usability(), Err(SkipReason::Saturated));
        // 40 % of the depth pixels NaN or inf: usable, those pixels carry no reading.
        let depth: Vec<f32> = (0..64)
            .map(|i| match i % 5 {
                0 => f32::NAN,
                1 => f32::INFINITY,
                _ => 2.0,
            })
            .collect();
        let holes = Frame::new(k(8, 8), rgb(), depth, 0.0).unwrap();
        assert_eq!(holes.usability(), Ok(()));
        assert_eq!(holes.depth.iter().filter(|d| **d == 0.0).count(), 26);
        assert_eq!(holes.median_depth(), Some(2.0));
        assert_eq!(holes.downscale(2).non_finite_depth, 26);
        let loud = Frame::new(k(2, 1), vec![[7.0, -1.0, 0.5]; 2], vec![1.0; 2], f64::NAN).unwrap();
        assert_eq!(loud.rgb[0], [1.0, 0.0, 0.5]);
        assert_eq!(loud.stamp, 0.0);
    }

    #[test]
    fn downscale_averages_and_drops_depth_edges() {
        // 4×2 image: left block depth 1.0/1.02 (kept, mean), right block 1.0/3.0 (edge -> 0).
        let rgb = vec![
            [0.0; 3], [1.0; 3], [0.2; 3], [0.2; 3], [0.0; 3], [1.0; 3], [0.2; 3], [0.2; 3],
        ];
        let depth = vec![1.0, 1.02, 1.0, 3.0, 1.0, 1.02, 1.0, 3.0];
        let f = Frame::new(k(4, 2), rgb, depth, 0.0).unwrap().downscale(2);
        assert_eq!((f.width(), f.height()), (2, 1));
        assert!((f.rgb[0][1] - 0.5).abs() < 1e-6 && (f.rgb[1][0] - 0.2).abs() < 1e-6);
        assert!((f.depth[0] - 1.01).abs() < 1e-6);
        assert_eq!(f.depth[1], 0.0);
        // The rescaled camera sees a point at the same place: pixel centre 0 covers old 0..2.
        assert!((f.intrinsics.fx - 1.0).abs() < 1e-12 && (f.intrinsics.cx - 0.5).abs() < 1e-12);
    }
}
