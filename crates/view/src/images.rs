//! Images for the view channels: colour as JPEG, depth as a colour-mapped PNG.
//!
//! The view shows the images; the exact pixels (colour bytes and f32 depth) stay in the
//! recording's replay channel, so the view may compress lossily.

use image::codecs::jpeg::JpegEncoder;
use image::codecs::png::{CompressionType, FilterType, PngEncoder};
use image::{ExtendedColorType, ImageEncoder};

/// Encode an RGB8 image (`width·height·3` bytes, row-major) as JPEG of the given quality (1–100).
pub fn rgb_to_jpeg(
    rgb: &[u8],
    width: u32,
    height: u32,
    quality: u8,
) -> Result<Vec<u8>, image::ImageError> {
    let mut out = Vec::with_capacity(rgb.len() / 8);
    JpegEncoder::new_with_quality(&mut out, quality.clamp(1, 100)).write_image(
        rgb,
        width,
        height,
        ExtendedColorType::Rgb8,
    )?;
    Ok(out)
}

/// Encode an RGB8 image as PNG (fast compression: the recorder runs beside the operators).
pub fn rgb_to_png(rgb: &[u8], width: u32, height: u32) -> Result<Vec<u8>, image::ImageError> {
    let mut out = Vec::new();
    PngEncoder::new_with_quality(&mut out, CompressionType::Fast, FilterType::Adaptive)
        .write_image(rgb, width, height, ExtendedColorType::Rgb8)?;
    Ok(out)
}

/// Colour stops of the depth colour map, from near (0) to far (1): dark blue, teal, green,
/// yellow, pale yellow. Monotone in brightness, so a grey-scale print still reads as depth.
const DEPTH_STOPS: [[f32; 3]; 5] = [
    [30.0, 30.0, 120.0],
    [30.0, 140.0, 160.0],
    [90.0, 200.0, 90.0],
    [240.0, 220.0, 40.0],
    [255.0, 250.0, 215.0],
];

/// The colour of a depth in metres on a `[0, max_depth]` ramp; black for no reading (0, or not
/// finite, SPEC §2) and the far end for anything beyond `max_depth`.
pub fn depth_color(depth: f32, max_depth: f32) -> [u8; 3] {
    if !(depth.is_finite() && depth > 0.0) {
        return [0, 0, 0];
    }
    let t = (depth / max_depth.max(f32::MIN_POSITIVE)).clamp(0.0, 1.0);
    let pos = t * (DEPTH_STOPS.len() - 1) as f32;
    let i = (pos.floor() as usize).min(DEPTH_STOPS.len() - 2);
    let f = pos - i as f32;
    let (a, b) = (DEPTH_STOPS[i], DEPTH_STOPS[i + 1]);
    std::array::from_fn(|c| (a[c] + (b[c] - a[c]) * f).round() as u8)
}

/// A depth image (metres, row-major) colour-mapped with [`depth_color`] and encoded as PNG.
pub fn depth_to_png(
    depth: &[f32],
    width: u32,
    height: u32,
    max_depth: f32,
) -> Result<Vec<u8>, image::ImageError> {
    let rgb: Vec<u8> = depth
        .iter()
        .flat_map(|&d| depth_color(d, max_depth))
        .collect();
    rgb_to_png(&rgb, width, height)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_depth_ramp_brightens_with_depth_and_marks_missing_readings_black() {
        let luma = |c: [u8; 3]| 0.299 * c[0] as f32 + 0.587 * c[1] as f32 + 0.114 * c[2] as f32;
        let mut last = -1.0;
        for i in 1..=100 {
            let c = depth_color(i as f32 * 0.05, 5.0);
            assert!(luma(c) > last, "depth {} not brighter", i as f32 * 0.05);
            last = luma(c);
        }
        assert_eq!(depth_color(0.0, 5.0), [0, 0, 0]);
        assert_eq!(depth_color(f32::NAN, 5.0), [0, 0, 0]);
        assert_eq!(depth_color(f32::INFINITY, 5.0), [0, 0, 0]);
        assert_eq!(depth_color(50.0, 5.0), depth_color(5.0, 5.0));
    }

    #[test]
    fn images_decode_back_with_their_size_and_content() {
        let (w, h) = (8u32, 6u32);
        let rgb: Vec<u8> = (0..w * h * 3).map(|i| (i * 5 % 256) as u8).collect();
        let png = rgb_to_png(&rgb, w, h).unwrap();
        let back = image::load_from_memory(&png).unwrap().to_rgb8();
        assert_eq!((back.width(), back.height()), (w, h));
        assert_eq!(back.into_raw(), rgb, "PNG is lossless");
        let flat = vec![128u8; (w * h * 3) as usize];
        let jpeg = rgb_to_jpeg(&flat, w, h, 90).unwrap();
        let back = image::load_from_memory(&jpeg).unwrap().to_rgb8();
        assert_eq!((back.width(), back.height()), (w, h));
        assert!(
            back.pixels()
                .all(|p| p.0.iter().all(|&c| c.abs_diff(128) <= 2))
        );
        let depth: Vec<f32> = (0..w * h).map(|i| i as f32 * 0.1).collect();
        let png = depth_to_png(&depth, w, h, 5.0).unwrap();
        let back = image::load_from_memory(&png).unwrap().to_rgb8();
        assert_eq!(back.get_pixel(0, 0).0, [0, 0, 0]);
        assert_eq!(back.get_pixel(3, 2).0, depth_color(1.9, 5.0));
    }
}
