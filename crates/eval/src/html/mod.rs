//! `report.html` of a run folder: one self-contained page (inline CSS, PNGs as base64 data URIs,
//! plots as inline SVG, no script) that opens offline and reads at a glance:
//!
//! - for an invalid run (issue 16: warnings in `summary.json` or `metrics.json`,
//!   [`crate::validity`]), an `INVALID RUN` banner (`id="invalid"`) with every reason, and the
//!   metrics table's figures struck through;
//! - the summary and the metrics table (`summary.json`, `metrics.json` of `activemap eval`);
//! - the bird's-eye map (`bev.png`: grid, true path blue, estimated green, frontiers red) and a
//!   top-down plot of both trajectories after the ATE alignment;
//! - 2D coverage (`coverage.csv`) and ATE RMSE of the trajectory so far against steps;
//! - the Fisher replans (`fisher.csv`): log10 of the chosen path's EIG and its `C_local` sum
//!   against steps, with the counts of replans, refine replans and fallbacks and the median
//!   replan time, else "no Fisher replans";
//! - test renders of the map next to the ground truth (`eval/view_NN_*.png`, `eval/views.csv`);
//! - the per-stage time breakdown (`timings.csv`), else "not recorded";
//! - the LLM exchanges (`llm.jsonl`), else "none".
//!
//! Figures carry stable ids (`fig-bev`, `fig-trajectories`, `fig-coverage`, `fig-ate`,
//! `fig-fisher`, `fig-renders`, `fig-timings`, `llm-exchanges`) so tests and people can find
//! them.

mod svg;

use crate::run_folder::{
    CoverageRow, FisherRow, RunError, RunFolder, StageTime, Summary, ViewImage,
};
use crate::validity::RunWarning;
use crate::{AteOptions, MetricsReport, ate};
use activemap_geometry::tum::Trajectory;
use base64::Engine as _;
use std::fmt::Write as _;
use std::path::{Path, PathBuf};
use svg::Series;
pub use svg::ticks;

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
pre{white-space:pre-wrap;background:#f7f7f7;padding:8px;font-size:.85em}\
div.invalid{border:3px solid #c00;background:#fff0f0;padding:4px 14px;margin:12px 0}div.invalid h2{color:#c00;border:none;margin-top:8px}\
td.invalid{color:#a00;background:#fff0f0}";

/// Writes `report.html` into the run folder `dir`; returns its path. Needs `summary.json` and
/// the two trajectories; every other input is optional and shown as missing when absent.
pub fn write_report(dir: &Path) -> Result<PathBuf, RunError> {
    let html = render_report(dir)?;
    RunFolder::new(dir).write_report(&html)
}

/// The report page of the run folder `dir` as text.
pub fn render_report(dir: &Path) -> Result<String, RunError> {
    let run = RunFolder::new(dir);
    let summary = run.read_summary()?;
    let truth = run.read_trajectory(RunFolder::TRAJECTORY_TRUE)?;
    let estimate = run.read_trajectory(RunFolder::TRAJECTORY_EST)?;
    let coverage = run.read_coverage()?;
    let metrics = run.read_metrics()?;
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
    let warnings = report_warnings(&summary, metrics.as_ref());
    page += &invalid_section(&warnings);
    page += &summary_section(&summary, metrics.as_ref(), warnings.is_empty());
    page += &map_section(&run, &truth, &estimate)?;
    page += &progress_section(coverage.as_deref(), &truth, &estimate);
    page += &fisher_section(run.read_fisher()?.as_deref());
    page += &renders_section(&run)?;
    page += &timings_section(&run)?;
    page += &llm_section(&run)?;
    page += "</body></html>\n";
    Ok(page)
}

/// Why the run is invalid: the warnings of `summary.json`, then those `metrics.json` adds (one
/// per code); empty for a valid run.
pub fn report_warnings(summary: &Summary, metrics: Option<&MetricsReport>) -> Vec<RunWarning> {
    let mut warnings = summary.warnings.clone();
    if let Some(m) = metrics {
        crate::validity::merge(&mut warnings, m.warnings.iter().cloned());
    }
    warnings
}

/// The `INVALID RUN` banner listing `warnings` (code and message); empty when there is none.
fn invalid_section(warnings: &[RunWarning]) -> String {
    if warnings.is_empty() {
        return String::new();
    }
    let mut s = String::from(
        "<div class=\"invalid\" id=\"invalid\"><h2>INVALID RUN</h2><p>This run's figures are not valid results:</p><ul>",
    );
    for w in warnings {
        let _ = write!(
            s,
            "<li><code>{}</code>: {}</li>",
            escape(&w.code),
            escape(&w.message)
        );
    }
    s + "</ul></div>"
}

/// The summary table and the metrics table; with `valid` false the metrics are struck through.
fn summary_section(summary: &Summary, metrics: Option<&MetricsReport>, valid: bool) -> String {
    let mut s = String::from("<h2>Summary</h2><table id=\"summary\">");
    for (k, v) in summary.rows() {
        let _ = write!(
            s,
            "<tr><td class=\"k\">{}</td><td>{}</td></tr>",
            escape(k),
            escape(&v)
        );
    }
    s += "</table><h2>Metrics (SPEC §8)</h2>";
    match metrics {
        None => {
            s += "<p class=\"missing\" id=\"metrics\">Not computed yet: run <code>activemap eval RUN_DIR</code>.</p>"
        }
        Some(m) => {
            let cell = |v: Option<f64>, digits: usize, scale: f64| {
                let text = match v {
                    None => return "<td>—</td>".to_string(),
                    Some(x) if x == f64::INFINITY => "∞".to_string(),
                    Some(x) => format!("{:.*}", digits, x * scale),
                };
                if valid {
                    format!("<td>{text}</td>")
                } else {
                    format!("<td class=\"invalid\" title=\"invalid run\"><s>{text}</s></td>")
                }
            };
            let _ = write!(
                s,
                "<table id=\"metrics\"{}><tr><th>PSNR ↑</th><th>SSIM ↑</th><th>LPIPS ↓</th><th>Depth MAE ↓ (m)</th><th>ATE ↓ (m)</th><th>Completeness ↑ (%)</th><th>2D coverage (%)</th><th>test views</th></tr>\
                 <tr>{}{}{}{}{}{}{}<td>{}</td></tr></table>",
                if valid { "" } else { " class=\"invalid\"" },
                cell(m.psnr_db, 2, 1.0),
                cell(m.ssim, 4, 1.0),
                cell(m.lpips, 4, 1.0),
                cell(m.depth_mae_m, 4, 1.0),
                cell(m.ate_rmse_m, 4, 1.0),
                cell(m.completeness, 2, 100.0),
                cell(m.coverage_2d, 2, 100.0),
                m.test_views
            );
            let _ = write!(
                s,
                "<p>Completeness: ground-truth mesh samples within 5 cm of the map's reconstructed \
                 surface (its rendered depth fused in a TSDF), over the samples a camera pose of the \
                 robot can see; accuracy and completion error: mean distances reconstruction → truth \
                 and observable truth → reconstruction.</p>\
                 <table id=\"surface\"{}><tr><th>Completeness, all samples (%)</th>\
                 <th>Completeness, Gaussian centres (%)</th><th>Accuracy ↓ (cm)</th>\
                 <th>Completion error ↓ (cm)</th><th>Observable share (%)</th>\
                 <th>2D coverage, fog of war (%)</th></tr><tr>{}{}{}{}{}{}</tr></table>",
                if valid { "" } else { " class=\"invalid\"" },
                cell(m.completeness_all, 2, 100.0),
                cell(m.completeness_gaussians, 2, 100.0),
                cell(m.accuracy_cm, 2, 1.0),
                cell(m.completion_error_cm, 2, 1.0),
                cell(m.observable_share, 2, 100.0),
                cell(m.coverage_fog, 2, 100.0),
            );
            if !valid {
                s += "<p class=\"missing\">Struck through: the run is INVALID (see above).</p>";
            }
            if m.empty_truth_views > 0 {
                let _ = write!(
                    s,
                    "<p class=\"missing\">{} of {} test views had an empty ground truth and are left out of the image metrics.</p>",
                    m.empty_truth_views, m.test_views
                );
            }
            for (k, why) in &m.missing {
                let _ = write!(s, "<p class=\"missing\">{}: {}</p>", escape(k), escape(why));
            }
        }
    }
    s
}

/// `<img>` of a PNG file of the run folder as a data URI, or `None` when the file is absent.
fn png_img(run: &RunFolder, path: &Path, attrs: &str) -> Result<Option<String>, RunError> {
    Ok(run.read_optional_bytes(path)?.map(|bytes| {
        format!(
            "<img {attrs} src=\"data:image/png;base64,{}\">",
            base64::engine::general_purpose::STANDARD.encode(bytes)
        )
    }))
}

fn map_section(
    run: &RunFolder,
    truth: &Trajectory,
    estimate: &Trajectory,
) -> Result<String, RunError> {
    let mut s = String::from("<h2>Bird's-eye map</h2><div class=\"row\">");
    match png_img(
        run,
        &run.path(RunFolder::BEV),
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
    coverage: Option<&[CoverageRow]>,
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
                    points: rows
                        .iter()
                        .map(|r| (r.step as f64, r.coverage * 100.0))
                        .collect(),
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

/// The median of `values` (mean of the middle two for an even count); `None` when empty.
fn median(values: &[f64]) -> Option<f64> {
    let mut v = values.to_vec();
    v.sort_by(f64::total_cmp);
    let n = v.len();
    match n {
        0 => None,
        _ if n % 2 == 1 => Some(v[n / 2]),
        _ => Some((v[n / 2 - 1] + v[n / 2]) / 2.0),
    }
}

/// One line on the Fisher replans: how many, how many refine, how many fell back, the median
/// replan time.
pub fn fisher_line(rows: &[FisherRow]) -> String {
    let refine = rows.iter().filter(|r| r.refine).count();
    let fallbacks = rows.iter().filter(|r| r.fallback).count();
    let ms: Vec<f64> = rows.iter().map(|r| r.total_ms).collect();
    format!(
        "{} replans, {refine} refine, {fallbacks} fallbacks, median replan {}",
        rows.len(),
        median(&ms).map_or_else(|| "—".to_string(), |m| format!("{m:.1} ms"))
    )
}

fn fisher_section(rows: Option<&[FisherRow]>) -> String {
    let mut s = String::from("<h2>Fisher replans</h2>");
    let Some(rows) = rows else {
        s += "<p class=\"missing\" id=\"fig-fisher\">No Fisher replans (e.g. policy fbe): the run folder holds no fisher.csv.</p>";
        return s;
    };
    // log10 of a non-positive EIG is not finite: the plot skips it.
    let log_eig = |pick: fn(&FisherRow) -> Option<f64>| -> Vec<(f64, f64)> {
        rows.iter()
            .filter_map(|r| pick(r).map(|v| (r.step as f64, v.log10())))
            .collect()
    };
    let eig = svg::line_plot(
        "fig-fisher-eig",
        "EIG of the chosen path (log10)",
        "step",
        "log10 EIG",
        &[
            Series {
                name: "path Σ EIG_i",
                colour: "#6a3d9a",
                points: log_eig(|r| r.eig_sum),
            },
            Series {
                name: "first scored pose EIG_1",
                colour: "#1f9e89",
                points: log_eig(|r| r.eig_first),
            },
        ],
    );
    let c_local = svg::line_plot(
        "fig-fisher-c-local",
        "C_local of the chosen path",
        "step",
        "Σ C_local",
        &[Series {
            name: "Σ C_local(x_i) (+∞ not drawn)",
            colour: "#b03060",
            points: rows
                .iter()
                .filter_map(|r| r.c_local_sum.map(|c| (r.step as f64, c)))
                .collect(),
        }],
    );
    let _ = write!(
        s,
        "<figure id=\"fig-fisher\"><div class=\"row\">{eig}{c_local}</div><figcaption>{}. \
         Left: log10 of the chosen path's EIG (base-10 logarithm of the values, linear axis) per \
         replan, summed over its scored poses and of its first one; right: the sum of its C_local \
         terms. Replans with no chosen path are not drawn.</figcaption></figure>",
        escape(&fisher_line(rows))
    );
    s
}

fn renders_section(run: &RunFolder) -> Result<String, RunError> {
    let per_view = run.read_views()?.unwrap_or_default();
    let mut s = String::from(
        "<h2>Test renders: map (left) and ground truth (right)</h2><div class=\"row\" id=\"fig-renders\">",
    );
    let mut shown = 0;
    for i in 0..100 {
        let map = png_img(
            run,
            &run.view_image(i, ViewImage::Map),
            &format!("class=\"px render\" alt=\"map render {i}\" width=\"200\""),
        )?;
        let truth = png_img(
            run,
            &run.view_image(i, ViewImage::Truth),
            &format!("class=\"px render\" alt=\"ground truth {i}\" width=\"200\""),
        )?;
        let (Some(map), Some(truth)) = (map, truth) else {
            break;
        };
        let caption = match per_view.iter().find(|v| v.view == i) {
            Some(v) => {
                let mut c = format!("view {i}: PSNR {:.2} dB, SSIM {:.3}", v.psnr_db, v.ssim);
                if let Some(l) = v.lpips {
                    let _ = write!(c, ", LPIPS {l:.3}");
                }
                if let Some(d) = v.depth_mae_m {
                    let _ = write!(c, ", depth MAE {d:.3} m");
                }
                c
            }
            None => format!("view {i}"),
        };
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

fn timings_section(run: &RunFolder) -> Result<String, RunError> {
    let mut s = String::from("<h2>Time per stage</h2>");
    let Some(rows) = run.read_timings()? else {
        s += "<p class=\"missing\" id=\"fig-timings\">Not recorded: the run folder holds no timings.csv.</p>";
        return Ok(s);
    };
    // A node restarted by its restart policy appends a second row: one stage, summed.
    let rows = StageTime::summed(&rows);
    let total: f64 = rows.iter().map(|r| r.seconds).sum();
    s += &svg::bars(
        "fig-timings",
        "Wall time per stage",
        &rows
            .iter()
            .map(|r| (r.stage.clone(), r.seconds))
            .collect::<Vec<_>>(),
        "s",
    );
    s += "<table><tr><th>stage</th><th>seconds</th><th>share</th><th>calls</th><th>ms / call</th></tr>";
    for StageTime {
        stage,
        seconds: secs,
        calls,
    } in &rows
    {
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

fn llm_section(run: &RunFolder) -> Result<String, RunError> {
    let mut s = String::from("<h2>LLM exchanges</h2><div id=\"llm-exchanges\">");
    let Some(records) = run.read_llm()? else {
        s += "<p class=\"missing\">None: this run made no LLM exchange (no llm.jsonl).</p>";
        return Ok(s + "</div>");
    };
    let coverage = run.read_coverage()?.unwrap_or_default();
    let totals = crate::run_folder::LlmSummary::of_run(
        &records,
        &coverage,
        crate::run_folder::LLM_OUTCOME_HORIZON_STEPS,
    );
    let _ = write!(s, "<p>{}</p>", escape(&totals.line()));
    let dash = || "—".to_string();
    for r in &records {
        let decided = match (r.target, r.failure.as_deref()) {
            (Some(t), _) => match r.fallback_target {
                Some(f) if f != t => format!("target {t} (the fallback's: {f})"),
                Some(_) => format!("target {t} (as the fallback)"),
                None => format!("target {t}"),
            },
            (None, Some(kind)) => format!(
                "fallback to {} ({kind})",
                r.decision.map_or_else(dash, |v| v.to_string())
            ),
            (None, None) => format!(
                "decision {}",
                r.decision.map_or_else(dash, |v| v.to_string())
            ),
        };
        let image = match &r.bev {
            Some(rel) => png_img(run, &run.path(rel), "class=\"bev\" width=\"400\"")?
                .unwrap_or_else(|| format!("<p class=\"missing\">{} is missing</p>", escape(rel))),
            None => String::new(),
        };
        let finish = r
            .finish_reason
            .as_deref()
            .map_or(String::new(), |f| format!(" · finish {f}"));
        let background = match (r.answered_step, &r.stale) {
            (_, Some(why)) => format!(" · not applied: {why}"),
            (Some(a), None) if Some(a) != r.step => {
                format!(" · asked in the background, applied at step {a}")
            }
            _ => String::new(),
        };
        let decided = decided + &background;
        let refused = if r.schema_refused == Some(true) {
            " · JSON schema refused by the server, sent without"
        } else {
            ""
        };
        let _ = write!(
            s,
            "<details class=\"llm\"><summary>step {} — {} of {} candidates — {}{}</summary>{image}<p><b>reason</b> {}</p><p><b>model</b> {} {} · HTTP {} · {} attempts · {} ms · {} + {} tokens{}{}</p><b>system</b><pre>{}</pre><b>prompt</b><pre>{}</pre>{}<b>reply</b><pre>{}</pre>",
            escape(&r.step.map_or_else(dash, |v| v.to_string())),
            escape(&decided),
            escape(&r.candidates.map_or_else(dash, |v| v.to_string())),
            escape(r.failure_detail.as_deref().unwrap_or("valid reply")),
            if r.follow_up.is_some() {
                " (after a follow-up)"
            } else {
                ""
            },
            escape(r.reason.as_deref().unwrap_or("—")),
            escape(r.provider.as_deref().unwrap_or("—")),
            escape(r.model.as_deref().unwrap_or("")),
            escape(&r.http_status.map_or_else(dash, |v| v.to_string())),
            escape(&r.attempts.map_or_else(dash, |v| v.to_string())),
            escape(&r.latency_ms.map_or_else(dash, |v| format!("{v:.0}"))),
            escape(&r.prompt_tokens.map_or_else(dash, |v| v.to_string())),
            escape(&r.completion_tokens.map_or_else(dash, |v| v.to_string())),
            escape(&finish),
            refused,
            escape(r.system.as_deref().unwrap_or("—")),
            escape(r.prompt.as_deref().unwrap_or("—")),
            reasoning_html("reasoning", r.reasoning.as_deref(), r.thinking.as_deref()),
            escape(r.reply.as_deref().unwrap_or("—"))
        );
        if let Some(f) = &r.follow_up {
            let _ = write!(
                s,
                "<p><b>follow-up</b> because {} · HTTP {} · {} attempts · {} ms · {} + {} tokens{}{}</p><b>follow-up prompt</b><pre>{}</pre>{}<b>follow-up reply</b><pre>{}</pre>",
                escape(f.cause.as_deref().unwrap_or("—")),
                escape(&f.http_status.map_or_else(dash, |v| v.to_string())),
                escape(&f.attempts.map_or_else(dash, |v| v.to_string())),
                escape(&f.latency_ms.map_or_else(dash, |v| format!("{v:.0}"))),
                escape(&f.prompt_tokens.map_or_else(dash, |v| v.to_string())),
                escape(&f.completion_tokens.map_or_else(dash, |v| v.to_string())),
                escape(
                    &f.finish_reason
                        .as_deref()
                        .map_or(String::new(), |v| format!(" · finish {v}"))
                ),
                if f.schema_refused == Some(true) {
                    " · JSON schema refused by the server, sent without"
                } else {
                    ""
                },
                escape(f.prompt.as_deref().unwrap_or("—")),
                reasoning_html(
                    "follow-up reasoning",
                    f.reasoning.as_deref(),
                    f.thinking.as_deref()
                ),
                escape(f.reply.as_deref().unwrap_or("—"))
            );
        }
        s += "</details>";
    }
    if records.is_empty() {
        s += "<p class=\"missing\">None: llm.jsonl is empty.</p>";
    }
    Ok(s + "</div>")
}

/// The reasoning of a reasoning model, titled `title`: the server's separate field and the
/// reply's `<think>` blocks (never parsed as the answer); empty when there is neither.
fn reasoning_html(title: &str, reasoning: Option<&str>, thinking: Option<&str>) -> String {
    let parts: Vec<&str> = [reasoning, thinking]
        .into_iter()
        .flatten()
        .map(str::trim)
        .filter(|t| !t.is_empty())
        .collect();
    if parts.is_empty() {
        return String::new();
    }
    format!(
        "<b>{}</b> (not parsed)<pre class=\"reasoning\">{}</pre>",
        escape(title),
        escape(&parts.join("\n\n"))
    )
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::run_eval::{EvalOptions, LpipsSource, evaluate_run};
    use crate::run_folder::{LlmFollowUpRecord, LlmRecord};
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
            cache_dir: None,
            ..EvalOptions::default()
        };
        evaluate_run(dir, &options).unwrap();
        // A BEV stand-in and the optional inputs, as the pipeline writes them.
        image::RgbImage::from_pixel(8, 6, image::Rgb([200, 200, 200]))
            .save(dir.join(RunFolder::BEV))
            .unwrap();
        std::fs::write(
            dir.join(RunFolder::TIMINGS),
            "stage,seconds,calls\ntracker,2.0,8\nmapper,1.0,4\ntracker,1.0,4\n",
        )
        .unwrap();
        RunFolder::new(dir).write_fisher(&fisher_rows()).unwrap();
        std::fs::write(
            dir.join(RunFolder::LLM),
            "{\"step\": 5, \"prompt\": \"pick <a frontier>\", \"reply\": \"{\\\"target\\\": 1}\", \"target\": 1}\n",
        )
        .unwrap();
    }

    /// Three replans: a frontier one with EIG 10² (first pose 10¹), a refine one that fell
    /// back with no chosen path, a frontier one with EIG 10⁻¹ and C_local +∞.
    fn fisher_rows() -> Vec<FisherRow> {
        let row = |step, refine, chosen: Option<(f64, f64, f64)>, total_ms, fallback| FisherRow {
            step,
            refine,
            candidates: 20,
            paths: 4,
            chosen: if chosen.is_some() { 1 } else { -1 },
            objective: chosen.map(|_| -12.0),
            eig_sum: chosen.map(|c| c.0),
            eig_first: chosen.map(|c| c.1),
            c_local_sum: chosen.map(|c| c.2),
            actions: chosen.map(|_| 30),
            total_ms,
            model_reused: false,
            fallback,
        };
        vec![
            row(20, false, Some((100.0, 10.0, -25.0)), 800.0, false),
            row(40, true, None, 4.0, true),
            row(60, false, Some((0.1, 0.01, f64::INFINITY)), 900.0, false),
        ]
    }

    #[test]
    fn fisher_figure_draws_log10_eig_and_counts_the_replans() {
        let rows = fisher_rows();
        assert_eq!(
            fisher_line(&rows),
            "3 replans, 1 refine, 1 fallbacks, median replan 800.0 ms"
        );
        assert_eq!(
            fisher_line(&rows[..2]),
            "2 replans, 1 refine, 1 fallbacks, median replan 402.0 ms"
        );
        assert_eq!(
            fisher_line(&[]),
            "0 replans, 0 refine, 0 fallbacks, median replan —"
        );
        let html = fisher_section(Some(&rows));
        for id in ["fig-fisher", "fig-fisher-eig", "fig-fisher-c-local"] {
            assert!(html.contains(&format!("id=\"{id}\"")), "{id} missing");
        }
        assert!(html.contains("log10 of the chosen path's EIG"));
        // The points of each polyline of the figure with id `id`.
        let polylines = |id: &str| -> Vec<Vec<String>> {
            let svg = &html[html.find(&format!("id=\"{id}\"")).unwrap()..];
            let svg = &svg[..svg.find("</svg>").unwrap()];
            svg.split("<polyline points=\"")
                .skip(1)
                .map(|p| {
                    p[..p.find('"').unwrap()]
                        .split(' ')
                        .map(String::from)
                        .collect()
                })
                .collect()
        };
        // log10 Σ EIG: 2 at step 20, −1 at step 60 (the refine replan chose nothing); of the
        // first pose 1 and −2. The y axis spans [−2, 2] over the frame's rows 256..30.
        assert_eq!(
            polylines("fig-fisher-eig"),
            [["64.0,30.0", "544.0,199.5"], ["64.0,86.5", "544.0,256.0"]],
            "{html}"
        );
        // C_local: the +∞ sum is not drawn, leaving the point of step 20.
        assert_eq!(polylines("fig-fisher-c-local"), [["304.0,143.0"]]);
        assert!(fisher_section(None).contains("No Fisher replans (e.g. policy fbe)"));
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
            "fig-fisher",
            "fig-fisher-eig",
            "fig-fisher-c-local",
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
        assert!(html.contains("ATE RMSE 0.0000 m over 72 poses"));
        assert!(html.contains("3 replans, 1 refine, 1 fallbacks, median replan 800.0 ms"));
    }

    /// Each LLM query shows its BEV inline, the choice (or the fallback and its kind) and the
    /// reason; the totals line counts calls, fallbacks by kind, tokens and latency.
    #[test]
    fn llm_queries_show_their_bev_choice_and_reason() {
        let dir = tempfile::tempdir().unwrap();
        let run = RunFolder::new(dir.path());
        let bev = run.write_llm_bev(0, 72, b"\x89PNG-bytes").unwrap();
        assert_eq!(bev, "llm/bev_0000_step_72.png");
        let valid = LlmRecord {
            step: Some(72),
            bev: Some(bev),
            candidates: Some(4),
            attempts: Some(2),
            latency_ms: Some(1500.0),
            prompt_tokens: Some(800),
            completion_tokens: Some(30),
            target: Some(2),
            reason: Some("unvisited <bedroom>".into()),
            decision: Some(2),
            reply: Some("plan {\"target\": 2}".into()),
            ..LlmRecord::default()
        };
        let fallback = LlmRecord {
            step: Some(90),
            candidates: Some(3),
            attempts: Some(1),
            latency_ms: Some(500.0),
            decision: Some(0),
            failure: Some("no_json".into()),
            failure_detail: Some("no JSON object in the reply".into()),
            ..LlmRecord::default()
        };
        run.append_llm(&valid).unwrap();
        run.append_llm(&fallback).unwrap();
        assert_eq!(run.read_llm().unwrap().unwrap(), [valid, fallback]);
        let html = llm_section(&run).unwrap();
        assert!(
            html.contains(
                "2 queries, 3 calls, 1 fallbacks (no_json 1), 800 + 30 tokens, 2.0 s model latency"
            ),
            "{html}"
        );
        assert_eq!(html.matches("class=\"bev\"").count(), 1);
        assert!(html.contains("step 72 — target 2 of 4 candidates"));
        assert!(html.contains("unvisited &lt;bedroom&gt;"));
        assert!(html.contains(
            "step 90 — fallback to 0 (no_json) of 3 candidates — no JSON object in the reply"
        ));
    }

    /// A cut reply recovered by a follow-up shows both turns, the finish reasons, the
    /// refused schema and the reasoning (set apart, marked as not parsed); the totals count
    /// the cut reply, the follow-up and its calls and tokens.
    #[test]
    fn llm_follow_ups_finish_reasons_and_reasoning_are_shown() {
        let dir = tempfile::tempdir().unwrap();
        let run = RunFolder::new(dir.path());
        let record = LlmRecord {
            step: Some(40),
            candidates: Some(3),
            attempts: Some(1),
            latency_ms: Some(1000.0),
            prompt_tokens: Some(500),
            completion_tokens: Some(200),
            reply: Some("<think>corridor <first></think>Plan: 1. look".into()),
            thinking: Some("corridor <first>".into()),
            reasoning: Some("separate field".into()),
            finish_reason: Some("length".into()),
            target: Some(1),
            reason: Some("door".into()),
            decision: Some(1),
            follow_up: Some(LlmFollowUpRecord {
                cause: Some("no_json: no JSON object in the reply (finish reason length)".into()),
                prompt: Some("only the JSON".into()),
                attempts: Some(2),
                latency_ms: Some(1000.0),
                prompt_tokens: Some(700),
                completion_tokens: Some(20),
                reply: Some("{\"target\": 1, \"reason\": \"door\"}".into()),
                finish_reason: Some("stop".into()),
                schema_refused: Some(true),
                ..LlmFollowUpRecord::default()
            }),
            ..LlmRecord::default()
        };
        run.append_llm(&record).unwrap();
        let html = llm_section(&run).unwrap();
        assert!(
            html.contains(
                "1 queries, 3 calls, 0 fallbacks, 1200 + 220 tokens, 2.0 s model latency, \
                 1 replies cut (finish reason length), 1 follow-ups (1 recovered)"
            ),
            "{html}"
        );
        assert!(html.contains("valid reply (after a follow-up)"));
        assert!(html.contains("200 tokens · finish length</p>"));
        assert!(
            html.contains("because no_json: no JSON object in the reply (finish reason length)")
        );
        assert!(html.contains("20 tokens · finish stop · JSON schema refused by the server"));
        assert!(html.contains(
            "<b>reasoning</b> (not parsed)<pre class=\"reasoning\">separate field\n\ncorridor &lt;first&gt;</pre>"
        ));
        assert!(html.contains("<b>follow-up reply</b><pre>{&quot;target&quot;: 1"));
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
        assert!(html.contains(
            "<p class=\"missing\" id=\"fig-fisher\">No Fisher replans (e.g. policy fbe)"
        ));
        std::fs::write(
            dir.path().join(RunFolder::FISHER),
            format!(
                "{}\n20,false,1,1,0,,,,,,1,false,false\n",
                <FisherRow as crate::run_folder::CsvRow>::HEADER.join(",")
            ),
        )
        .unwrap();
        let e = render_report(dir.path()).unwrap_err().to_string();
        assert!(
            e.contains("fisher.csv: malformed: line 2: objective is empty"),
            "{e}"
        );
        std::fs::remove_file(dir.path().join(RunFolder::FISHER)).unwrap();
        std::fs::write(
            dir.path().join(RunFolder::TIMINGS),
            "stage,seconds,calls\nx,abc,1\n",
        )
        .unwrap();
        let e = render_report(dir.path()).unwrap_err().to_string();
        assert!(e.contains("timings.csv") && e.contains("line 2"), "{e}");
        std::fs::remove_file(dir.path().join(RunFolder::TIMINGS)).unwrap();
        std::fs::write(dir.path().join(RunFolder::LLM), "{not json\n").unwrap();
        let e = render_report(dir.path()).unwrap_err().to_string();
        assert!(e.contains("llm.jsonl") && e.contains("line 1"), "{e}");
        std::fs::remove_file(dir.path().join(RunFolder::TRAJECTORY_EST)).unwrap();
        let e = render_report(dir.path()).unwrap_err().to_string();
        assert!(e.contains("trajectory_est.tum: missing"), "{e}");
    }

    /// An invalid run's page opens with the INVALID banner listing every reason (the summary's
    /// and the evaluation's, once each) and strikes its figures instead of printing them as
    /// results; a valid run has neither.
    #[test]
    fn an_invalid_run_is_marked_and_its_figures_struck() {
        use crate::validity::code;
        let dir = tempfile::tempdir().unwrap();
        write_run(dir.path(), MapKind::Empty);
        let run = RunFolder::new(dir.path());
        let mut summary = run.read_summary().unwrap();
        summary.warnings = vec![RunWarning::new(
            code::START_SEES_NOTHING,
            "the first frame (0) has 0.00 % valid depth <pixels>",
        )];
        run.write_summary(&summary).unwrap();
        // Before `activemap eval`: the summary's warning alone.
        let html = render_report(dir.path()).unwrap();
        assert!(html.contains("id=\"invalid\"") && html.contains("INVALID RUN"));
        assert!(
            html.contains("<code>start_sees_nothing</code>: the first frame (0) has 0.00 % valid depth &lt;pixels&gt;"),
            "{html}"
        );
        let options = EvalOptions {
            test_views: 3,
            width: 48,
            height: 48,
            lpips: LpipsSource::Off,
            completeness_samples: 2_000,
            saved_views: 0,
            cache_dir: None,
            ..EvalOptions::default()
        };
        let metrics = evaluate_run(dir.path(), &options).unwrap();
        assert!(!metrics.is_valid());
        let html = render_report(dir.path()).unwrap();
        let banner = &html[html.find("id=\"invalid\"").unwrap()..];
        let banner = &banner[..banner.find("</div>").unwrap()];
        assert!(
            banner.contains("<code>start_sees_nothing</code>"),
            "{banner}"
        );
        assert!(banner.contains("<code>empty_map</code>"), "{banner}");
        assert_eq!(html.matches("<code>start_sees_nothing</code>").count(), 1);
        // Coverage 42 %, completeness 0 %: struck, never a plain cell.
        assert!(
            html.contains("<table id=\"metrics\" class=\"invalid\">"),
            "{html}"
        );
        assert!(
            html.contains("<s>42.00</s>") && html.contains("<s>0.00</s>"),
            "{html}"
        );
        assert!(!html.contains("<td>42.00</td>") && !html.contains("<td>0.00</td>"));
        assert!(
            html.contains("<tr><td class=\"k\">valid</td><td>NO: start_sees_nothing</td></tr>")
        );
        // The same folder once valid.
        let summary = Summary {
            warnings: Vec::new(),
            ..summary
        };
        run.write_summary(&summary).unwrap();
        let mut m = metrics;
        m.warnings.clear();
        run.write_metrics(&m, "").unwrap();
        let html = render_report(dir.path()).unwrap();
        assert!(!html.contains("id=\"invalid\"") && !html.contains("<s>"));
        assert!(html.contains("<td>42.00</td>"));
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
            "fig-fisher",
            "fig-renders",
            "fig-timings",
        ] {
            assert!(dom.contains(&format!("id=\"{id}\"")), "{id} not in the DOM");
        }
        assert_eq!(dom.matches("<svg").count(), 6, "6 inline SVG figures");
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
