//! `report.html` of a run folder: one self-contained page (inline CSS, PNGs as base64 data URIs,
//! plots as inline SVG, no script) that opens offline and reads at a glance:
//!
//! - the summary and the metrics table (`summary.json`, `metrics.json` of `activemap eval`);
//! - the bird's-eye map (`bev.png`: grid, true path blue, estimated green, frontiers red) and a
//!   top-down plot of both trajectories after the ATE alignment;
//! - 2D coverage (`coverage.csv`) and ATE RMSE of the trajectory so far against steps;
//! - test renders of the map next to the ground truth (`eval/view_NN_*.png`, `eval/views.csv`);
//! - the per-stage time breakdown (`timings.csv`), else "not recorded";
//! - the LLM exchanges (`llm.jsonl`), else "none".
//!
//! Figures carry stable ids (`fig-bev`, `fig-trajectories`, `fig-coverage`, `fig-ate`,
//! `fig-renders`, `fig-timings`, `llm-exchanges`) so tests and people can find them.

mod base64;
mod svg;

use crate::run_folder::{
    RunError, files, read_coverage, read_summary, read_trajectory, write_file,
};
use crate::{AteOptions, MetricsReport, ate};
use activemap_geometry::tum::Trajectory;
use std::fmt::Write as _;
use std::path::{Path, PathBuf};
use svg::Series;

pub use base64::encode as base64_encode;

/// Escapes text for HTML element content and attribute values.
pub fn escape(text: &str) -> String {
    let mut out = String::with_capacity(text.len());
    for c in text.chars() {
        match c {
            '&' => out.push_str("&amp;"),
            '<' => out.push_str("&lt;"),
            '>' => out.push_str("&gt;"),
            '"' => out.push_str("&quot;"),
            '\'' => out.push_str("&#39;"),
            c => out.push(c),
        }
    }
    out
}

const STYLE: &str = "body{font-family:system-ui,sans-serif;margin:24px;color:#222;max-width:1200px}\
h1{font-size:1.5em;margin-bottom:4px}h2{font-size:1.15em;border-bottom:1px solid #ccc;padding-bottom:3px;margin-top:28px}\
table{border-collapse:collapse;margin:8px 0}td,th{border:1px solid #ccc;padding:3px 8px;text-align:right}\
th{background:#f2f2f2}td.k{text-align:left;font-family:monospace}.missing{color:#a33;font-style:italic}\
.row{display:flex;flex-wrap:wrap;gap:16px;align-items:flex-start}figure{margin:0}figcaption{font-size:.85em;color:#555}\
img.px{image-rendering:pixelated}svg.plot text{font-size:11px;fill:#333}svg.plot .title{font-size:13px;font-weight:600}\
svg.plot .grid{stroke:#e4e4e4}svg.plot .frame{fill:none;stroke:#888}details{margin:6px 0}\
pre{white-space:pre-wrap;background:#f7f7f7;padding:8px;font-size:.85em}";

/// Writes `report.html` into the run folder `dir`; returns its path. Needs `summary.json` and
/// the two trajectories; every other input is optional and shown as missing when absent.
pub fn write_report(dir: &Path) -> Result<PathBuf, RunError> {
    let html = render_report(dir)?;
    let path = dir.join(files::REPORT);
    write_file(&path, html)?;
    Ok(path)
}

/// The report page of the run folder `dir` as text.
pub fn render_report(dir: &Path) -> Result<String, RunError> {
    let summary = read_summary(dir)?;
    let truth = read_trajectory(dir, files::TRAJECTORY_TRUE)?;
    let estimate = read_trajectory(dir, files::TRAJECTORY_EST)?;
    let coverage = read_coverage(dir)?;
    let metrics = read_metrics(dir)?;
    let name = dir
        .canonicalize()
        .ok()
        .and_then(|p| p.file_name().map(|n| n.to_string_lossy().into_owned()))
        .unwrap_or_else(|| dir.display().to_string());

    let mut page = format!(
        "<!DOCTYPE html><html lang=\"en\"><head><meta charset=\"utf-8\"><title>activemap run {n}</title><style>{STYLE}</style></head><body>\
         <h1>activemap run <code>{n}</code></h1>",
        n = escape(&name)
    );
    page += &summary_section(&summary, metrics.as_ref());
    page += &map_section(dir, &truth, &estimate)?;
    page += &progress_section(coverage.as_deref(), &truth, &estimate);
    page += &renders_section(dir)?;
    page += &timings_section(dir)?;
    page += &llm_section(dir)?;
    page += "</body></html>\n";
    Ok(page)
}

/// `metrics.json` when `activemap eval` wrote it.
fn read_metrics(dir: &Path) -> Result<Option<MetricsReport>, RunError> {
    let path = dir.join(files::METRICS_JSON);
    if !path.exists() {
        return Ok(None);
    }
    let text = crate::run_folder::read_text(&path, "metrics of `activemap eval`")?;
    MetricsReport::from_json(&text)
        .map(Some)
        .map_err(|e| RunError::Malformed {
            path,
            detail: e.to_string(),
        })
}

fn summary_section(summary: &serde_json::Value, metrics: Option<&MetricsReport>) -> String {
    let mut s = String::from("<h2>Summary</h2><table id=\"summary\">");
    if let Some(obj) = summary.as_object() {
        for (k, v) in obj {
            let v = match v {
                serde_json::Value::String(t) => t.clone(),
                serde_json::Value::Number(n) => match n.as_f64() {
                    Some(f) if n.is_f64() => format!("{f:.4}"),
                    _ => n.to_string(),
                },
                other => other.to_string(),
            };
            let _ = write!(
                s,
                "<tr><td class=\"k\">{}</td><td>{}</td></tr>",
                escape(k),
                escape(&v)
            );
        }
    }
    s += "</table><h2>Metrics (SPEC §8)</h2>";
    match metrics {
        None => {
            s += "<p class=\"missing\" id=\"metrics\">Not computed yet: run <code>activemap eval RUN_DIR</code>.</p>"
        }
        Some(m) => {
            let cell = |v: Option<f64>, digits: usize, scale: f64| match v {
                None => "—".to_string(),
                Some(x) if x == f64::INFINITY => "∞".into(),
                Some(x) => format!("{:.*}", digits, x * scale),
            };
            let _ = write!(
                s,
                "<table id=\"metrics\"><tr><th>PSNR ↑</th><th>SSIM ↑</th><th>LPIPS ↓</th><th>Depth MAE ↓ (m)</th><th>ATE ↓ (m)</th><th>Completeness ↑ (%)</th><th>2D coverage (%)</th><th>test views</th></tr>\
                 <tr><td>{}</td><td>{}</td><td>{}</td><td>{}</td><td>{}</td><td>{}</td><td>{}</td><td>{}</td></tr></table>",
                cell(m.psnr_db, 2, 1.0),
                cell(m.ssim, 4, 1.0),
                cell(m.lpips, 4, 1.0),
                cell(m.depth_mae_m, 4, 1.0),
                cell(m.ate_rmse_m, 4, 1.0),
                cell(m.completeness, 2, 100.0),
                cell(m.coverage_2d, 2, 100.0),
                m.test_views
            );
            for (k, why) in &m.missing {
                let _ = write!(s, "<p class=\"missing\">{}: {}</p>", escape(k), escape(why));
            }
        }
    }
    s
}

/// `<img>` of a PNG file as a data URI, or `None` when the file is absent.
fn png_img(path: &Path, attrs: &str) -> Result<Option<String>, RunError> {
    match std::fs::read(path) {
        Ok(bytes) => Ok(Some(format!(
            "<img {attrs} src=\"data:image/png;base64,{}\">",
            base64::encode(&bytes)
        ))),
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => Ok(None),
        Err(source) => Err(RunError::Io {
            path: path.to_path_buf(),
            source,
        }),
    }
}

fn map_section(dir: &Path, truth: &Trajectory, estimate: &Trajectory) -> Result<String, RunError> {
    let mut s = String::from("<h2>Bird's-eye map</h2><div class=\"row\">");
    match png_img(
        &dir.join(files::BEV),
        "id=\"fig-bev\" class=\"px\" alt=\"bird's-eye map\" style=\"max-width:560px;width:100%\"",
    )? {
        Some(img) => {
            let _ = write!(
                s,
                "<figure>{img}<figcaption>Last occupancy grid (free white, occupied black, unknown grey), \
                 true path blue, estimated path green, frontier centroids red.</figcaption></figure>"
            );
        }
        None => s += "<p class=\"missing\" id=\"fig-bev\">bev.png not in the run folder.</p>",
    }
    let xy = |t: &Trajectory| -> Vec<(f64, f64)> {
        t.poses
            .iter()
            .map(|p| (p.translation.x, p.translation.y))
            .collect()
    };
    let (aligned, caption) = match ate(truth, estimate, AteOptions::default()) {
        Ok(r) => {
            let mut t = estimate.clone();
            t.poses.iter_mut().for_each(|p| *p = r.alignment * *p);
            (
                xy(&t),
                format!("ATE RMSE {:.4} m over {} poses", r.rmse, r.pairs),
            )
        }
        Err(e) => (Vec::new(), format!("no alignment: {e}")),
    };
    let plot = svg::top_down(
        "fig-trajectories",
        "Trajectories (world frame, estimate aligned)",
        &[
            Series {
                name: "true",
                colour: "#2850ff",
                points: xy(truth),
            },
            Series {
                name: "estimated (aligned)",
                colour: "#00a000",
                points: aligned,
            },
        ],
    );
    let _ = write!(
        s,
        "<figure>{plot}<figcaption>{}</figcaption></figure></div>",
        escape(&caption)
    );
    Ok(s)
}

/// ATE RMSE of the trajectory up to each of ~60 evenly spaced steps (each prefix aligned on
/// its own), as (step, metres).
pub fn ate_against_steps(truth: &Trajectory, estimate: &Trajectory) -> Vec<(f64, f64)> {
    let n = estimate.len();
    if n < 3 {
        return Vec::new();
    }
    let points = 60.min(n - 2);
    (0..points)
        .filter_map(|i| {
            let len = 3 + (n - 3) * (i + 1) / points;
            let prefix = Trajectory {
                stamps: estimate.stamps[..len].to_vec(),
                poses: estimate.poses[..len].to_vec(),
            };
            ate(truth, &prefix, AteOptions::default())
                .ok()
                .map(|r| (len as f64, r.rmse))
        })
        .collect()
}

fn progress_section(
    coverage: Option<&[(u64, f64)]>,
    truth: &Trajectory,
    estimate: &Trajectory,
) -> String {
    let mut s = String::from("<h2>Progress against steps</h2><div class=\"row\">");
    match coverage {
        Some(rows) => {
            s += &svg::line_plot(
                "fig-coverage",
                "2D coverage",
                "step",
                "coverage (%)",
                &[Series {
                    name: "seen / navigable floor",
                    colour: "#d07a00",
                    points: rows.iter().map(|&(k, c)| (k as f64, c * 100.0)).collect(),
                }],
            )
        }
        None => {
            s += "<p class=\"missing\" id=\"fig-coverage\">coverage.csv not in the run folder.</p>"
        }
    }
    s += &svg::line_plot(
        "fig-ate",
        "ATE RMSE of the trajectory so far",
        "step (poses)",
        "ATE RMSE (m)",
        &[Series {
            name: "ATE (Umeyama SE(3))",
            colour: "#b03060",
            points: ate_against_steps(truth, estimate),
        }],
    );
    s + "</div>"
}

fn renders_section(dir: &Path) -> Result<String, RunError> {
    let eval_dir = dir.join(files::EVAL_DIR);
    let per_view = read_views_csv(&eval_dir.join("views.csv"))?;
    let mut s = String::from(
        "<h2>Test renders: map (left) and ground truth (right)</h2><div class=\"row\" id=\"fig-renders\">",
    );
    let mut shown = 0;
    for i in 0..100 {
        let map = png_img(
            &eval_dir.join(format!("view_{i:02}_map.png")),
            &format!("class=\"px render\" alt=\"map render {i}\" width=\"200\""),
        )?;
        let truth = png_img(
            &eval_dir.join(format!("view_{i:02}_truth.png")),
            &format!("class=\"px render\" alt=\"ground truth {i}\" width=\"200\""),
        )?;
        let (Some(map), Some(truth)) = (map, truth) else {
            break;
        };
        let caption = per_view
            .get(i)
            .map(|v| format!("view {i}: {v}"))
            .unwrap_or_else(|| format!("view {i}"));
        let _ = write!(
            s,
            "<figure>{map}{truth}<figcaption>{}</figcaption></figure>",
            escape(&caption)
        );
        shown += 1;
    }
    if shown == 0 {
        s += "<p class=\"missing\">No test renders: run <code>activemap eval RUN_DIR</code>.</p>";
    }
    Ok(s + "</div>")
}

/// Captions from `eval/views.csv` (`view,psnr_db,ssim,lpips,depth_mae_m`); empty when absent.
fn read_views_csv(path: &Path) -> Result<Vec<String>, RunError> {
    if !path.exists() {
        return Ok(Vec::new());
    }
    let text = crate::run_folder::read_text(path, "per-view metrics")?;
    Ok(text
        .lines()
        .skip(1)
        .map(|line| {
            let f: Vec<&str> = line.split(',').collect();
            let num = |i: usize| f.get(i).and_then(|v| v.parse::<f64>().ok());
            let mut c = String::new();
            if let Some(p) = num(1) {
                let _ = write!(c, "PSNR {p:.2} dB");
            }
            if let Some(v) = num(2) {
                let _ = write!(c, ", SSIM {v:.3}");
            }
            if let Some(v) = num(3) {
                let _ = write!(c, ", LPIPS {v:.3}");
            }
            if let Some(v) = num(4) {
                let _ = write!(c, ", depth MAE {v:.3} m");
            }
            c
        })
        .collect())
}

fn timings_section(dir: &Path) -> Result<String, RunError> {
    let path = dir.join(files::TIMINGS);
    let mut s = String::from("<h2>Time per stage</h2>");
    if !path.exists() {
        s += "<p class=\"missing\" id=\"fig-timings\">Not recorded: the run folder holds no timings.csv.</p>";
        return Ok(s);
    }
    let text = crate::run_folder::read_text(&path, "per-stage times")?;
    let mut rows: Vec<(String, f64, u64)> = Vec::new();
    for (n, line) in text.lines().enumerate().skip(1) {
        if line.trim().is_empty() {
            continue;
        }
        let f: Vec<&str> = line.split(',').map(str::trim).collect();
        let parsed = match f.as_slice() {
            [stage, secs, calls] => secs
                .parse::<f64>()
                .ok()
                .filter(|v| v.is_finite() && *v >= 0.0)
                .zip(calls.parse::<u64>().ok())
                .map(|(t, c)| (stage.to_string(), t, c)),
            _ => None,
        };
        let (stage, secs, calls) = parsed.ok_or_else(|| RunError::Malformed {
            path: path.clone(),
            detail: format!(
                "line {}: expected `stage,seconds,calls`, found `{line}`",
                n + 1
            ),
        })?;
        // A node restarted by its restart policy appends a second row: one stage, summed.
        match rows.iter_mut().find(|r| r.0 == stage) {
            Some(row) => {
                row.1 += secs;
                row.2 += calls;
            }
            None => rows.push((stage, secs, calls)),
        }
    }
    let total: f64 = rows.iter().map(|r| r.1).sum();
    s += &svg::bars(
        "fig-timings",
        "Wall time per stage",
        &rows.iter().map(|r| (r.0.clone(), r.1)).collect::<Vec<_>>(),
        "s",
    );
    s += "<table><tr><th>stage</th><th>seconds</th><th>share</th><th>calls</th><th>ms / call</th></tr>";
    for (stage, secs, calls) in &rows {
        let _ = write!(
            s,
            "<tr><td class=\"k\">{}</td><td>{secs:.3}</td><td>{:.1} %</td><td>{calls}</td><td>{}</td></tr>",
            escape(stage),
            if total > 0.0 {
                secs / total * 100.0
            } else {
                0.0
            },
            if *calls > 0 {
                format!("{:.2}", secs * 1000.0 / *calls as f64)
            } else {
                "—".into()
            }
        );
    }
    Ok(s + "</table>")
}

fn llm_section(dir: &Path) -> Result<String, RunError> {
    let path = dir.join(files::LLM);
    let mut s = String::from("<h2>LLM exchanges</h2><div id=\"llm-exchanges\">");
    if !path.exists() {
        s += "<p class=\"missing\">None: this run made no LLM exchange (no llm.jsonl).</p>";
        return Ok(s + "</div>");
    }
    let text = crate::run_folder::read_text(&path, "LLM exchanges")?;
    let mut count = 0;
    for (n, line) in text.lines().enumerate() {
        if line.trim().is_empty() {
            continue;
        }
        let v: serde_json::Value = serde_json::from_str(line).map_err(|e| RunError::Malformed {
            path: path.clone(),
            detail: format!("line {}: {e}", n + 1),
        })?;
        let field = |k: &str| match v.get(k) {
            Some(serde_json::Value::String(t)) => t.clone(),
            Some(serde_json::Value::Null) | None => "—".into(),
            Some(other) => other.to_string(),
        };
        let _ = write!(
            s,
            "<details class=\"llm\"><summary>step {} — target {}</summary><b>prompt</b><pre>{}</pre><b>reply</b><pre>{}</pre></details>",
            escape(&field("step")),
            escape(&field("target")),
            escape(&field("prompt")),
            escape(&field("reply"))
        );
        count += 1;
    }
    if count == 0 {
        s += "<p class=\"missing\">None: llm.jsonl is empty.</p>";
    }
    Ok(s + "</div>")
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::run_eval::{EvalOptions, LpipsSource, evaluate_run};
    use crate::testing::{MapKind, write_run};
    use activemap_geometry::Isometry3;
    use std::process::Command;

    fn evaluated_run(dir: &Path) {
        write_run(dir, MapKind::SurfaceInMapFrame);
        let options = EvalOptions {
            test_views: 4,
            width: 48,
            height: 48,
            lpips: LpipsSource::Off,
            completeness_samples: 5_000,
            saved_views: 3,
            ..EvalOptions::default()
        };
        evaluate_run(dir, &options).unwrap();
        // A BEV stand-in and the optional inputs, as the pipeline writes them.
        image::RgbImage::from_pixel(8, 6, image::Rgb([200, 200, 200]))
            .save(dir.join(files::BEV))
            .unwrap();
        std::fs::write(
            dir.join(files::TIMINGS),
            "stage,seconds,calls\ntracker,2.0,8\nmapper,1.0,4\ntracker,1.0,4\n",
        )
        .unwrap();
        std::fs::write(
            dir.join(files::LLM),
            "{\"step\": 5, \"prompt\": \"pick <a frontier>\", \"reply\": \"{\\\"target\\\": 1}\", \"target\": 1}\n",
        )
        .unwrap();
    }

    #[test]
    fn report_holds_every_figure_and_no_external_resource() {
        let dir = tempfile::tempdir().unwrap();
        evaluated_run(dir.path());
        let path = write_report(dir.path()).unwrap();
        let html = std::fs::read_to_string(&path).unwrap();
        for id in [
            "fig-bev",
            "fig-trajectories",
            "fig-coverage",
            "fig-ate",
            "fig-renders",
            "fig-timings",
            "llm-exchanges",
            "metrics",
        ] {
            assert!(html.contains(&format!("id=\"{id}\"")), "{id} missing");
        }
        // 1 BEV + 3 pairs of renders, all inline.
        assert_eq!(html.matches("src=\"data:image/png;base64,").count(), 7);
        assert!(
            !html.contains("http://")
                || html.matches("http://").count()
                    == html.matches("xmlns=\"http://www.w3.org/2000/svg\"").count()
        );
        assert!(!html.contains("<script"));
        // Values: coverage 42 %, the tracker holds 75 % of the time, escaped LLM prompt.
        assert!(html.contains("<td>42.00</td>"), "coverage cell");
        assert!(html.contains("75.0 %"));
        // The restarted tracker's two rows are one stage: 3 s over 12 calls.
        assert!(html.contains("<td>3.000</td><td>75.0 %</td><td>12</td><td>250.00</td>"));
        assert!(html.contains("pick &lt;a frontier&gt;"));
        assert!(html.contains("ATE RMSE 0.0000 m over 12 poses"));
    }

    #[test]
    fn absent_optional_inputs_show_as_missing_and_bad_ones_are_named() {
        let dir = tempfile::tempdir().unwrap();
        write_run(dir.path(), MapKind::Empty);
        let html = render_report(dir.path()).unwrap();
        assert!(html.contains("Not recorded: the run folder holds no timings.csv"));
        assert!(html.contains("None: this run made no LLM exchange"));
        assert!(html.contains("bev.png not in the run folder"));
        assert!(html.contains("Not computed yet"));
        std::fs::write(
            dir.path().join(files::TIMINGS),
            "stage,seconds,calls\nx,abc,1\n",
        )
        .unwrap();
        let e = render_report(dir.path()).unwrap_err().to_string();
        assert!(e.contains("timings.csv") && e.contains("line 2"), "{e}");
        std::fs::remove_file(dir.path().join(files::TIMINGS)).unwrap();
        std::fs::write(dir.path().join(files::LLM), "{not json\n").unwrap();
        let e = render_report(dir.path()).unwrap_err().to_string();
        assert!(e.contains("llm.jsonl") && e.contains("line 1"), "{e}");
        std::fs::remove_file(dir.path().join(files::TRAJECTORY_EST)).unwrap();
        let e = render_report(dir.path()).unwrap_err().to_string();
        assert!(e.contains("trajectory_est.tum: missing"), "{e}");
    }

    #[test]
    fn ate_against_steps_follows_a_drifting_estimate() {
        // Truth: an arc; estimate: the arc plus a vertical drift growing as k², so early
        // prefixes align almost exactly and the full one does not.
        let mut truth = Trajectory::default();
        let mut est = Trajectory::default();
        for k in 0..40 {
            let (t, a) = (k as f64, 0.05 * k as f64);
            truth.push(t, Isometry3::translation(2.0 * a.cos(), 2.0 * a.sin(), 0.0));
            est.push(
                t,
                Isometry3::translation(2.0 * a.cos(), 2.0 * a.sin(), 1e-3 * t * t),
            );
        }
        let curve = ate_against_steps(&truth, &est);
        assert_eq!(curve.len(), 38);
        assert_eq!(curve[0].0, 3.0);
        assert_eq!(curve.last().unwrap().0, 40.0);
        let full = ate(&truth, &est, AteOptions::default()).unwrap().rmse;
        assert!((curve.last().unwrap().1 - full).abs() < 1e-12);
        assert!(full > 0.01 && curve[0].1 < full / 10.0, "{curve:?}");
        assert!(ate_against_steps(&truth, &Trajectory::default()).is_empty());
    }

    /// Finds Debian's chromium; installs it under CI as root; `None` = skip.
    fn chromium() -> Option<PathBuf> {
        let path = PathBuf::from("/usr/bin/chromium");
        if path.exists() {
            return Some(path);
        }
        let ci = std::env::var("CI").is_ok_and(|v| v == "true");
        let root = Command::new("id")
            .arg("-u")
            .output()
            .is_ok_and(|o| String::from_utf8_lossy(&o.stdout).trim() == "0");
        if !(ci && root) {
            eprintln!(
                "SKIP browser test: /usr/bin/chromium absent (installed automatically only with CI=true as root; run `apt-get install -y chromium`)"
            );
            return None;
        }
        let ok = Command::new("sh")
            .args(["-c", "apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq chromium"])
            .status()
            .is_ok_and(|s| s.success());
        assert!(ok && path.exists(), "CI: installing chromium failed");
        Some(path)
    }

    fn headless(
        browser: &Path,
        profile: &Path,
        extra: &[&str],
        page: &Path,
    ) -> std::process::Output {
        Command::new(browser)
            .args([
                "--headless",
                "--no-sandbox",
                "--disable-gpu",
                "--disable-quic",
                "--no-first-run",
                "--disable-background-networking",
                "--disable-component-update",
                "--disable-sync",
                "--enable-logging=stderr",
                "--v=0",
            ])
            .arg(format!("--user-data-dir={}", profile.display()))
            .args(extra)
            .arg(format!("file://{}", page.display()))
            .output()
            .expect("chromium runs")
    }

    #[test]
    fn headless_chromium_renders_the_report_without_console_errors() {
        let Some(browser) = chromium() else { return };
        let dir = tempfile::tempdir().unwrap();
        evaluated_run(dir.path());
        let page = write_report(dir.path()).unwrap();
        let profile = tempfile::tempdir().unwrap();
        let out = headless(&browser, profile.path(), &["--dump-dom"], &page);
        let dom = String::from_utf8_lossy(&out.stdout);
        let log = String::from_utf8_lossy(&out.stderr);
        assert!(out.status.success(), "chromium failed: {log}");
        for id in [
            "fig-bev",
            "fig-trajectories",
            "fig-coverage",
            "fig-ate",
            "fig-renders",
            "fig-timings",
        ] {
            assert!(dom.contains(&format!("id=\"{id}\"")), "{id} not in the DOM");
        }
        assert_eq!(dom.matches("<svg").count(), 4, "4 inline SVG figures");
        assert_eq!(dom.matches("<img").count(), 7, "BEV and 3 render pairs");
        let console: Vec<&str> = log
            .lines()
            .filter(|l| {
                l.contains("CONSOLE") || l.contains("Failed to load") || l.contains("Uncaught")
            })
            .collect();
        assert!(console.is_empty(), "console messages: {console:?}");
        let shot = dir.path().join("report.png");
        let profile = tempfile::tempdir().unwrap();
        let out = headless(
            &browser,
            profile.path(),
            &[
                &format!("--screenshot={}", shot.display()),
                "--window-size=1280,2400",
                "--hide-scrollbars",
            ],
            &page,
        );
        assert!(
            out.status.success(),
            "{}",
            String::from_utf8_lossy(&out.stderr)
        );
        let img = image::open(&shot).unwrap().to_rgb8();
        assert_eq!(img.dimensions(), (1280, 2400));
        // Not a blank page: some pixels are far from white.
        assert!(
            img.pixels()
                .filter(|p| p.0.iter().all(|&c| c < 128))
                .count()
                > 1000
        );
        if let Ok(keep) = std::env::var("ACTIVEMAP_REPORT_SCREENSHOT") {
            std::fs::copy(&shot, &keep).unwrap();
            std::fs::copy(&page, Path::new(&keep).with_extension("html")).unwrap();
        }
    }
}
