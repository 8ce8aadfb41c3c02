//! The results table in the layout of the paper's Table 1 (rows = methods; columns PSNR ↑,
//! SSIM ↑, LPIPS ↓, depth MAE ↓, RMSE ATE ↓, completeness ↑ %, SPEC §8) plus 2D coverage, as
//! Markdown and CSV.
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
//! Under them, completeness by kind of surface (floor, walls by height, ceiling) per method says
//! where the surface no method observed lies.

use super::grid::{KNOWN_METHODS, KnownMethod};
use super::runner::{CellOutcome, CellResult};
use activemap_eval::{MetricsReport, SurfaceClass};
use std::collections::{BTreeMap, BTreeSet};
use std::fmt::Write as _;

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
    /// The value in a run's metrics.
    pub get: fn(&MetricsReport) -> Option<f64>,
}

/// The columns in Table 1 order, then 2D coverage.
pub const COLUMNS: [Column; 7] = [
    Column {
        key: "psnr_db",
        title: "PSNR ↑",
        digits: 2,
        scale: 1.0,
        get: |m| m.psnr_db,
    },
    Column {
        key: "ssim",
        title: "SSIM ↑",
        digits: 4,
        scale: 1.0,
        get: |m| m.ssim,
    },
    Column {
        key: "lpips",
        title: "LPIPS ↓",
        digits: 4,
        scale: 1.0,
        get: |m| m.lpips,
    },
    Column {
        key: "depth_mae_m",
        title: "Depth MAE ↓ (m)",
        digits: 4,
        scale: 1.0,
        get: |m| m.depth_mae_m,
    },
    Column {
        key: "ate_rmse_m",
        title: "RMSE ATE ↓ (m)",
        digits: 4,
        scale: 1.0,
        get: |m| m.ate_rmse_m,
    },
    Column {
        key: "completeness_pct",
        title: "Completeness (%) ↑",
        digits: 2,
        scale: 100.0,
        get: |m| m.completeness,
    },
    Column {
        key: "coverage_2d_pct",
        title: "2D coverage (%) ↑",
        digits: 2,
        scale: 100.0,
        get: |m| m.coverage_2d,
    },
];

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

/// A Markdown table of `rows`: the method, then an optional second text column (`(header,
/// one value per row)`), the metrics and the runs.
fn markdown_table(rows: &[TableRow], second: Option<(&str, Vec<String>)>) -> String {
    let mut s = String::from("| Method |");
    if let Some((header, _)) = &second {
        let _ = write!(s, " {header} |");
    }
    for c in &COLUMNS {
        let _ = write!(s, " {} |", c.title);
    }
    s += " Runs |\n|---|";
    if second.is_some() {
        s += "---|";
    }
    s += &"---|".repeat(COLUMNS.len() + 1);
    s += "\n";
    for (i, row) in rows.iter().enumerate() {
        let _ = write!(s, "| {} |", row.method);
        if let Some((_, values)) = &second {
            let _ = write!(s, " {} |", values.get(i).map_or("", String::as_str));
        }
        for (c, v) in COLUMNS.iter().zip(&row.values) {
            let _ = write!(
                s,
                " {} |",
                v.map_or("—".to_string(), |v| v.markdown(c.digits))
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

/// The whole `results.md`: `heading` lines (settings, command), Table 1 layout, the ablation
/// (when two or more of its policies ran), the per-scene table and the notes.
pub fn markdown(heading: &str, results: &[CellResult]) -> String {
    let mut s = format!("# Results\n\n{heading}\n\n");
    s += "## Methods over all scenes (Table 1 layout)\n\n";
    s += "Mean ± sample standard deviation over seeds of the per-seed mean over scenes; \
          a seed counts for a metric only when all its scenes have it. Runs = complete / cells; \
          invalid runs (see the notes) are left out of every mean and counted apart.\n\n";
    s += &markdown_table(&method_rows(results), None);
    let ablation = ablation_rows(results);
    if !ablation.is_empty() {
        s += "\n## Ablation (the paper's variants; same aggregation)\n\n";
        let (known, rows): (Vec<&KnownMethod>, Vec<TableRow>) = ablation.into_iter().unzip();
        let names = known.iter().map(|k| k.ablation.to_string()).collect();
        s += &markdown_table(&rows, Some(("Variant", names)));
    }
    s += "\n## Per scene (mean ± spread over seeds)\n\n";
    let rows = scene_rows(results);
    let scenes = rows
        .iter()
        .map(|r| r.scene.clone().unwrap_or_default())
        .collect();
    s += &markdown_table(&rows, Some(("Scene", scenes)));
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
    let mut s = String::from("method,scene,complete,cells");
    for c in &COLUMNS {
        let _ = write!(s, ",{0},{0}_std,{0}_n", c.key);
    }
    s.push_str(",invalid\n");
    for row in method_rows(results).iter().chain(&scene_rows(results)) {
        let _ = write!(
            s,
            "{},{},{},{}",
            csv_field(&row.method),
            csv_field(row.scene.as_deref().unwrap_or("all")),
            row.complete,
            row.cells
        );
        for v in &row.values {
            match v {
                Some(v) => {
                    let mean = if v.mean == f64::INFINITY {
                        "inf".to_string()
                    } else {
                        format!("{}", v.mean)
                    };
                    let _ = write!(
                        s,
                        ",{mean},{},{}",
                        v.spread.map_or(String::new(), |x| format!("{x}")),
                        v.n
                    );
                }
                None => s.push_str(",,,0"),
            }
        }
        let _ = writeln!(s, ",{}", row.invalid);
    }
    s
}

fn csv_field(text: &str) -> String {
    if text.contains([',', '"', '\n']) {
        format!("\"{}\"", text.replace('"', "\"\""))
    } else {
        text.to_string()
    }
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
            md.contains("| fbe | 24.00 ± 2.83 | — | — | — | — | 55.00 | — | 4/4 |"),
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
        assert!(lines[0].ends_with(",coverage_2d_pct_n,invalid"), "{csv}");
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
        let ablation = &ablation[..ablation.find("## Per scene").unwrap()];
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
}
