//! A plain scatter plot as a PNG (the EIG–PSNR figure of `activemap bench eig-psnr`): a framed
//! plot area, round tick values as tick marks and light grid lines, tick labels, axis labels
//! and a title in a built-in 3×5 pixel font (digits, capitals and a few signs; the workspace has
//! no font), points as small discs.

use std::path::Path;

use anyhow::Context as _;
use image::{Rgb, RgbImage};

/// What to plot.
#[derive(Debug, Clone, Copy)]
pub struct Scatter<'a> {
    /// Title above the plot.
    pub title: &'a str,
    /// Label under the x axis.
    pub x_label: &'a str,
    /// Label above the y axis.
    pub y_label: &'a str,
    /// The points; non-finite ones are left out.
    pub points: &'a [(f64, f64)],
}

const WIDTH: u32 = 720;
const HEIGHT: u32 = 540;
const LEFT: i64 = 76;
const RIGHT: i64 = 24;
const TOP: i64 = 48;
const BOTTOM: i64 = 64;
/// Font pixel size (each glyph cell is 3×5 of these).
const SCALE: i64 = 2;

const WHITE: Rgb<u8> = Rgb([255, 255, 255]);
const BLACK: Rgb<u8> = Rgb([0, 0, 0]);
const GRID: Rgb<u8> = Rgb([225, 225, 225]);
const POINT: Rgb<u8> = Rgb([31, 90, 190]);

use activemap_eval::html::ticks as nice_ticks;

/// A tick value printed without trailing zeros.
fn tick_text(v: f64) -> String {
    let s = format!("{v:.3}");
    let s = s.trim_end_matches('0').trim_end_matches('.');
    if s == "-0" { "0".into() } else { s.into() }
}

/// Rows of a 3×5 glyph (bit 2 = left column); unknown characters are blank.
fn glyph(c: char) -> [u8; 5] {
    match c.to_ascii_uppercase() {
        '0' => [7, 5, 5, 5, 7],
        '1' => [2, 6, 2, 2, 7],
        '2' => [7, 1, 7, 4, 7],
        '3' => [7, 1, 7, 1, 7],
        '4' => [5, 5, 7, 1, 1],
        '5' => [7, 4, 7, 1, 7],
        '6' => [7, 4, 7, 5, 7],
        '7' => [7, 1, 1, 1, 1],
        '8' => [7, 5, 7, 5, 7],
        '9' => [7, 5, 7, 1, 7],
        '.' => [0, 0, 0, 0, 2],
        ',' => [0, 0, 0, 2, 4],
        '-' => [0, 0, 7, 0, 0],
        '+' => [0, 2, 7, 2, 0],
        '=' => [0, 7, 0, 7, 0],
        '(' => [1, 2, 2, 2, 1],
        ')' => [4, 2, 2, 2, 4],
        ':' => [0, 2, 0, 2, 0],
        '/' => [1, 1, 2, 4, 4],
        '<' => [1, 2, 4, 2, 1],
        '>' => [4, 2, 1, 2, 4],
        'A' => [2, 5, 7, 5, 5],
        'B' => [6, 5, 6, 5, 6],
        'C' => [3, 4, 4, 4, 3],
        'D' => [6, 5, 5, 5, 6],
        'E' => [7, 4, 6, 4, 7],
        'F' => [7, 4, 6, 4, 4],
        'G' => [3, 4, 5, 5, 3],
        'H' => [5, 5, 7, 5, 5],
        'I' => [7, 2, 2, 2, 7],
        'J' => [1, 1, 1, 5, 2],
        'K' => [5, 5, 6, 5, 5],
        'L' => [4, 4, 4, 4, 7],
        'M' => [5, 7, 7, 5, 5],
        'N' => [6, 5, 5, 5, 5],
        'O' => [2, 5, 5, 5, 2],
        'P' => [6, 5, 6, 4, 4],
        'Q' => [2, 5, 5, 6, 3],
        'R' => [6, 5, 6, 5, 5],
        'S' => [3, 4, 2, 1, 6],
        'T' => [7, 2, 2, 2, 2],
        'U' => [5, 5, 5, 5, 7],
        'V' => [5, 5, 5, 5, 2],
        'W' => [5, 5, 7, 7, 5],
        'X' => [5, 5, 2, 5, 5],
        'Y' => [5, 5, 2, 2, 2],
        'Z' => [7, 1, 2, 4, 7],
        _ => [0; 5],
    }
}

/// Width in pixels of `text` in the built-in font.
fn text_width(text: &str) -> i64 {
    text.chars().count() as i64 * 4 * SCALE - SCALE
}

fn put(img: &mut RgbImage, x: i64, y: i64, c: Rgb<u8>) {
    if x >= 0 && y >= 0 && x < img.width() as i64 && y < img.height() as i64 {
        img.put_pixel(x as u32, y as u32, c);
    }
}

fn fill(img: &mut RgbImage, x0: i64, y0: i64, x1: i64, y1: i64, c: Rgb<u8>) {
    for y in y0.min(y1)..=y0.max(y1) {
        for x in x0.min(x1)..=x0.max(x1) {
            put(img, x, y, c);
        }
    }
}

/// Draws `text` with its top-left corner at `(x, y)`.
fn text(img: &mut RgbImage, x: i64, y: i64, text: &str, c: Rgb<u8>) {
    for (i, ch) in text.chars().enumerate() {
        let gx = x + i as i64 * 4 * SCALE;
        for (row, bits) in glyph(ch).iter().enumerate() {
            for col in 0..3 {
                if bits & (4 >> col) != 0 {
                    let px = gx + col * SCALE;
                    let py = y + row as i64 * SCALE;
                    fill(img, px, py, px + SCALE - 1, py + SCALE - 1, c);
                }
            }
        }
    }
}

/// The data bounds of the finite points, padded by 5 % (and widened when flat).
fn bounds(points: &[(f64, f64)]) -> Option<[f64; 4]> {
    let finite: Vec<&(f64, f64)> = points
        .iter()
        .filter(|(x, y)| x.is_finite() && y.is_finite())
        .collect();
    let first = finite.first()?;
    let mut b = [first.0, first.0, first.1, first.1];
    for (x, y) in &finite {
        b = [b[0].min(*x), b[1].max(*x), b[2].min(*y), b[3].max(*y)];
    }
    for (lo, hi) in [(0, 1), (2, 3)] {
        let pad = ((b[hi] - b[lo]) * 0.05).max(1e-6);
        b[lo] -= pad;
        b[hi] += pad;
    }
    Some(b)
}

/// Renders the plot.
pub fn render(plot: &Scatter<'_>) -> RgbImage {
    let mut img = RgbImage::from_pixel(WIDTH, HEIGHT, WHITE);
    let (w, h) = (WIDTH as i64, HEIGHT as i64);
    let (x_min, x_max, y_min, y_max) = (LEFT, w - RIGHT, TOP, h - BOTTOM);
    text(
        &mut img,
        (w - text_width(plot.title)) / 2,
        14,
        plot.title,
        BLACK,
    );
    let [x0, x1, y0, y1] = bounds(plot.points).unwrap_or([0.0, 1.0, 0.0, 1.0]);
    let sx = |x: f64| x_min + ((x - x0) / (x1 - x0) * (x_max - x_min) as f64).round() as i64;
    let sy = |y: f64| y_max - ((y - y0) / (y1 - y0) * (y_max - y_min) as f64).round() as i64;
    for t in nice_ticks(x0, x1) {
        let x = sx(t);
        fill(&mut img, x, y_min, x, y_max, GRID);
        fill(&mut img, x, y_max, x, y_max + 5, BLACK);
        let label = tick_text(t);
        text(
            &mut img,
            x - text_width(&label) / 2,
            y_max + 9,
            &label,
            BLACK,
        );
    }
    for t in nice_ticks(y0, y1) {
        let y = sy(t);
        fill(&mut img, x_min, y, x_max, y, GRID);
        fill(&mut img, x_min - 5, y, x_min, y, BLACK);
        let label = tick_text(t);
        text(
            &mut img,
            x_min - 9 - text_width(&label),
            y - 5 * SCALE / 2,
            &label,
            BLACK,
        );
    }
    // The frame.
    fill(&mut img, x_min, y_min, x_max, y_min, BLACK);
    fill(&mut img, x_min, y_max, x_max, y_max, BLACK);
    fill(&mut img, x_min, y_min, x_min, y_max, BLACK);
    fill(&mut img, x_max, y_min, x_max, y_max, BLACK);
    text(
        &mut img,
        (x_min + x_max - text_width(plot.x_label)) / 2,
        y_max + 32,
        plot.x_label,
        BLACK,
    );
    text(&mut img, 8, y_min - 16, plot.y_label, BLACK);
    for &(x, y) in plot.points {
        if !(x.is_finite() && y.is_finite()) {
            continue;
        }
        let (cx, cy) = (sx(x), sy(y));
        for dy in -2i64..=2 {
            for dx in -2i64..=2 {
                if dx * dx + dy * dy <= 5 {
                    put(&mut img, cx + dx, cy + dy, POINT);
                }
            }
        }
    }
    img
}

/// Renders the plot and writes it as a PNG at `path` (its folder created).
pub fn write_png(plot: &Scatter<'_>, path: &Path) -> anyhow::Result<()> {
    if let Some(dir) = path.parent().filter(|d| !d.as_os_str().is_empty()) {
        std::fs::create_dir_all(dir).with_context(|| format!("creating {}", dir.display()))?;
    }
    render(plot)
        .save_with_format(path, image::ImageFormat::Png)
        .with_context(|| format!("writing {}", path.display()))
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Tick labels lose their trailing zeros (the tick values are the report's, tested there).
    #[test]
    fn tick_labels_are_short() {
        assert_eq!(tick_text(2.5), "2.5");
        assert_eq!(tick_text(20.0), "20");
    }

    /// The points land inside the frame in their colour, the corners of the data at the
    /// padded ends; non-finite points are skipped.
    #[test]
    fn points_are_drawn_inside_the_frame() {
        let points = [(0.0, 10.0), (1.0, 20.0), (f64::NAN, 3.0)];
        let img = render(&Scatter {
            title: "EIG VS PSNR",
            x_label: "LOG10 EIG",
            y_label: "PSNR (DB)",
            points: &points,
        });
        assert_eq!(img.dimensions(), (WIDTH, HEIGHT));
        let blue: Vec<(u32, u32)> = img
            .enumerate_pixels()
            .filter(|(_, _, p)| **p == POINT)
            .map(|(x, y, _)| (x, y))
            .collect();
        assert_eq!(blue.len(), 2 * 21, "two discs of 21 pixels");
        for (x, y) in blue {
            assert!((LEFT as u32..WIDTH - RIGHT as u32).contains(&x));
            assert!((TOP as u32..HEIGHT - BOTTOM as u32).contains(&y));
        }
        // The frame's corner and some text are black.
        assert_eq!(*img.get_pixel(LEFT as u32, TOP as u32), BLACK);
        assert!(img.pixels().filter(|p| **p == BLACK).count() > 500);
    }
}
