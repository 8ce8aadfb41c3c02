//! The results table in the layout of the paper's Table 1 (rows = methods; columns PSNR ↑,
//! SSIM ↑, LPIPS ↓, depth MAE ↓, RMSE ATE ↓, completeness ↑ %, SPEC §8), a companion table
//! of accuracy, completion error, the other completeness figures, the observable share and
//! both 2D coverages ([`COLUMNS`]), as Markdown and CSV (written with the `csv` crate).
//!
//! Aggregation: the paper averages each method over the scenes of a dataset. Here, for each seed,
//! the mean over the scenes is taken; the table shows the mean of those per-seed values and their
//! spread (sample standard deviation, n − 1) over seeds. A seed counts for a metric only when every
//! scene of it is complete with that metric, so a failed run never biases the mean (the `runs`
//! column shows how many cells are complete). A per-scene table gives mean ± spread over seeds.
//!
//! An **invalid** run (its `metrics.json` carries warnings, `activemap_eval::validity`: a start
//! that sees nothing, a robot that cannot move, an empty map, empty test views…) counts like an
//! unfinished one: it is left out of every mean, the `runs` column counts it
//! (`2/4 (1 invalid)`), the notes list it with its reasons, and `results.csv` has an `invalid`
//! column.
//!
//! When two or more of the named policies of the paper's ablation ([`KNOWN_METHODS`]: `fbe`,
//! `fisher_eig_only` = "w/o LLM & localisation", `fisher` = "w/o LLM") are among the methods,
//! an ablation table lists their all-scene rows in that order, each with the paper's name.
//!
//! **Paired comparison** ([`paired`], `paired.csv`): every method against a baseline (`fbe`
//! when it ran, otherwise the first method) over the (scene, seed) pairs where both runs are
//! complete and valid: wins and losses by the column's direction ([`Better`]), the mean of the
//! differences and its 95 % percentile bootstrap interval (10 000 resamples, fixed seed, so the
//! same runs always give the same interval). An interval that leaves out 0 is printed bold.
//!
//! Under them, completeness by kind of surface (floor, walls by height, ceiling) per method says
//! where the surface no method observed lies.

use super::grid::{KNOWN_METHODS, KnownMethod};
use super::runner::{CellOutcome, CellResult};
use activemap_eval::{MetricsReport, SurfaceClass};
use std::collections::{BTreeMap, BTreeSet};
use std::fmt::Write as _;

/// Which way a column improves, for the paired wins and losses.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Better {
    /// Higher is better (PSNR, SSIM, completeness, coverage).
    Higher,
    /// Lower is better (LPIPS, depth MAE, ATE, accuracy, completion error).
    Lower,
    /// Neither: a property of the scene rather than of the method (the observable share);
    /// no wins or losses are counted.
    Neither,
}

impl Better {
    /// The arrow printed after a column's title.
    pub fn arrow(self) -> &'static str {
        match self {
            Better::Higher => "↑",
            Better::Lower => "↓",
            Better::Neither => "",
        }
    }

    /// The word written in `paired.csv`.
    pub fn word(self) -> &'static str {
        match self {
            Better::Higher => "higher",
            Better::Lower => "lower",
            Better::Neither => "neither",
        }
    }
}

/// One column of the table.
pub struct Column {
    /// CSV name (unit in the name).
    pub key: &'static str,
    /// Markdown header.
    pub title: &'static str,
    /// Decimals printed in Markdown.
    pub digits: usize,
    /// Factor from the stored value to the printed one (100 for percentages).
    pub scale: f64,
    /// Which way the column improves.
    pub better: Better,
    /// One of the paper's Table 1 columns (the first Markdown table); the others go to the
    /// surface-and-coverage table.
    pub table1: bool,
    /// The value in a run's metrics.
    pub get: fn(&MetricsReport) -> Option<f64>,
}

/// The columns: Table 1's (PSNR, SSIM, LPIPS, depth MAE, ATE, completeness), then the part of
/// the depth error from surfaces rendered in front of the true ones, Active Neural Mapping's
/// accuracy and completion error, the other completeness figures, the
/// observable share and both 2D coverages.
pub const COLUMNS: [Column; 14] = [
    Column {
        key: "psnr_db",
        title: "PSNR ↑",
        digits: 2,
        scale: 1.0,
        better: Better::Higher,
        table1: true,
        get: |m| m.psnr_db,
    },
    Column {
        key: "ssim",
        title: "SSIM ↑",
        digits: 4,
        scale: 1.0,
        better: Better::Higher,
        table1: true,
        get: |m| m.ssim,
    },
    Column {
        key: "lpips",
        title: "LPIPS ↓",
        digits: 4,
        scale: 1.0,
        better: Better::Lower,
        table1: true,
        get: |m| m.lpips,
    },
    Column {
        key: "depth_mae_m",
        title: "Depth MAE ↓ (m)",
        digits: 4,
        scale: 1.0,
        better: Better::Lower,
        table1: true,
        get: |m| m.depth_mae_m,
    },
    Column {
        key: "ate_rmse_m",
        title: "RMSE ATE ↓ (m)",
        digits: 4,
        scale: 1.0,
        better: Better::Lower,
        table1: true,
        get: |m| m.ate_rmse_m,
    },
    Column {
        key: "completeness_pct",
        title: "Completeness (%) ↑",
        digits: 2,
        scale: 100.0,
        better: Better::Higher,
        table1: true,
        get: |m| m.completeness,
    },
    Column {
        key: "depth_mae_in_front_cm",
        title: "Depth MAE from surfaces in front ↓ (cm)",
        digits: 2,
        scale: 100.0,
        better: Better::Lower,
        table1: false,
        get: |m| m.depth_error_contribution_m(activemap_eval::DepthErrorClass::InFront),
    },
    Column {
        key: "accuracy_cm",
        title: "Accuracy ↓ (cm)",
        digits: 2,
        scale: 1.0,
        better: Better::Lower,
        table1: false,
        get: |m| m.accuracy_cm,
    },
    Column {
        key: "completion_error_cm",
        title: "Completion error ↓ (cm)",
        digits: 2,
        scale: 1.0,
        better: Better::Lower,
        table1: false,
        get: |m| m.completion_error_cm,
    },
    Column {
        key: "completeness_all_pct",
        title: "Completeness, all samples (%) ↑",
        digits: 2,
        scale: 100.0,
        better: Better::Higher,
        table1: false,
        get: |m| m.completeness_all,
    },
    Column {
        key: "completeness_gaussians_pct",
        title: "Completeness, Gaussian centres (%) ↑",
        digits: 2,
        scale: 100.0,
        better: Better::Higher,
        table1: false,
        get: |m| m.completeness_gaussians,
    },
    Column {
        key: "observable_share_pct",
        title: "Observable share (%)",
        digits: 2,
        scale: 100.0,
        better: Better::Neither,
        table1: false,
        get: |m| m.observable_share,
    },
    Column {
        key: "coverage_2d_pct",
        title: "2D coverage (%) ↑",
        digits: 2,
        scale: 100.0,
        better: Better::Higher,
        table1: false,
        get: |m| m.coverage_2d,
    },
    Column {
        key: "coverage_fog_pct",
        title: "2D coverage, fog of war (%) ↑",
        digits: 2,
        scale: 100.0,
        better: Better::Higher,
        table1: false,
        get: |m| m.coverage_fog,
    },
];

/// Index in [`COLUMNS`] of the column named `key` (its CSV name).
pub fn column_index(key: &str) -> Option<usize> {
    COLUMNS.iter().position(|c| c.key == key)
}

/// Mean and spread of one metric over seeds (printed units: percentages already ×100).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Stat {
    /// Mean.
    pub mean: f64,
    /// Sample standard deviation (n − 1); `None` with one value or an infinite mean.
    pub spread: Option<f64>,
    /// Number of values (seeds).
    pub n: usize,
}

impl Stat {
    /// Mean and sample standard deviation of `values` (`None` when empty).
    pub fn of(values: &[f64]) -> Option<Self> {
        if values.is_empty() {
            return None;
        }
        let n = values.len();
        let mean = values.iter().sum::<f64>() / n as f64;
        let spread = if n >= 2 && mean.is_finite() {
            let ss: f64 = values.iter().map(|v| (v - mean).powi(2)).sum();
            Some((ss / (n - 1) as f64).sqrt())
        } else {
            None
        };
        Some(Self { mean, spread, n })
    }

    fn markdown(&self, digits: usize) -> String {
        let number = |x: f64| {
            if x == f64::INFINITY {
                "∞".to_string()
            } else {
                format!("{x:.digits$}")
            }
        };
        match self.spread {
            Some(s) => format!("{} ± {}", number(self.mean), number(s)),
            None => number(self.mean),
        }
    }
}

/// One row: a method over all scenes (`scene` = `None`) or on one scene.
#[derive(Debug, Clone, PartialEq)]
pub struct TableRow {
    /// Method name.
    pub method: String,
    /// The scene, or `None` for the all-scene row.
    pub scene: Option<String>,
    /// Complete and valid cells (the ones the means use).
    pub complete: usize,
    /// Complete cells whose run is invalid (left out of the means).
    pub invalid: usize,
    /// Cells of the row.
    pub cells: usize,
    /// One entry per [`COLUMNS`] entry; `None` = no usable value.
    pub values: Vec<Option<Stat>>,
}

/// The metrics of a cell when it is complete and its run valid (what the means use).
fn valid_metrics(r: &CellResult) -> Option<&MetricsReport> {
    r.outcome.metrics().filter(|m| m.is_valid())
}

/// Cells of `rows` that are complete but invalid.
fn invalid_count(rows: &[&CellResult]) -> usize {
    rows.iter()
        .filter(|r| r.outcome.metrics().is_some_and(|m| !m.is_valid()))
        .count()
}

fn ordered<T: Ord + Clone>(items: impl Iterator<Item = T>) -> Vec<T> {
    let mut seen = BTreeSet::new();
    items.filter(|x| seen.insert(x.clone())).collect()
}

/// The all-scene rows (Table 1), one per method in first-seen order.
pub fn method_rows(results: &[CellResult]) -> Vec<TableRow> {
    let methods = ordered(results.iter().map(|r| r.cell.method.name.clone()));
    methods
        .into_iter()
        .map(|method| {
            let rows: Vec<&CellResult> = results
                .iter()
                .filter(|r| r.cell.method.name == method)
                .collect();
            let seeds = ordered(rows.iter().map(|r| r.cell.seed));
            let values = COLUMNS
                .iter()
                .map(|col| {
                    let per_seed: Vec<f64> = seeds
                        .iter()
                        .filter_map(|&seed| {
                            let cells: Vec<Option<f64>> = rows
                                .iter()
                                .filter(|r| r.cell.seed == seed)
                                .map(|r| valid_metrics(r).and_then(col.get))
                                .collect();
                            let all: Option<Vec<f64>> = cells.into_iter().collect();
                            all.filter(|v| !v.is_empty())
                                .map(|v| v.iter().sum::<f64>() / v.len() as f64 * col.scale)
                        })
                        .collect();
                    Stat::of(&per_seed)
                })
                .collect();
            TableRow {
                complete: rows.iter().filter(|r| valid_metrics(r).is_some()).count(),
                invalid: invalid_count(&rows),
                cells: rows.len(),
                method,
                scene: None,
                values,
            }
        })
        .collect()
}

/// The per-scene rows: method × scene, mean ± spread over the complete seeds.
pub fn scene_rows(results: &[CellResult]) -> Vec<TableRow> {
    let keys = ordered(
        results
            .iter()
            .map(|r| (r.cell.method.name.clone(), r.cell.scene.clone())),
    );
    keys.into_iter()
        .map(|(method, scene)| {
            let rows: Vec<&CellResult> = results
                .iter()
                .filter(|r| r.cell.method.name == method && r.cell.scene == scene)
                .collect();
            let values = COLUMNS
                .iter()
                .map(|col| {
                    let v: Vec<f64> = rows
                        .iter()
                        .filter_map(|r| valid_metrics(r).and_then(col.get))
                        .map(|x| x * col.scale)
                        .collect();
                    Stat::of(&v)
                })
                .collect();
            TableRow {
                complete: rows.iter().filter(|r| valid_metrics(r).is_some()).count(),
                invalid: invalid_count(&rows),
                cells: rows.len(),
                method,
                scene: Some(scene),
                values,
            }
        })
        .collect()
}

/// The ablation rows: the all-scene rows of the [`KNOWN_METHODS`] present, in that order, each
/// with its policy; empty unless at least two of them are present.
pub fn ablation_rows(results: &[CellResult]) -> Vec<(&'static KnownMethod, TableRow)> {
    let rows = method_rows(results);
    let picked: Vec<(&'static KnownMethod, TableRow)> = KNOWN_METHODS
        .iter()
        .filter_map(|known| {
            rows.iter()
                .find(|r| r.method == known.name)
                .map(|r| (known, r.clone()))
        })
        .collect();
    if picked.len() >= 2 {
        picked
    } else {
        Vec::new()
    }
}

/// A Markdown table of `rows` over the [`COLUMNS`] whose `table1` flag equals `table1`: the
/// method, then an optional second text column (`(header, one value per row)`), the metrics
/// and the runs. A missing value is `—`.
fn markdown_table(rows: &[TableRow], second: Option<(&str, Vec<String>)>, table1: bool) -> String {
    let columns: Vec<(&Column, usize)> = COLUMNS
        .iter()
        .enumerate()
        .filter(|(_, c)| c.table1 == table1)
        .map(|(i, c)| (c, i))
        .collect();
    let mut s = String::from("| Method |");
    if let Some((header, _)) = &second {
        let _ = write!(s, " {header} |");
    }
    for (c, _) in &columns {
        let _ = write!(s, " {} |", c.title);
    }
    s += " Runs |\n|---|";
    if second.is_some() {
        s += "---|";
    }
    s += &"---|".repeat(columns.len() + 1);
    s += "\n";
    for (i, row) in rows.iter().enumerate() {
        let _ = write!(s, "| {} |", row.method);
        if let Some((_, values)) = &second {
            let _ = write!(s, " {} |", values.get(i).map_or("", String::as_str));
        }
        for (c, k) in &columns {
            let _ = write!(
                s,
                " {} |",
                row.values[*k].map_or("—".to_string(), |v| v.markdown(c.digits))
            );
        }
        let _ = write!(s, " {}/{}", row.complete, row.cells);
        if row.invalid > 0 {
            let _ = write!(s, " ({} invalid)", row.invalid);
        }
        s += " |\n";
    }
    s
}

/// The method the paired comparisons take as their baseline: `fbe` when it ran, otherwise the
/// first method; `None` when fewer than two methods ran.
pub fn baseline(results: &[CellResult]) -> Option<String> {
    let methods = ordered(results.iter().map(|r| r.cell.method.name.clone()));
    if methods.len() < 2 {
        return None;
    }
    Some(
        methods
            .iter()
            .find(|m| m.as_str() == "fbe")
            .unwrap_or(&methods[0])
            .clone(),
    )
}

/// Fewest pairs for a bootstrap interval: a single pair resamples only to itself. With few
/// pairs the percentile interval is narrow (every resample of two same-signed differences
/// leaves out 0): read it with the number of pairs.
pub const MIN_PAIRS_FOR_INTERVAL: usize = 2;

/// One method against the baseline on one column, over the (scene, seed) pairs where both
/// cells are complete, valid and have a finite value.
#[derive(Debug, Clone, PartialEq)]
pub struct Paired {
    /// The method.
    pub method: String,
    /// The baseline it is compared with.
    pub baseline: String,
    /// Index of the column in [`COLUMNS`].
    pub column: usize,
    /// Number of (scene, seed) pairs.
    pub pairs: usize,
    /// Pairs where the method is better (by the column's [`Better`]); 0 for `Neither`.
    pub wins: usize,
    /// Pairs where the method is worse; 0 for `Neither`.
    pub losses: usize,
    /// Pairs with equal values (or any pair of a `Neither` column that is neither).
    pub ties: usize,
    /// Mean of method − baseline over the pairs, printed units; `None` without pairs.
    pub mean_difference: Option<f64>,
    /// 95 % percentile bootstrap interval of that mean
    /// ([`crate::stats::bootstrap_mean_interval`], 10 000 resamples, fixed seed); `None`
    /// with fewer than [`MIN_PAIRS_FOR_INTERVAL`] pairs.
    pub interval: Option<(f64, f64)>,
}

impl Paired {
    /// True when the interval leaves out 0: the difference is unlikely to be chance.
    pub fn decided(&self) -> bool {
        self.interval.is_some_and(|(lo, hi)| lo > 0.0 || hi < 0.0)
    }
}

/// Every method other than the [`baseline`] against it, column by column, in method then
/// [`COLUMNS`] order; empty when fewer than two methods ran.
pub fn paired(results: &[CellResult]) -> Vec<Paired> {
    use crate::stats::{BOOTSTRAP_RESAMPLES, BOOTSTRAP_SEED, bootstrap_mean_interval};
    let Some(baseline) = baseline(results) else {
        return Vec::new();
    };
    let value = |method: &str, scene: &str, seed: u64, column: &Column| -> Option<f64> {
        results
            .iter()
            .find(|r| r.cell.method.name == method && r.cell.scene == scene && r.cell.seed == seed)
            .and_then(valid_metrics)
            .and_then(column.get)
            .map(|v| v * column.scale)
            .filter(|v| v.is_finite())
    };
    let keys = ordered(
        results
            .iter()
            .filter(|r| r.cell.method.name == baseline)
            .map(|r| (r.cell.scene.clone(), r.cell.seed)),
    );
    let methods = ordered(results.iter().map(|r| r.cell.method.name.clone()));
    let mut out = Vec::new();
    for method in methods.iter().filter(|m| **m != baseline) {
        for (index, column) in COLUMNS.iter().enumerate() {
            let differences: Vec<f64> = keys
                .iter()
                .filter_map(|(scene, seed)| {
                    let b = value(&baseline, scene, *seed, column)?;
                    let m = value(method, scene, *seed, column)?;
                    Some(m - b)
                })
                .collect();
            let count = |keep: fn(f64) -> bool| differences.iter().filter(|d| keep(**d)).count();
            let (wins, losses) = match column.better {
                Better::Higher => (count(|d| d > 0.0), count(|d| d < 0.0)),
                Better::Lower => (count(|d| d < 0.0), count(|d| d > 0.0)),
                Better::Neither => (0, 0),
            };
            let pairs = differences.len();
            out.push(Paired {
                method: method.clone(),
                baseline: baseline.clone(),
                column: index,
                pairs,
                wins,
                losses,
                ties: pairs - wins - losses,
                mean_difference: (pairs > 0)
                    .then(|| differences.iter().sum::<f64>() / pairs as f64),
                // One pair resamples to itself: no interval.
                interval: if pairs >= MIN_PAIRS_FOR_INTERVAL {
                    bootstrap_mean_interval(&differences, 0.95, BOOTSTRAP_RESAMPLES, BOOTSTRAP_SEED)
                } else {
                    None
                },
            });
        }
    }
    out
}

/// The paired comparison as Markdown: one line per method and column with pairs; an interval
/// that leaves out 0 is bold.
fn paired_markdown(rows: &[Paired]) -> String {
    let mut s = String::from(
        "| Method | Metric | Pairs | Wins | Losses | Ties | Mean Δ (method − baseline) | 95 % bootstrap interval |\n\
         |---|---|---|---|---|---|---|---|\n",
    );
    for p in rows.iter().filter(|p| p.pairs > 0) {
        let c = &COLUMNS[p.column];
        let digits = c.digits;
        let signed = |x: f64| format!("{x:+.digits$}");
        let (wins, losses) = if c.better == Better::Neither {
            ("—".to_string(), "—".to_string())
        } else {
            (p.wins.to_string(), p.losses.to_string())
        };
        let interval = p.interval.map_or("—".to_string(), |(lo, hi)| {
            let text = format!("[{}, {}]", signed(lo), signed(hi));
            if p.decided() {
                format!("**{text}**")
            } else {
                text
            }
        });
        let _ = writeln!(
            s,
            "| {} | {} | {} | {wins} | {losses} | {} | {} | {interval} |",
            p.method,
            c.title,
            p.pairs,
            p.ties,
            p.mean_difference.map_or("—".to_string(), signed),
        );
    }
    s
}

/// The whole `paired.csv`: one row per method other than the baseline and column (every
/// column, with `pairs` 0 and empty figures where there are none); differences in the printed
/// units of `results.csv` (percentages ×100).
pub fn paired_csv(results: &[CellResult]) -> String {
    let mut w = ::csv::Writer::from_writer(Vec::new());
    let number = |x: Option<f64>| x.map_or(String::new(), |v| v.to_string());
    let _ = w.write_record([
        "method",
        "baseline",
        "metric",
        "better",
        "pairs",
        "wins",
        "losses",
        "ties",
        "mean_difference",
        "ci95_low",
        "ci95_high",
    ]);
    for p in paired(results) {
        let c = &COLUMNS[p.column];
        let _ = w.write_record([
            p.method.clone(),
            p.baseline.clone(),
            c.key.to_string(),
            c.better.word().to_string(),
            p.pairs.to_string(),
            p.wins.to_string(),
            p.losses.to_string(),
            p.ties.to_string(),
            number(p.mean_difference),
            number(p.interval.map(|i| i.0)),
            number(p.interval.map(|i| i.1)),
        ]);
    }
    csv_text(w)
}

/// The text a CSV writer over a `Vec<u8>` holds (writing to memory cannot fail).
fn csv_text(w: ::csv::Writer<Vec<u8>>) -> String {
    w.into_inner()
        .map(|bytes| String::from_utf8_lossy(&bytes).into_owned())
        .unwrap_or_default()
}

/// Why values are missing, which cells did not finish and which runs are invalid (with their
/// reasons), as Markdown bullet lines.
fn notes(results: &[CellResult]) -> String {
    let mut reasons: BTreeMap<(String, String), Vec<String>> = BTreeMap::new();
    let mut unfinished = Vec::new();
    for r in results {
        match &r.outcome {
            CellOutcome::Reused(m) | CellOutcome::Ran(m) => {
                if !m.is_valid() {
                    let why: Vec<String> = m
                        .warnings
                        .iter()
                        .map(|w| format!("`{}`: {}", w.code, w.message))
                        .collect();
                    unfinished.push(format!(
                        "{}: INVALID, left out of the means: {}",
                        r.cell.label(),
                        why.join("; ")
                    ));
                }
                for (metric, why) in &m.missing {
                    reasons
                        .entry((metric.clone(), why.clone()))
                        .or_default()
                        .push(r.cell.label());
                }
            }
            CellOutcome::Failed(why) => {
                unfinished.push(format!("{}: failed: {why}", r.cell.label()))
            }
            CellOutcome::Interrupted => {
                unfinished.push(format!("{}: not run (stopped)", r.cell.label()))
            }
        }
    }
    let mut s = String::new();
    for ((metric, why), cells) in &reasons {
        let _ = writeln!(
            s,
            "- `{metric}` missing in {} run(s) ({}): {why}",
            cells.len(),
            cells.join(", ")
        );
    }
    for line in unfinished {
        let _ = writeln!(s, "- {line}");
    }
    s
}

/// Where the unobserved surface lies, per method: the mean over its valid cells of each
/// [`SurfaceClass`]'s completeness (%), under a row of the classes' mean share of the mesh
/// area. Empty when no cell has the breakdown (runs evaluated before it existed).
fn surface_table(results: &[CellResult]) -> String {
    let with_breakdown: Vec<(&str, &MetricsReport)> = results
        .iter()
        .filter_map(|r| valid_metrics(r).map(|m| (r.cell.method.name.as_str(), m)))
        .filter(|(_, m)| m.completeness_by_surface.len() == SurfaceClass::ALL.len())
        .collect();
    if with_breakdown.is_empty() {
        return String::new();
    }
    let mean = |values: Vec<f64>| -> String {
        if values.is_empty() {
            "—".to_string()
        } else {
            format!(
                "{:.1}",
                100.0 * values.iter().sum::<f64>() / values.len() as f64
            )
        }
    };
    let mut s = String::from("| Method | Runs |");
    for class in SurfaceClass::ALL {
        let _ = write!(s, " {} |", class.label());
    }
    s += "\n|---|---|";
    s += &"---|".repeat(SurfaceClass::ALL.len());
    s += "\n| *share of the mesh area (%)* | |";
    for i in 0..SurfaceClass::ALL.len() {
        let shares = with_breakdown
            .iter()
            .map(|(_, m)| m.completeness_by_surface[i].share)
            .collect();
        let _ = write!(s, " {} |", mean(shares));
    }
    s += "\n";
    for method in ordered(with_breakdown.iter().map(|(name, _)| *name)) {
        let cells: Vec<&MetricsReport> = with_breakdown
            .iter()
            .filter(|(name, _)| *name == method)
            .map(|(_, m)| *m)
            .collect();
        let _ = write!(s, "| {method} | {} |", cells.len());
        for i in 0..SurfaceClass::ALL.len() {
            let values = cells
                .iter()
                .filter_map(|m| m.completeness_by_surface[i].completeness)
                .collect();
            let _ = write!(s, " {} |", mean(values));
        }
        s += "\n";
    }
    s
}

/// The whole `results.md`: `heading` lines (settings, command), Table 1 layout and its
/// surface-and-coverage companion, the ablation (when two or more of its policies ran), the
/// paired comparison against the baseline, the per-scene tables and the notes.
pub fn markdown(heading: &str, results: &[CellResult]) -> String {
    let mut s = format!("# Results\n\n{heading}\n\n");
    s += "## Methods over all scenes (Table 1 layout)\n\n";
    s += "Mean ± sample standard deviation over seeds of the per-seed mean over scenes; \
          a seed counts for a metric only when all its scenes have it. Runs = complete / cells; \
          invalid runs (see the notes) are left out of every mean and counted apart; — = not \
          available.\n\n";
    let rows = method_rows(results);
    s += &markdown_table(&rows, None, true);
    s += "\n### Surface and coverage (same aggregation)\n\n";
    s += "Accuracy and completion error as Active Neural Mapping defines them; completeness \
          over every ground-truth sample and from the Gaussian centres; the share of the \
          ground truth a camera pose of the robot can see; 2D coverage as this project and as \
          the authors' release (fog of war) compute it.\n\n";
    s += &markdown_table(&rows, None, false);
    let ablation = ablation_rows(results);
    if !ablation.is_empty() {
        s += "\n## Ablation (the paper's variants; same aggregation)\n\n";
        let (known, rows): (Vec<&KnownMethod>, Vec<TableRow>) = ablation.into_iter().unzip();
        let names = known.iter().map(|k| k.ablation.to_string()).collect();
        s += &markdown_table(&rows, Some(("Variant", names)), true);
    }
    let pairs = paired(results);
    if let Some(first) = pairs.first() {
        let _ = write!(
            s,
            "\n## Paired against `{}` (same scene and seed)\n\n\
             For each (scene, seed) where both runs are complete and valid: a win when the \
             method is better than `{0}` by the column's arrow, a loss when worse; Δ = method − \
             `{0}` in the table's units, its mean over the pairs and the 95 % percentile \
             bootstrap interval of that mean (10 000 resamples of the pairs, fixed seed; none \
             from a single pair). A **bold** interval leaves out 0: a difference chance alone \
             is unlikely to make; with few pairs the interval is narrow, so read it with their \
             number.\n\n",
            first.baseline
        );
        s += &paired_markdown(&pairs);
    }
    s += "\n## Per scene (mean ± spread over seeds)\n\n";
    let rows = scene_rows(results);
    let scenes: Vec<String> = rows
        .iter()
        .map(|r| r.scene.clone().unwrap_or_default())
        .collect();
    s += &markdown_table(&rows, Some(("Scene", scenes.clone())), true);
    s += "\n";
    s += &markdown_table(&rows, Some(("Scene", scenes)), false);
    let surfaces = surface_table(results);
    if !surfaces.is_empty() {
        s += "\n## Completeness by surface (%, mean over valid runs)\n\n";
        s += "Where the unobserved surface lies: horizontal = normal within 45° of vertical; \
              floor and ceiling = horizontal within 15 cm of the floor or the scene's top; walls \
              (everything steeper) by height above the floor.\n\n";
        s += &surfaces;
    }
    let n = notes(results);
    if !n.is_empty() {
        s += "\n## Notes\n\n";
        s += &n;
    }
    s
}

/// The whole `results.csv`: one row per method over all scenes (`scene` = `all`) then per
/// method and scene; `<metric>` is the mean, `<metric>_std` the spread, `<metric>_n` the number
/// of seeds; empty = not available. Percentages are ×100. `complete` counts the complete valid
/// cells, the last column `invalid` the complete cells left out as invalid.
pub fn csv(results: &[CellResult]) -> String {
    let mut w = ::csv::Writer::from_writer(Vec::new());
    let mut header: Vec<String> = ["method", "scene", "complete", "cells"]
        .map(String::from)
        .to_vec();
    for c in &COLUMNS {
        header.extend([
            c.key.to_string(),
            format!("{}_std", c.key),
            format!("{}_n", c.key),
        ]);
    }
    header.push("invalid".into());
    let _ = w.write_record(&header);
    for row in method_rows(results).iter().chain(&scene_rows(results)) {
        let mut record = vec![
            row.method.clone(),
            row.scene.clone().unwrap_or_else(|| "all".into()),
            row.complete.to_string(),
            row.cells.to_string(),
        ];
        for v in &row.values {
            match v {
                Some(v) => record.extend([
                    if v.mean == f64::INFINITY {
                        "inf".to_string()
                    } else {
                        v.mean.to_string()
                    },
                    v.spread.map_or(String::new(), |x| x.to_string()),
                    v.n.to_string(),
                ]),
                None => record.extend([String::new(), String::new(), "0".into()]),
            }
        }
        record.push(row.invalid.to_string());
        let _ = w.write_record(&record);
    }
    csv_text(w)
}

#[cfg(test)]
mod tests {
    use super::super::grid::{GridSettings, Method, cells};
    use super::*;

    fn report(psnr: f64, completeness: Option<f64>) -> MetricsReport {
        let mut m = MetricsReport {
            psnr_db: Some(psnr),
            completeness,
            ..Default::default()
        };
        m.mark_missing("lpips", "weights absent");
        m
    }

    /// 2 houses × 2 seeds of FBE with hand-picked values.
    fn results() -> Vec<CellResult> {
        let settings = GridSettings {
            steps: 10,
            resolution: 32,
            max_rooms: None,
            max_area: None,
            eval_views: 4,
            noise: None,
            ..GridSettings::default()
        };
        let grid = cells(
            &[Method::parse("fbe=x.yaml").unwrap()],
            &["house:1".into(), "house:2".into()],
            &[1, 2],
            &settings,
        );
        // (house 1, seed 1), (house 1, seed 2), (house 2, seed 1), (house 2, seed 2)
        let metrics = [
            report(20.0, Some(0.50)),
            report(22.0, Some(0.70)),
            report(24.0, Some(0.60)),
            report(30.0, None),
        ];
        grid.into_iter()
            .zip(metrics)
            .map(|(cell, m)| CellResult {
                cell,
                outcome: CellOutcome::Ran(Box::new(m)),
            })
            .collect()
    }

    #[test]
    fn method_row_averages_scenes_per_seed_then_spreads_over_seeds() {
        let rows = method_rows(&results());
        assert_eq!(rows.len(), 1);
        let psnr = rows[0].values[0].unwrap();
        // Seed 1: (20 + 24) / 2 = 22; seed 2: (22 + 30) / 2 = 26 → mean 24, std √8.
        assert_eq!(psnr.mean, 24.0);
        assert!((psnr.spread.unwrap() - 8f64.sqrt()).abs() < 1e-12);
        assert_eq!(psnr.n, 2);
        // Completeness: seed 2 lacks house 2, so only seed 1 counts: (50 + 60) / 2 %.
        let comp = rows[0].values[5].unwrap();
        assert!((comp.mean - 55.0).abs() < 1e-12 && comp.spread.is_none() && comp.n == 1);
        assert!(rows[0].values[1].is_none(), "no SSIM anywhere");
        assert_eq!((rows[0].complete, rows[0].cells), (4, 4));
    }

    #[test]
    fn scene_rows_and_both_formats_hold_the_same_numbers() {
        let r = results();
        let rows = scene_rows(&r);
        assert_eq!(rows.len(), 2);
        let h2 = &rows[1];
        assert_eq!(h2.scene.as_deref(), Some("house:2"));
        assert_eq!(h2.values[0].unwrap().mean, 27.0);
        assert!((h2.values[0].unwrap().spread.unwrap() - 18f64.sqrt()).abs() < 1e-12);
        let md = markdown("FBE, 10 steps", &r);
        assert!(
            md.contains("| fbe | 24.00 ± 2.83 | — | — | — | — | 55.00 | 4/4 |"),
            "{md}"
        );
        assert!(md.contains("| fbe | house:2 | 27.00 ± 4.24 |"), "{md}");
        assert!(md.contains("`lpips` missing in 4 run(s)"), "{md}");
        let csv = csv(&r);
        let lines: Vec<&str> = csv.lines().collect();
        assert_eq!(lines.len(), 4, "{csv}");
        assert!(
            lines[0].starts_with("method,scene,complete,cells,psnr_db,psnr_db_std,psnr_db_n,ssim,")
        );
        let f: Vec<&str> = lines[1].split(',').collect();
        let spread = format!("{}", 8f64.sqrt());
        assert_eq!(
            &f[..7],
            ["fbe", "all", "4", "4", "24", spread.as_str(), "2"]
        );
        assert_eq!(&f[7..10], ["", "", "0"]);
    }

    /// The surface table averages each class over the method's valid cells with a breakdown,
    /// and is absent when no cell has one.
    #[test]
    fn completeness_by_surface_is_averaged_per_method() {
        use activemap_eval::SurfaceCompleteness;
        let mut r = results();
        assert!(!markdown("", &r).contains("Completeness by surface"));
        for (i, cell) in r.iter_mut().enumerate().take(2) {
            if let CellOutcome::Ran(m) = &mut cell.outcome {
                m.completeness_by_surface = SurfaceClass::ALL
                    .iter()
                    .map(|&surface| SurfaceCompleteness {
                        surface,
                        share: 1.0 / 6.0,
                        // Floor 0.9 and 0.7; no ceiling sample in the first cell.
                        completeness: match (surface, i) {
                            (SurfaceClass::Ceiling, 0) => None,
                            (SurfaceClass::Floor, _) => Some(0.9 - 0.2 * i as f64),
                            _ => Some(0.25),
                        },
                        observable: None,
                    })
                    .collect();
            }
        }
        let md = markdown("", &r);
        assert!(
            md.contains("| *share of the mesh area (%)* | | 16.7 | 16.7 |"),
            "{md}"
        );
        assert!(
            md.contains("| fbe | 2 | 80.0 | 25.0 | 25.0 | 25.0 | 25.0 | 25.0 |\n"),
            "{md}"
        );
    }

    #[test]
    fn unfinished_cells_are_counted_and_listed() {
        let mut r = results();
        r[3].outcome = CellOutcome::Failed("tracker crashed".into());
        r[1].outcome = CellOutcome::Interrupted;
        let rows = method_rows(&r);
        assert_eq!((rows[0].complete, rows[0].cells), (2, 4));
        // Only seed 1 is whole: (20 + 24) / 2.
        assert_eq!(rows[0].values[0].unwrap().mean, 22.0);
        let md = markdown("", &r);
        assert!(
            md.contains("fbe house:2 seed 2: failed: tracker crashed"),
            "{md}"
        );
        assert!(md.contains("fbe house:1 seed 2: not run (stopped)"), "{md}");
        let inf = Stat::of(&[f64::INFINITY, 3.0]).unwrap();
        assert!(inf.spread.is_none() && inf.markdown(2) == "∞");
        assert!(Stat::of(&[]).is_none());
    }

    /// An invalid run (warnings in its metrics) is left out of the means like a failed one,
    /// counted in the runs column and the CSV, and listed with its reasons in the notes; its
    /// PSNR +∞ never reaches the table.
    #[test]
    fn invalid_runs_are_marked_and_left_out_of_the_means() {
        use activemap_eval::RunWarning;
        let mut r = results();
        // House 2, seed 2: the user's run (a robot boxed in, an empty map, PSNR ∞).
        if let CellOutcome::Ran(m) = &mut r[3].outcome {
            m.psnr_db = Some(f64::INFINITY);
            m.warnings = vec![
                RunWarning::new("robot_cannot_move", "206 of 206 forward moves blocked"),
                RunWarning::new("empty_map", "the final map holds 0 observed Gaussians"),
            ];
        }
        let rows = method_rows(&r);
        assert_eq!(
            (rows[0].complete, rows[0].invalid, rows[0].cells),
            (3, 1, 4)
        );
        // Only seed 1 is whole and valid: (20 + 24) / 2, finite.
        assert_eq!(rows[0].values[0].unwrap().mean, 22.0);
        let scenes = scene_rows(&r);
        assert_eq!((scenes[1].complete, scenes[1].invalid), (1, 1));
        assert_eq!(scenes[1].values[0].unwrap().mean, 24.0);
        assert_eq!((scenes[0].complete, scenes[0].invalid), (2, 0));
        let md = markdown("", &r);
        assert!(md.contains("| 3/4 (1 invalid) |"), "{md}");
        assert!(md.contains("| house:2 | 24.00 |"), "{md}");
        assert!(!md.contains('∞'), "{md}");
        assert!(
            md.contains(
                "- fbe house:2 seed 2: INVALID, left out of the means: `robot_cannot_move`: 206 of 206 forward moves blocked; `empty_map`: the final map holds 0 observed Gaussians"
            ),
            "{md}"
        );
        let csv = csv(&r);
        let lines: Vec<&str> = csv.lines().collect();
        assert!(lines[0].ends_with(",coverage_fog_pct_n,invalid"), "{csv}");
        let all: Vec<&str> = lines[1].split(',').collect();
        assert_eq!((all[2], all[3], *all.last().unwrap()), ("3", "4", "1"));
        assert_eq!(all[4], "22");
        let house1: Vec<&str> = lines[2].split(',').collect();
        assert_eq!(*house1.last().unwrap(), "0");
        // Every row has as many fields as the header.
        let fields = lines[0].split(',').count();
        assert!(
            lines.iter().all(|l| l.split(',').count() == fields),
            "{csv}"
        );
    }

    /// Methods × one house × two seeds; PSNR `base + seed` for each method.
    fn ablation_results(methods: &[(&str, f64)]) -> Vec<CellResult> {
        let settings = GridSettings {
            steps: 10,
            resolution: 32,
            max_rooms: None,
            max_area: None,
            eval_views: 4,
            noise: None,
            ..GridSettings::default()
        };
        let parsed: Vec<Method> = methods
            .iter()
            .map(|(m, _)| Method::parse(&format!("{m}=x.yaml")).unwrap())
            .collect();
        cells(&parsed, &["house:1".into()], &[1, 2], &settings)
            .into_iter()
            .map(|cell| {
                let base = methods
                    .iter()
                    .find(|(m, _)| *m == cell.method.name)
                    .unwrap()
                    .1;
                let m = report(base + cell.seed as f64, Some(0.5));
                CellResult {
                    cell,
                    outcome: CellOutcome::Ran(Box::new(m)),
                }
            })
            .collect()
    }

    /// The ablation lists the paper's variants in the paper's order (whatever the command-line
    /// order), with their names, and leaves other methods out; it needs two variants.
    #[test]
    fn ablation_rows_follow_the_paper_order_and_names() {
        let r = ablation_results(&[
            ("fisher", 30.0),
            ("mine", 10.0),
            ("fbe", 20.0),
            ("fisher_eig_only", 25.0),
        ]);
        let rows = ablation_rows(&r);
        let names: Vec<(&str, &str)> = rows
            .iter()
            .map(|(k, r)| (k.name, r.method.as_str()))
            .collect();
        assert_eq!(
            names,
            [
                ("fbe", "fbe"),
                ("fisher_eig_only", "fisher_eig_only"),
                ("fisher", "fisher")
            ]
        );
        // Mean over seeds 1, 2 of base + seed, spread √0.5.
        assert_eq!(rows[2].1.values[0].unwrap().mean, 31.5);
        let md = markdown("", &r);
        let ablation = &md[md.find("## Ablation").expect("an ablation section")..];
        let ablation = &ablation[..ablation.find("## Paired").unwrap()];
        assert!(
            ablation.contains("| Method | Variant | PSNR ↑ |"),
            "{ablation}"
        );
        assert!(
            ablation.contains("| fisher_eig_only | w/o LLM & localisation | 26.50 ± 0.71 |"),
            "{ablation}"
        );
        assert!(
            ablation.contains("| fisher | w/o LLM | 31.50 ± 0.71 |"),
            "{ablation}"
        );
        assert!(!ablation.contains("mine"), "{ablation}");
        let fbe = ablation.find("| fbe |").unwrap();
        let eig = ablation.find("| fisher_eig_only |").unwrap();
        let full = ablation.find("| fisher |").unwrap();
        assert!(fbe < eig && eig < full);
        // The Table 1 rows keep the command-line order and every method.
        let table1 = &md[..md.find("## Ablation").unwrap()];
        assert!(table1.find("| fisher |").unwrap() < table1.find("| mine |").unwrap());
        // One variant alone: no ablation section.
        let single = ablation_results(&[("fbe", 20.0), ("mine", 10.0)]);
        assert!(ablation_rows(&single).is_empty());
        assert!(!markdown("", &single).contains("## Ablation"));
    }

    /// `fisher` (listed first) against `fbe` on one house, seeds 1–4; seed 4's `fisher` run
    /// is invalid. PSNR: fbe 20, 23, 19, fisher 21, 22, 21 → Δ +1, −1, +2 (2 wins, 1 loss,
    /// mean 2/3); ATE (lower is better): fbe 0.5, 0.25, 0.125 m, fisher 0.25, 0.25, 0.375 →
    /// Δ −0.25, 0, +0.25 (1 win, 1 loss, 1 tie, mean 0); completeness 50 → 75 % everywhere
    /// (3 wins, interval [25, 25]); observable share equal (no wins or losses); SSIM absent.
    fn paired_results() -> Vec<CellResult> {
        let settings = GridSettings {
            steps: 10,
            resolution: 32,
            max_rooms: None,
            max_area: None,
            eval_views: 4,
            noise: None,
            ..GridSettings::default()
        };
        let methods = [
            Method::parse("fisher=x.yaml").unwrap(),
            Method::parse("fbe=y.yaml").unwrap(),
        ];
        cells(&methods, &["house:1".into()], &[1, 2, 3, 4], &settings)
            .into_iter()
            .map(|cell| {
                let fbe = cell.method.name == "fbe";
                let i = cell.seed as usize - 1;
                let (psnr, ate, completeness) = if fbe {
                    ([20.0, 23.0, 19.0, 30.0][i], [0.5, 0.25, 0.125, 0.5][i], 0.5)
                } else {
                    (
                        [21.0, 22.0, 21.0, 10.0][i],
                        [0.25, 0.25, 0.375, 0.5][i],
                        0.75,
                    )
                };
                let mut m = MetricsReport {
                    psnr_db: Some(psnr),
                    ate_rmse_m: Some(ate),
                    completeness: Some(completeness),
                    observable_share: Some(0.8),
                    ..Default::default()
                };
                if !fbe && cell.seed == 4 {
                    m.warnings = vec![activemap_eval::RunWarning::new("empty_map", "no map")];
                }
                CellResult {
                    cell,
                    outcome: CellOutcome::Ran(Box::new(m)),
                }
            })
            .collect()
    }

    #[test]
    fn paired_comparison_counts_wins_and_losses_by_direction() {
        let r = paired_results();
        assert_eq!(baseline(&r).as_deref(), Some("fbe"));
        let rows = paired(&r);
        assert_eq!(rows.len(), COLUMNS.len(), "one method × every column");
        let get = |key: &str| rows[column_index(key).unwrap()].clone();
        let psnr = get("psnr_db");
        assert_eq!(
            (psnr.method.as_str(), psnr.baseline.as_str()),
            ("fisher", "fbe")
        );
        assert_eq!(
            (psnr.pairs, psnr.wins, psnr.losses, psnr.ties),
            (3, 2, 1, 0)
        );
        assert!((psnr.mean_difference.unwrap() - 2.0 / 3.0).abs() < 1e-12);
        let (lo, hi) = psnr.interval.unwrap();
        assert!(
            lo < 2.0 / 3.0 && 2.0 / 3.0 < hi && lo >= -1.0 && hi <= 2.0,
            "{lo} {hi}"
        );
        assert!(!psnr.decided());
        let ate = get("ate_rmse_m");
        assert_eq!((ate.pairs, ate.wins, ate.losses, ate.ties), (3, 1, 1, 1));
        assert_eq!(ate.mean_difference, Some(0.0));
        let comp = get("completeness_pct");
        assert_eq!((comp.wins, comp.losses), (3, 0));
        assert_eq!(comp.interval, Some((25.0, 25.0)));
        assert!(comp.decided());
        let share = get("observable_share_pct");
        assert_eq!(
            (share.pairs, share.wins, share.losses, share.ties),
            (3, 0, 0, 3)
        );
        let ssim = get("ssim");
        assert_eq!(
            (ssim.pairs, ssim.mean_difference, ssim.interval),
            (0, None, None)
        );
        assert_eq!(paired(&r), rows, "deterministic");

        let md = markdown("", &r);
        assert!(md.contains("## Paired against `fbe`"), "{md}");
        assert!(
            md.contains(&format!(
                "| fisher | PSNR ↑ | 3 | 2 | 1 | 0 | +0.67 | [{lo:+.2}, {hi:+.2}] |"
            )),
            "{md}"
        );
        assert!(
            md.contains(
                "| fisher | Completeness (%) ↑ | 3 | 3 | 0 | 0 | +25.00 | **[+25.00, +25.00]** |"
            ),
            "{md}"
        );
        assert!(
            md.contains("| fisher | Observable share (%) | 3 | — | — | 3 | +0.00 |"),
            "{md}"
        );
        assert!(
            !md.contains("| fisher | SSIM ↑ |"),
            "no pairs, no line: {md}"
        );
        assert!(md.contains("- fisher house:1 seed 4: INVALID"), "{md}");

        let csv = paired_csv(&r);
        let mut reader = ::csv::Reader::from_reader(csv.as_bytes());
        let header = reader.headers().unwrap().clone();
        assert_eq!(header.get(0), Some("method"));
        let records: Vec<::csv::StringRecord> = reader.records().map(Result::unwrap).collect();
        assert_eq!(records.len(), COLUMNS.len());
        let psnr_row = &records[column_index("psnr_db").unwrap()];
        assert_eq!(
            psnr_row.iter().take(8).collect::<Vec<_>>(),
            ["fisher", "fbe", "psnr_db", "higher", "3", "2", "1", "0"]
        );
        assert_eq!(psnr_row[9].parse::<f64>().unwrap(), lo);
        assert_eq!(psnr_row[10].parse::<f64>().unwrap(), hi);
        let ssim_row = &records[column_index("ssim").unwrap()];
        assert_eq!((&ssim_row[4], &ssim_row[8]), ("0", ""));
        // One pair (seeds 2–4 of fisher left out): a mean difference, but no interval.
        let one: Vec<CellResult> = r
            .iter()
            .filter(|c| c.cell.method.name == "fbe" || c.cell.seed == 1)
            .cloned()
            .collect();
        let psnr_one = paired(&one)[column_index("psnr_db").unwrap()].clone();
        assert_eq!(
            (psnr_one.pairs, psnr_one.mean_difference, psnr_one.interval),
            (1, Some(1.0), None)
        );
        assert!(!psnr_one.decided());
        assert!(
            markdown("", &one).contains("| fisher | PSNR ↑ | 1 | 1 | 0 | 0 | +1.00 | — |"),
            "{}",
            markdown("", &one)
        );
        // One method alone: nothing to pair.
        let alone: Vec<CellResult> = r
            .into_iter()
            .filter(|c| c.cell.method.name == "fbe")
            .collect();
        assert!(paired(&alone).is_empty() && baseline(&alone).is_none());
        assert!(!markdown("", &alone).contains("## Paired"));
    }

    /// A scene name with a comma is quoted in the CSV by the csv crate, and reads back whole.
    #[test]
    fn csv_quotes_fields_that_need_it() {
        let mut r = results();
        for c in &mut r {
            c.cell.scene = format!("{}, \"big\"", c.cell.scene);
        }
        let text = csv(&r);
        let mut reader = ::csv::Reader::from_reader(text.as_bytes());
        let scenes: Vec<String> = reader
            .records()
            .map(|rec| rec.unwrap()[1].to_string())
            .collect();
        assert_eq!(scenes, ["all", "house:1, \"big\"", "house:2, \"big\""]);
    }
}
