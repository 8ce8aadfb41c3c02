//! The image form every image metric takes: a borrowed, row-major, channel-interleaved `f32`
//! buffer with its size. RGB is 3 channels in [0, 1] (data range 1); depth is 1 channel in
//! metres with 0 = no reading (SPEC §2). No conversion and no copy.

use crate::error::EvalError;

/// A borrowed image: pixel `(x, y)` channel `c` is `data[(y * width + x) * channels + c]`.
/// Built only through [`ImageView::new`] (or `rgb`/`depth`), so its size always matches its data.
#[derive(Debug, Clone, Copy)]
pub struct ImageView<'a> {
    /// The samples, row-major, channels interleaved.
    pub(crate) data: &'a [f32],
    /// Columns.
    pub(crate) width: usize,
    /// Rows.
    pub(crate) height: usize,
    /// Samples per pixel (3 for RGB, 1 for depth).
    pub(crate) channels: usize,
}

impl<'a> ImageView<'a> {
    /// Wraps `data`, checking that it holds exactly `width × height × channels` samples.
    pub fn new(
        data: &'a [f32],
        width: usize,
        height: usize,
        channels: usize,
    ) -> Result<Self, EvalError> {
        if channels == 0 {
            return Err(EvalError::InvalidParameter {
                metric: "image",
                detail: "an image needs at least one channel".into(),
            });
        }
        let expected = width
            .checked_mul(height)
            .and_then(|n| n.checked_mul(channels));
        if expected != Some(data.len()) {
            return Err(EvalError::SizeMismatch {
                metric: "image",
                detail: format!(
                    "{width}×{height}×{channels} needs {} samples, the buffer holds {}",
                    expected.map_or_else(|| "too many".to_string(), |n| n.to_string()),
                    data.len()
                ),
            });
        }
        Ok(Self {
            data,
            width,
            height,
            channels,
        })
    }

    /// An RGB image (3 channels, values in [0, 1]).
    pub fn rgb(data: &'a [f32], width: usize, height: usize) -> Result<Self, EvalError> {
        Self::new(data, width, height, 3)
    }

    /// A depth image (1 channel, metres, 0 = no reading).
    pub fn depth(data: &'a [f32], width: usize, height: usize) -> Result<Self, EvalError> {
        Self::new(data, width, height, 1)
    }

    /// The samples, row-major, channels interleaved.
    pub fn data(&self) -> &'a [f32] {
        self.data
    }

    /// Columns.
    pub fn width(&self) -> usize {
        self.width
    }

    /// Rows.
    pub fn height(&self) -> usize {
        self.height
    }

    /// Samples per pixel.
    pub fn channels(&self) -> usize {
        self.channels
    }

    /// Human-readable location of sample `index`, for error messages.
    pub(crate) fn location(&self, index: usize) -> String {
        let pixel = index / self.channels;
        let (x, y) = (pixel % self.width, pixel / self.width);
        if self.channels == 1 {
            format!("pixel (x {x}, y {y})")
        } else {
            format!("pixel (x {x}, y {y}) channel {}", index % self.channels)
        }
    }

    /// Fails with the first non-finite sample, naming `input` and its pixel.
    pub(crate) fn check_finite(
        &self,
        metric: &'static str,
        input: &'static str,
    ) -> Result<(), EvalError> {
        match self.data.iter().position(|v| !v.is_finite()) {
            None => Ok(()),
            Some(i) => Err(EvalError::NonFinite {
                metric,
                input,
                location: self.location(i),
            }),
        }
    }
}

/// Fails unless `a` and `b` have the same width, height and channel count.
pub(crate) fn check_same_shape(
    metric: &'static str,
    a: &ImageView<'_>,
    b: &ImageView<'_>,
) -> Result<(), EvalError> {
    check_shape_against_truth(metric, "rendered", a, b)
}

/// Fails unless `image` (called `name` in the error) has the width, height and channel count of
/// `truth`.
fn check_shape_against_truth(
    metric: &'static str,
    name: &str,
    image: &ImageView<'_>,
    truth: &ImageView<'_>,
) -> Result<(), EvalError> {
    let shape = |v: &ImageView<'_>| (v.width, v.height, v.channels);
    if shape(image) != shape(truth) {
        return Err(EvalError::SizeMismatch {
            metric,
            detail: format!(
                "{name} is {}×{}×{}, truth is {}×{}×{}",
                image.width,
                image.height,
                image.channels,
                truth.width,
                truth.height,
                truth.channels
            ),
        });
    }
    Ok(())
}

/// Fails unless `truth` and each named image are 1-channel images of one size (depth, opacity)
/// with finite samples; the errors name the image and, for a non-finite sample, its pixel.
pub(crate) fn check_depth_images(
    metric: &'static str,
    named: &[(&'static str, &ImageView<'_>)],
    truth: &ImageView<'_>,
) -> Result<(), EvalError> {
    for (name, image) in named {
        check_shape_against_truth(metric, name, image, truth)?;
    }
    if truth.channels != 1 {
        return Err(EvalError::InvalidParameter {
            metric,
            detail: format!("depth images have 1 channel, got {}", truth.channels),
        });
    }
    for (name, image) in named {
        image.check_finite(metric, name)?;
    }
    truth.check_finite(metric, "truth")
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn wrong_length_is_refused_with_sizes() {
        let data = vec![0.0f32; 11];
        let e = ImageView::rgb(&data, 2, 2).unwrap_err().to_string();
        assert!(
            e.contains("2×2×3") && e.contains("12") && e.contains("11"),
            "{e}"
        );
    }

    #[test]
    fn location_names_pixel_and_channel() {
        let data = vec![0.0f32; 4 * 3 * 3];
        let img = ImageView::rgb(&data, 4, 3).unwrap();
        // sample 3*(1*4+2)+1 = 19 is pixel x 2, y 1, channel 1
        assert_eq!(img.location(19), "pixel (x 2, y 1) channel 1");
    }
}
