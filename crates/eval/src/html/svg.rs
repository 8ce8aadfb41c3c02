//! Inline SVG figures (no script, no external resource): line plots, a top-down trajectory
//! plot and horizontal bars.

use super::escape;

/// One polyline of a plot.
pub struct Series<'a> {
    /// Legend text.
    pub name: &'a str,
    /// CSS colour.
    pub colour: &'a str,
    /// Points (x, y); non-finite ones are skipped.
    pub points: Vec<(f64, f64)>,
}

const W: f64 = 560.0;
const H: f64 = 300.0;
const LEFT: f64 = 64.0;
const RIGHT: f64 = 16.0;
const TOP: f64 = 30.0;
const BOTTOM: f64 = 44.0;

/// Up to about six round tick values (1, 2 or 5 × 10^k apart) covering `[lo, hi]`; none for
/// a non-finite or reversed range. Shared by the report's SVG plots and the benchmarks' PNG
/// plots.
pub fn ticks(lo: f64, hi: f64) -> Vec<f64> {
    if !(lo.is_finite() && hi.is_finite()) || hi < lo {
        return Vec::new();
    }
    let span = (hi - lo).max(1e-12);
    let raw = span / 5.0;
    let mag = 10f64.powf(raw.log10().floor());
    let step = [1.0, 2.0, 5.0, 10.0]
        .iter()
        .map(|m| m * mag)
        .find(|s| span / s <= 6.0)
        .unwrap_or(10.0 * mag);
    let mut t = (lo / step).ceil() * step;
    let mut out = Vec::new();
    while t <= hi + step * 1e-9 && out.len() < 12 {
        out.push(if t.abs() < step * 1e-9 { 0.0 } else { t });
        t += step;
    }
    out
}

fn fmt_tick(v: f64) -> String {
    let s = format!("{v:.4}");
    let s = s.trim_end_matches('0').trim_end_matches('.');
    if s == "-0" { "0".into() } else { s.into() }
}

/// Data bounds of all finite points, padded when flat; `None` without points.
fn bounds(series: &[Series<'_>]) -> Option<[f64; 4]> {
    let mut b = [
        f64::INFINITY,
        f64::NEG_INFINITY,
        f64::INFINITY,
        f64::NEG_INFINITY,
    ];
    for (x, y) in series.iter().flat_map(|s| s.points.iter()) {
        if x.is_finite() && y.is_finite() {
            b = [b[0].min(*x), b[1].max(*x), b[2].min(*y), b[3].max(*y)];
        }
    }
    if !b[0].is_finite() {
        return None;
    }
    for (lo, hi) in [(0, 1), (2, 3)] {
        if b[hi] - b[lo] < 1e-9 {
            b[lo] -= 0.5;
            b[hi] += 0.5;
        }
    }
    Some(b)
}

/// A line plot with axes, ticks, labels and a legend (unnamed series get none); `id` becomes
/// the `<svg>` id.
pub fn line_plot(
    id: &str,
    title: &str,
    x_label: &str,
    y_label: &str,
    series: &[Series<'_>],
) -> String {
    let Some([x0, x1, y0, y1]) = bounds(series) else {
        return format!(
            "<p class=\"missing\" id=\"{id}\">{}: no data.</p>",
            escape(title)
        );
    };
    let sx = |x: f64| LEFT + (x - x0) / (x1 - x0) * (W - LEFT - RIGHT);
    let sy = |y: f64| H - BOTTOM - (y - y0) / (y1 - y0) * (H - TOP - BOTTOM);
    let mut s = format!(
        "<svg id=\"{id}\" class=\"plot\" xmlns=\"http://www.w3.org/2000/svg\" viewBox=\"0 0 {W} {H}\" width=\"{W}\" height=\"{H}\" role=\"img\" aria-label=\"{t}\">\
         <text x=\"{cx}\" y=\"18\" text-anchor=\"middle\" class=\"title\">{t}</text>",
        t = escape(title),
        cx = W / 2.0
    );
    for t in ticks(x0, x1) {
        let x = sx(t);
        s += &format!(
            "<line x1=\"{x:.1}\" y1=\"{:.1}\" x2=\"{x:.1}\" y2=\"{TOP}\" class=\"grid\"/><text x=\"{x:.1}\" y=\"{:.1}\" text-anchor=\"middle\">{}</text>",
            H - BOTTOM,
            H - BOTTOM + 16.0,
            fmt_tick(t)
        );
    }
    for t in ticks(y0, y1) {
        let y = sy(t);
        s += &format!(
            "<line x1=\"{LEFT}\" y1=\"{y:.1}\" x2=\"{:.1}\" y2=\"{y:.1}\" class=\"grid\"/><text x=\"{:.1}\" y=\"{:.1}\" text-anchor=\"end\">{}</text>",
            W - RIGHT,
            LEFT - 6.0,
            y + 4.0,
            fmt_tick(t)
        );
    }
    s += &format!(
        "<rect x=\"{LEFT}\" y=\"{TOP}\" width=\"{:.1}\" height=\"{:.1}\" class=\"frame\"/>\
         <text x=\"{:.1}\" y=\"{:.1}\" text-anchor=\"middle\">{}</text>\
         <text transform=\"translate(14 {:.1}) rotate(-90)\" text-anchor=\"middle\">{}</text>",
        W - LEFT - RIGHT,
        H - TOP - BOTTOM,
        (LEFT + W - RIGHT) / 2.0,
        H - 6.0,
        escape(x_label),
        (TOP + H - BOTTOM) / 2.0,
        escape(y_label)
    );
    for (k, ser) in series.iter().enumerate() {
        let pts: Vec<String> = ser
            .points
            .iter()
            .filter(|(x, y)| x.is_finite() && y.is_finite())
            .map(|&(x, y)| format!("{:.1},{:.1}", sx(x), sy(y)))
            .collect();
        s += &format!(
            "<polyline points=\"{}\" fill=\"none\" stroke=\"{}\" stroke-width=\"2\"/>",
            pts.join(" "),
            ser.colour
        );
        if ser.name.is_empty() {
            continue;
        }
        let ly = TOP + 14.0 + 16.0 * k as f64;
        s += &format!(
            "<line x1=\"{:.1}\" y1=\"{ly:.1}\" x2=\"{:.1}\" y2=\"{ly:.1}\" stroke=\"{}\" stroke-width=\"3\"/><text x=\"{:.1}\" y=\"{:.1}\">{}</text>",
            LEFT + 10.0,
            LEFT + 30.0,
            ser.colour,
            LEFT + 36.0,
            ly + 4.0,
            escape(ser.name)
        );
    }
    s + "</svg>"
}

/// A top-down (x right, y up) plot of paths with equal axis scales.
pub fn top_down(id: &str, title: &str, series: &[Series<'_>]) -> String {
    let Some([x0, x1, y0, y1]) = bounds(series) else {
        return format!(
            "<p class=\"missing\" id=\"{id}\">{}: no data.</p>",
            escape(title)
        );
    };
    let (cx, cy) = ((x0 + x1) / 2.0, (y0 + y1) / 2.0);
    let half = ((x1 - x0).max(y1 - y0) / 2.0) * 1.05;
    let eq = [cx - half, cx + half, cy - half, cy + half];
    let square: Vec<Series<'_>> = series
        .iter()
        .map(|s| Series {
            name: s.name,
            colour: s.colour,
            points: s.points.clone(),
        })
        .chain(std::iter::once(Series {
            name: "",
            colour: "none",
            points: vec![(eq[0], eq[2]), (eq[1], eq[3])],
        }))
        .collect();
    // The invisible, unnamed diagonal fixes equal axis scales.
    line_plot(id, title, "x (m)", "y (m)", &square)
}

/// Horizontal bars: `(label, value)`; `unit` printed after each value.
pub fn bars(id: &str, title: &str, rows: &[(String, f64)], unit: &str) -> String {
    let max = rows.iter().map(|r| r.1).fold(0.0f64, f64::max);
    if rows.is_empty() || max <= 0.0 || !max.is_finite() {
        return format!(
            "<p class=\"missing\" id=\"{id}\">{}: no data.</p>",
            escape(title)
        );
    }
    let row_h = 22.0;
    let h = TOP + row_h * rows.len() as f64 + 10.0;
    let label_w = 160.0;
    let mut s = format!(
        "<svg id=\"{id}\" class=\"plot\" xmlns=\"http://www.w3.org/2000/svg\" viewBox=\"0 0 {W} {h}\" width=\"{W}\" height=\"{h}\" role=\"img\" aria-label=\"{t}\">\
         <text x=\"{cx}\" y=\"18\" text-anchor=\"middle\" class=\"title\">{t}</text>",
        t = escape(title),
        cx = W / 2.0
    );
    for (i, (label, v)) in rows.iter().enumerate() {
        let y = TOP + row_h * i as f64;
        let len = (v / max).max(0.0) * (W - label_w - 90.0);
        s += &format!(
            "<text x=\"{:.1}\" y=\"{:.1}\" text-anchor=\"end\">{}</text><rect x=\"{label_w}\" y=\"{:.1}\" width=\"{len:.1}\" height=\"{:.1}\" fill=\"#4a7bd0\"/><text x=\"{:.1}\" y=\"{:.1}\">{v:.3} {}</text>",
            label_w - 6.0,
            y + 15.0,
            escape(label),
            y + 3.0,
            row_h - 6.0,
            label_w + len + 4.0,
            y + 15.0,
            escape(unit)
        );
    }
    s + "</svg>"
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn ticks_are_round_and_cover_the_range() {
        let close = |a: Vec<f64>, b: &[f64]| {
            a.len() == b.len() && a.iter().zip(b).all(|(x, y)| (x - y).abs() < 1e-12)
        };
        assert!(close(ticks(0.0, 1.0), &[0.0, 0.2, 0.4, 0.6, 0.8, 1.0]));
        assert!(close(ticks(3.0, 47.0), &[10.0, 20.0, 30.0, 40.0]));
        assert!(close(ticks(-0.013, 0.004), &[-0.01, -0.005, 0.0]));
        assert!(close(
            ticks(-3.2, -0.4),
            &[-3.0, -2.5, -2.0, -1.5, -1.0, -0.5]
        ));
        assert!(ticks(f64::NAN, 1.0).is_empty() && ticks(2.0, 1.0).is_empty());
        assert_eq!(fmt_tick(0.30000000000000004), "0.3");
    }

    #[test]
    fn plot_maps_data_to_the_frame() {
        let svg = line_plot(
            "p",
            "t",
            "x",
            "y",
            &[Series {
                name: "a",
                colour: "red",
                points: vec![(0.0, 0.0), (1.0, 1.0), (f64::NAN, 2.0)],
            }],
        );
        // (0, 0) → bottom-left corner of the frame, (1, 1) → top-right; the NaN point is dropped.
        let bl = format!("{:.1},{:.1}", LEFT, H - BOTTOM);
        let tr = format!("{:.1},{:.1}", W - RIGHT, TOP);
        assert!(svg.contains(&format!("points=\"{bl} {tr}\"")), "{svg}");
        assert!(line_plot("q", "t", "x", "y", &[]).contains("no data"));
    }
}
