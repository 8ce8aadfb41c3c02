//! Where the depth error comes from: each valid ground-truth pixel of a test view is put in one
//! class by the map's rendered opacity `o` and its opacity-normalised depth `n = D̂ / o` against
//! the true depth `D` (D̂ is the composited depth the depth MAE scores, SPEC §8):
//!
//! | class | rule |
//! | --- | --- |
//! | `unmapped` | `o < 0.5`: the map shows (almost) nothing there |
//! | `translucent` | `0.5 ≤ o < 0.95`: a half-transparent surface |
//! | `in_front` | opaque and `n < (1 − 5 %) D`: a surface in front of the true one |
//! | `behind` | opaque and `n > (1 + 5 %) D`: a surface behind the true one |
//! | `on_surface` | the rest |
//!
//! Per class: its share of the pixels, its share of the summed |D̂ − D|, and its mean |D̂ − D|.
//! The sums pool the pixels of all views, so the pooled mean error can differ from the depth MAE,
//! which averages the views' means. A map whose error is mostly `in_front` has surfaces that
//! reach past where they end (issue 33: stretched discs smeared over close test views); mostly
//! `unmapped` means unexplored space; `behind` a map that sits behind its surfaces.

use crate::error::EvalError;
use crate::image::{ImageView, check_depth_images};
use serde::{Deserialize, Serialize};

/// Rendered opacity below which a pixel counts as unmapped.
pub const UNMAPPED_BELOW_OPACITY: f32 = 0.5;
/// Rendered opacity below which a mapped pixel counts as translucent.
pub const TRANSLUCENT_BELOW_OPACITY: f32 = 0.95;
/// Relative depth difference beyond which an opaque pixel is in front of or behind the truth.
pub const SURFACE_TOLERANCE: f32 = 0.05;

/// The class of one pixel's depth error (see the module doc).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum DepthErrorClass {
    /// Rendered opacity below 0.5.
    Unmapped,
    /// Rendered opacity in [0.5, 0.95).
    Translucent,
    /// Opaque, the normalised depth more than 5 % short of the truth.
    InFront,
    /// Opaque, the normalised depth more than 5 % beyond the truth.
    Behind,
    /// Opaque and within 5 % of the truth.
    OnSurface,
}

impl DepthErrorClass {
    /// Every class, in the order of the report.
    pub const ALL: [DepthErrorClass; 5] = [
        Self::Unmapped,
        Self::Translucent,
        Self::InFront,
        Self::Behind,
        Self::OnSurface,
    ];

    /// The class of a pixel with rendered depth `rendered`, opacity `opacity` and true depth
    /// `truth` (> 0).
    pub fn of(rendered: f32, opacity: f32, truth: f32) -> Self {
        if opacity < UNMAPPED_BELOW_OPACITY {
            return Self::Unmapped;
        }
        if opacity < TRANSLUCENT_BELOW_OPACITY {
            return Self::Translucent;
        }
        let normalised = rendered / opacity;
        if normalised < truth * (1.0 - SURFACE_TOLERANCE) {
            Self::InFront
        } else if normalised > truth * (1.0 + SURFACE_TOLERANCE) {
            Self::Behind
        } else {
            Self::OnSurface
        }
    }

    /// A short label for tables.
    pub fn label(self) -> &'static str {
        match self {
            Self::Unmapped => "unmapped (opacity < 0.5)",
            Self::Translucent => "translucent (opacity 0.5–0.95)",
            Self::InFront => "in front of the truth (> 5 %)",
            Self::Behind => "behind the truth (> 5 %)",
            Self::OnSurface => "on the surface (within 5 %)",
        }
    }

    /// The colour of the class in `eval/*_depth_classes.png`: unmapped black, translucent
    /// yellow, in front red, behind blue, on the surface grey (no ground truth: white).
    pub fn colour(self) -> [f32; 3] {
        match self {
            Self::Unmapped => [0.0, 0.0, 0.0],
            Self::Translucent => [0.95, 0.8, 0.1],
            Self::InFront => [0.9, 0.1, 0.1],
            Self::Behind => [0.15, 0.3, 0.95],
            Self::OnSurface => [0.6, 0.6, 0.6],
        }
    }

    fn index(self) -> usize {
        self as usize
    }
}

/// Pixel counts and summed absolute depth errors per [`DepthErrorClass`], over any number of
/// views ([`DepthErrorTally::add_view`], [`DepthErrorTally::merge`]).
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct DepthErrorTally {
    pixels: [u64; 5],
    error_sum_m: [f64; 5],
}

impl DepthErrorTally {
    /// Adds the valid pixels (truth > 0) of one view: rendered depth, rendered opacity and true
    /// depth, all 1-channel images of one size.
    pub fn add_view(
        &mut self,
        rendered: ImageView<'_>,
        opacity: ImageView<'_>,
        truth: ImageView<'_>,
    ) -> Result<(), EvalError> {
        let classes = classified_pixels(rendered, opacity, truth)?;
        for ((class, &r), &d) in classes.zip(rendered.data).zip(truth.data) {
            if let Some(class) = class {
                self.pixels[class.index()] += 1;
                self.error_sum_m[class.index()] += (f64::from(r) - f64::from(d)).abs();
            }
        }
        Ok(())
    }

    /// Adds another tally (e.g. of views scored in parallel).
    pub fn merge(&mut self, other: &DepthErrorTally) {
        for i in 0..5 {
            self.pixels[i] += other.pixels[i];
            self.error_sum_m[i] += other.error_sum_m[i];
        }
    }

    /// Valid pixels counted.
    pub fn pixels(&self) -> u64 {
        self.pixels.iter().sum()
    }

    /// The pooled mean |D̂ − D| over every counted pixel, metres; `None` without pixels.
    pub fn pooled_mean_error_m(&self) -> Option<f64> {
        let n = self.pixels();
        (n > 0).then(|| self.error_sum_m.iter().sum::<f64>() / n as f64)
    }

    /// One row per class: shares of pixels and of error, mean error; empty without pixels.
    pub fn shares(&self) -> Vec<DepthErrorShare> {
        let pixels = self.pixels();
        if pixels == 0 {
            return Vec::new();
        }
        let error: f64 = self.error_sum_m.iter().sum();
        DepthErrorClass::ALL
            .iter()
            .map(|&class| {
                let i = class.index();
                DepthErrorShare {
                    class,
                    pixel_share: self.pixels[i] as f64 / pixels as f64,
                    error_share: if error > 0.0 {
                        self.error_sum_m[i] / error
                    } else {
                        0.0
                    },
                    mean_error_m: (self.pixels[i] > 0)
                        .then(|| self.error_sum_m[i] / self.pixels[i] as f64),
                }
            })
            .collect()
    }
}

/// An RGB image in [0, 1] with each pixel in its class's [`DepthErrorClass::colour`] (white where
/// the ground truth has no reading): where a view's depth error comes from, at a glance.
pub fn depth_class_image(
    rendered: ImageView<'_>,
    opacity: ImageView<'_>,
    truth: ImageView<'_>,
) -> Result<Vec<f32>, EvalError> {
    Ok(classified_pixels(rendered, opacity, truth)?
        .flat_map(|class| class.map_or([1.0; 3], DepthErrorClass::colour))
        .collect())
}

/// Each pixel's [`DepthErrorClass`], row-major (`None` where the truth has no reading), after
/// checking that the three images are finite 1-channel images of one size.
fn classified_pixels<'a>(
    rendered: ImageView<'a>,
    opacity: ImageView<'a>,
    truth: ImageView<'a>,
) -> Result<impl Iterator<Item = Option<DepthErrorClass>> + 'a, EvalError> {
    check_depth_images(
        "depth error breakdown",
        &[("rendered", &rendered), ("opacity", &opacity)],
        &truth,
    )?;
    Ok(rendered
        .data
        .iter()
        .zip(opacity.data)
        .zip(truth.data)
        .map(|((&r, &o), &d)| (d > 0.0).then(|| DepthErrorClass::of(r, o, d))))
}

/// One class's part of the depth error over the test views (`metrics.json`,
/// `depth_error_breakdown`).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct DepthErrorShare {
    /// The class.
    pub class: DepthErrorClass,
    /// Its share of the valid ground-truth pixels, fraction in [0, 1].
    pub pixel_share: f64,
    /// Its share of the summed |D̂ − D|, fraction in [0, 1].
    pub error_share: f64,
    /// Its mean |D̂ − D|, metres; `None` when no pixel fell in it.
    pub mean_error_m: Option<f64>,
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn each_pixel_lands_in_the_class_its_opacity_and_depth_say() {
        // (rendered depth, opacity, true depth, class)
        let cases = [
            (0.5, 0.4, 2.0, DepthErrorClass::Unmapped),
            (1.8, 0.9, 2.0, DepthErrorClass::Translucent),
            // Normalised depth 1.9 / 0.95 = 2.0: on the surface although D̂ is 5 % short.
            (1.9, 0.95, 2.0, DepthErrorClass::OnSurface),
            (1.85, 1.0, 2.0, DepthErrorClass::InFront),
            (2.15, 1.0, 2.0, DepthErrorClass::Behind),
            (2.09, 1.0, 2.0, DepthErrorClass::OnSurface),
        ];
        for (rendered, opacity, truth, class) in cases {
            assert_eq!(
                DepthErrorClass::of(rendered, opacity, truth),
                class,
                "{rendered} {opacity} {truth}"
            );
        }
    }

    #[test]
    fn shares_pool_the_pixels_of_all_views_and_skip_invalid_truth() {
        // View a (2×2): truth [2, 2, 0, 4]; one pixel unmapped (error 2), one in front (0.5),
        // the invalid one ignored, one on the surface (0.1).
        let truth_a = [2.0f32, 2.0, 0.0, 4.0];
        let rendered_a = [0.0f32, 1.5, 9.0, 4.1];
        let opacity_a = [0.0f32, 1.0, 1.0, 1.0];
        // View b (1×2): one behind (1.0), one translucent (D̂ 1.0 against 3: error 2).
        let truth_b = [2.0f32, 3.0];
        let rendered_b = [3.0f32, 1.0];
        let opacity_b = [1.0f32, 0.6];
        fn dep(d: &[f32], w: usize, h: usize) -> ImageView<'_> {
            ImageView::depth(d, w, h).unwrap()
        }
        let mut a = DepthErrorTally::default();
        a.add_view(
            dep(&rendered_a, 2, 2),
            dep(&opacity_a, 2, 2),
            dep(&truth_a, 2, 2),
        )
        .unwrap();
        let mut b = DepthErrorTally::default();
        b.add_view(
            dep(&rendered_b, 1, 2),
            dep(&opacity_b, 1, 2),
            dep(&truth_b, 1, 2),
        )
        .unwrap();
        a.merge(&b);
        assert_eq!(a.pixels(), 5);
        let total = 2.0 + 0.5 + 0.1 + 1.0 + 2.0;
        assert!((a.pooled_mean_error_m().unwrap() - total / 5.0).abs() < 1e-6);
        let shares = a.shares();
        let expect = [
            (DepthErrorClass::Unmapped, 2.0),
            (DepthErrorClass::Translucent, 2.0),
            (DepthErrorClass::InFront, 0.5),
            (DepthErrorClass::Behind, 1.0),
            (DepthErrorClass::OnSurface, 0.1),
        ];
        for (row, (class, error)) in shares.iter().zip(expect) {
            assert_eq!(row.class, class);
            assert!((row.pixel_share - 0.2).abs() < 1e-12, "{row:?}");
            assert!((row.error_share - error / total).abs() < 1e-6, "{row:?}");
            assert!((row.mean_error_m.unwrap() - error).abs() < 1e-6, "{row:?}");
        }
        let sum: f64 = shares.iter().map(|r| r.error_share).sum();
        assert!((sum - 1.0).abs() < 1e-12);
    }

    #[test]
    fn the_class_image_colours_each_pixel_by_its_class() {
        let truth = [2.0f32, 0.0, 2.0];
        let rendered = [1.0f32, 1.0, 2.0];
        let opacity = [1.0f32, 1.0, 1.0];
        let image = depth_class_image(
            ImageView::depth(&rendered, 3, 1).unwrap(),
            ImageView::depth(&opacity, 3, 1).unwrap(),
            ImageView::depth(&truth, 3, 1).unwrap(),
        )
        .unwrap();
        let expected: Vec<f32> = [
            DepthErrorClass::InFront.colour(),
            [1.0; 3],
            DepthErrorClass::OnSurface.colour(),
        ]
        .concat();
        assert_eq!(image, expected);
    }

    #[test]
    fn bad_inputs_are_named_and_an_empty_tally_has_no_rows() {
        let mut tally = DepthErrorTally::default();
        assert!(tally.shares().is_empty() && tally.pooled_mean_error_m().is_none());
        let e = tally
            .add_view(
                ImageView::depth(&[1.0; 4], 2, 2).unwrap(),
                ImageView::depth(&[1.0; 2], 1, 2).unwrap(),
                ImageView::depth(&[1.0; 4], 2, 2).unwrap(),
            )
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("size mismatch") && e.contains("breakdown"),
            "{e}"
        );
        let e = tally
            .add_view(
                ImageView::depth(&[1.0; 4], 2, 2).unwrap(),
                ImageView::depth(&[1.0, f32::NAN, 1.0, 1.0], 2, 2).unwrap(),
                ImageView::depth(&[1.0; 4], 2, 2).unwrap(),
            )
            .unwrap_err()
            .to_string();
        assert!(e.contains("opacity"), "{e}");
    }
}
