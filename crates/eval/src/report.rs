//! The metrics of one run (SPEC §8) as one serde struct, written later as `metrics.json` by
//! `activemap eval`. A metric that could not be computed is `None` (JSON `null`) and
//! [`MetricsReport::missing`] says why (e.g. the command that fetches the LPIPS weights).
//! PSNR can be +∞ (identical images): JSON has no infinity, so ±∞ are written as the strings
//! `"inf"` / `"-inf"` and read back from them. A run whose figures mean nothing (issue 16) carries
//! its [`RunWarning`]s: `"valid": false` in the JSON, INVALID and struck figures in Markdown.

use crate::completeness::SurfaceCompleteness;
use crate::depth_breakdown::{DepthErrorClass, DepthErrorShare};
use crate::validity::RunWarning;
use serde::{Deserialize, Deserializer, Serialize, Serializer};
use std::collections::BTreeMap;

/// All metrics of one run; `None` = not computed (see `missing`).
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct MetricsReport {
    /// Mean PSNR over the test views, dB (+∞ when every view is exact).
    #[serde(with = "optional_extended_f64")]
    pub psnr_db: Option<f64>,
    /// Mean SSIM over the test views, in [−1, 1].
    pub ssim: Option<f64>,
    /// Mean LPIPS (AlexNet) over the test views; lower is better.
    pub lpips: Option<f64>,
    /// Mean depth MAE over the test views, metres.
    pub depth_mae_m: Option<f64>,
    /// Where the depth error comes from (`crate::depth_breakdown`): per class of pixel (unmapped,
    /// translucent, in front of the truth, behind it, on the surface), its share of the test
    /// views' valid pixels and of their summed error; empty when not computed (absent in older
    /// files).
    #[serde(default)]
    pub depth_error_breakdown: Vec<DepthErrorShare>,
    /// ATE RMSE after Umeyama SE(3) alignment, metres.
    pub ate_rmse_m: Option<f64>,
    /// Surface completeness at 5 cm over the observable ground-truth samples (SPEC §8, Active
    /// Neural Mapping): the share of mesh samples that a camera pose of the robot can see and
    /// that lie within 5 cm of the map's reconstructed surface (`crate::surface`); fraction in
    /// [0, 1] (the paper prints it ×100 %).
    pub completeness: Option<f64>,
    /// The same surface completeness over every ground-truth sample, observable or not.
    #[serde(default)]
    pub completeness_all: Option<f64>,
    /// Completeness from the map's Gaussian centres (the figure before surface completeness:
    /// mesh samples with a Gaussian mean within 5 cm), over every sample, kept so older results
    /// stay comparable.
    #[serde(default)]
    pub completeness_gaussians: Option<f64>,
    /// Accuracy (Active Neural Mapping): mean distance from the reconstructed surface's samples
    /// to the ground-truth mesh samples, centimetres; lower is better.
    #[serde(default)]
    pub accuracy_cm: Option<f64>,
    /// Completion error (Active Neural Mapping): mean distance from the observable ground-truth
    /// samples to the reconstructed surface, centimetres; lower is better.
    #[serde(default)]
    pub completion_error_cm: Option<f64>,
    /// Share of the ground-truth samples that some camera pose of the robot can see, fraction
    /// in [0, 1]: the ceiling on `completeness_all`.
    #[serde(default)]
    pub observable_share: Option<f64>,
    /// Seen / navigable floor area, fraction in [0, 1].
    pub coverage_2d: Option<f64>,
    /// 2D coverage as the authors' release computes it (a fog of war: 90° FOV, 10 m rays from
    /// the true pose every step, over the navigable cells), fraction in [0, 1].
    #[serde(default)]
    pub coverage_fog: Option<f64>,
    /// Completeness by kind of surface (floor, walls by height, ceiling, …): where the
    /// unobserved surface lies; empty when completeness is missing (absent in older files).
    #[serde(default)]
    pub completeness_by_surface: Vec<SurfaceCompleteness>,
    /// Number of test views drawn; the image metrics average over those with a non-empty ground
    /// truth (`test_views − empty_truth_views`).
    pub test_views: usize,
    /// Metric name → why it is missing.
    pub missing: BTreeMap<String, String>,
    /// Test views whose ground truth was empty (less than
    /// [`crate::validity::VIEW_MIN_VALID_DEPTH`] valid depth), left out of the image metrics
    /// (`test_views` counts them; absent in older files: 0).
    #[serde(default)]
    pub empty_truth_views: usize,
    /// Test views where the map rendered nothing (no Gaussian hit a pixel's ray); they stay in
    /// the means (an unmapped room scores as such); absent in older files: 0.
    #[serde(default)]
    pub empty_render_views: usize,
    /// Why the run is invalid ([`crate::validity`]): the run's `summary.json` warnings and those
    /// of the evaluation; empty = valid (absent in older files: valid). `metrics.json` also says
    /// `"valid": true|false`.
    #[serde(default)]
    pub warnings: Vec<RunWarning>,
}

impl MetricsReport {
    /// Records that `metric` could not be computed and why; its value stays `None`.
    pub fn mark_missing(&mut self, metric: &str, reason: impl Into<String>) {
        self.missing.insert(metric.to_string(), reason.into());
    }

    /// What one class of pixel adds to the pooled mean depth error, metres: its share of the
    /// pixels times its mean error (`crate::depth_breakdown`); `None` without a breakdown.
    pub fn depth_error_contribution_m(&self, class: DepthErrorClass) -> Option<f64> {
        let row = self.depth_error_share(class)?;
        Some(row.pixel_share * row.mean_error_m.unwrap_or(0.0))
    }

    /// The row of the depth error breakdown for `class`; `None` without a breakdown.
    pub fn depth_error_share(&self, class: DepthErrorClass) -> Option<&DepthErrorShare> {
        self.depth_error_breakdown
            .iter()
            .find(|row| row.class == class)
    }

    /// Whether the run is valid: no [`MetricsReport::warnings`].
    pub fn is_valid(&self) -> bool {
        self.warnings.is_empty()
    }

    /// Pretty JSON text (what `metrics.json` holds), with `"valid"` first ([`Self::is_valid`];
    /// derived from the warnings, ignored when read back).
    pub fn to_json(&self) -> String {
        #[derive(Serialize)]
        struct Written<'a> {
            valid: bool,
            #[serde(flatten)]
            report: &'a MetricsReport,
        }
        let written = Written {
            valid: self.is_valid(),
            report: self,
        };
        // Serialising plain numbers, strings and maps cannot fail.
        serde_json::to_string_pretty(&written).unwrap_or_default()
    }

    /// A two-row Markdown table in the column order of the paper's Table 1 (PSNR ↑, SSIM ↑,
    /// LPIPS ↓, depth MAE ↓ m, ATE ↓ m, completeness ↑ %) plus 2-D coverage %; a missing value
    /// prints as `—`, +∞ as `∞`. An invalid run ([`Self::is_valid`]) is headed by
    /// `**INVALID RUN**` and its reasons, and every figure is struck (`~~24.00~~`); test views
    /// left out for an empty ground truth are noted under the table.
    pub fn to_markdown(&self) -> String {
        let valid = self.is_valid();
        let cell = |v: Option<f64>, digits: usize, scale: f64| {
            let text = match v {
                None => return "—".to_string(),
                Some(x) if x == f64::INFINITY => "∞".to_string(),
                Some(x) => format!("{:.*}", digits, x * scale),
            };
            if valid { text } else { format!("~~{text}~~") }
        };
        let mut head = String::new();
        if !valid {
            head += "**INVALID RUN**: these figures are not valid results.\n\n";
            for w in &self.warnings {
                head += &format!("- `{}`: {}\n", w.code, w.message);
            }
            head += "\n";
        }
        let mut foot = String::new();
        if self.empty_truth_views > 0 {
            foot += &format!(
                "\n{} of {} test views had an empty ground truth and are left out of the image metrics.\n",
                self.empty_truth_views, self.test_views
            );
        }
        head + &format!(
            "| PSNR ↑ | SSIM ↑ | LPIPS ↓ | Depth MAE ↓ (m) | ATE ↓ (m) | Completeness ↑ (%) | 2D coverage (%) |\n\
             |---|---|---|---|---|---|---|\n\
             | {} | {} | {} | {} | {} | {} | {} |\n",
            cell(self.psnr_db, 2, 1.0),
            cell(self.ssim, 4, 1.0),
            cell(self.lpips, 4, 1.0),
            cell(self.depth_mae_m, 4, 1.0),
            cell(self.ate_rmse_m, 4, 1.0),
            cell(self.completeness, 2, 100.0),
            cell(self.coverage_2d, 2, 100.0),
        ) + &foot
            + &format!(
                "\nThe surface (completeness: ground-truth samples within 5 cm of the map's \
                 reconstructed surface, over the samples a camera pose of the robot can see; \
                 accuracy and completion error: mean distances reconstruction → truth and \
                 observable truth → reconstruction):\n\n\
                 | Completeness, all samples (%) | Completeness, Gaussian centres (%) | \
                 Accuracy ↓ (cm) | Completion error ↓ (cm) | Observable share (%) | \
                 2D coverage, fog of war (%) |\n\
                 |---|---|---|---|---|---|\n\
                 | {} | {} | {} | {} | {} | {} |\n",
                cell(self.completeness_all, 2, 100.0),
                cell(self.completeness_gaussians, 2, 100.0),
                cell(self.accuracy_cm, 2, 1.0),
                cell(self.completion_error_cm, 2, 1.0),
                cell(self.observable_share, 2, 100.0),
                cell(self.coverage_fog, 2, 100.0),
            )
            + &self.surface_markdown(&cell)
            + &self.depth_breakdown_markdown(&cell)
    }

    /// The depth error breakdown as a Markdown table under a heading (empty without one).
    fn depth_breakdown_markdown(&self, cell: &dyn Fn(Option<f64>, usize, f64) -> String) -> String {
        if self.depth_error_breakdown.is_empty() {
            return String::new();
        }
        let mut text = String::from(
            "\nWhere the depth error comes from (the test views' valid pixels pooled, classed by \
             the map's rendered opacity and its opacity-normalised depth against the truth):\n\n\
             | pixels | share of pixels (%) | share of the error (%) | mean error (cm) |\n\
             |---|---|---|---|\n",
        );
        for row in &self.depth_error_breakdown {
            text += &format!(
                "| {} | {} | {} | {} |\n",
                row.class.label(),
                cell(Some(row.pixel_share), 1, 100.0),
                cell(Some(row.error_share), 1, 100.0),
                cell(row.mean_error_m, 1, 100.0)
            );
        }
        text
    }

    /// The completeness breakdown as a Markdown table under a heading (empty without one).
    fn surface_markdown(&self, cell: &dyn Fn(Option<f64>, usize, f64) -> String) -> String {
        if self.completeness_by_surface.is_empty() {
            return String::new();
        }
        let mut text = String::from(
            "\nCompleteness by surface (share = the surface's part of the mesh area; observable = \
             the part of it a camera pose of the robot can see; completeness over that part):\n\n\
             | surface | share (%) | observable (%) | completeness ↑ (%) |\n|---|---|---|---|\n",
        );
        for s in &self.completeness_by_surface {
            text += &format!(
                "| {} | {} | {} | {} |\n",
                s.surface.label(),
                cell(Some(s.share), 1, 100.0),
                cell(s.observable, 1, 100.0),
                cell(s.completeness, 1, 100.0)
            );
        }
        text
    }

    /// Parses the JSON written by [`MetricsReport::to_json`].
    pub fn from_json(text: &str) -> Result<Self, serde_json::Error> {
        serde_json::from_str(text)
    }
}

/// Serde for `Option<f64>` that writes ±∞ as `"inf"`/`"-inf"` (JSON has no infinity).
mod optional_extended_f64 {
    use super::*;

    #[derive(Serialize, Deserialize)]
    #[serde(untagged)]
    enum Wire {
        Number(f64),
        Text(String),
    }

    pub fn serialize<S: Serializer>(value: &Option<f64>, s: S) -> Result<S::Ok, S::Error> {
        match value {
            None => s.serialize_none(),
            Some(v) if *v == f64::INFINITY => s.serialize_str("inf"),
            Some(v) if *v == f64::NEG_INFINITY => s.serialize_str("-inf"),
            Some(v) => s.serialize_f64(*v),
        }
    }

    pub fn deserialize<'de, D: Deserializer<'de>>(d: D) -> Result<Option<f64>, D::Error> {
        match Option::<Wire>::deserialize(d)? {
            None => Ok(None),
            Some(Wire::Number(v)) => Ok(Some(v)),
            Some(Wire::Text(t)) => match t.as_str() {
                "inf" => Ok(Some(f64::INFINITY)),
                "-inf" => Ok(Some(f64::NEG_INFINITY)),
                other => Err(serde::de::Error::custom(format!(
                    "expected a number, \"inf\" or \"-inf\", found \"{other}\""
                ))),
            },
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn infinity_and_missing_round_trip_through_json() {
        let mut r = MetricsReport {
            psnr_db: Some(f64::INFINITY),
            ssim: Some(1.0),
            ate_rmse_m: Some(0.0226),
            test_views: 3,
            ..Default::default()
        };
        r.mark_missing(
            "lpips",
            "weights absent: run `python3 tools/lpips/fetch_weights.py`",
        );
        let text = r.to_json();
        assert!(text.contains("\"psnr_db\": \"inf\""), "{text}");
        assert!(text.contains("\"lpips\": null"), "{text}");
        let back = MetricsReport::from_json(&text).unwrap();
        assert_eq!(back, r);
        let finite = MetricsReport {
            psnr_db: Some(23.28),
            ..Default::default()
        };
        assert!(finite.to_json().contains("\"psnr_db\": 23.28"));
        assert_eq!(MetricsReport::from_json(&finite.to_json()).unwrap(), finite);
        let table = r.to_markdown();
        assert!(
            table.contains("| ∞ | 1.0000 | — | — | 0.0226 | — | — |"),
            "{table}"
        );
        let paper = MetricsReport {
            psnr_db: Some(23.28),
            completeness: Some(0.8438),
            ..Default::default()
        };
        assert!(
            paper.to_markdown().contains("| 23.28 |") && paper.to_markdown().contains("| 84.38 |")
        );
        assert!(!paper.to_markdown().contains("by surface"));
        let broken_down = MetricsReport {
            completeness_by_surface: vec![
                SurfaceCompleteness {
                    surface: crate::SurfaceClass::WallAbove2m,
                    share: 0.25,
                    completeness: Some(0.125),
                    observable: Some(0.5),
                },
                SurfaceCompleteness {
                    surface: crate::SurfaceClass::Ceiling,
                    share: 0.0,
                    completeness: None,
                    observable: None,
                },
            ],
            depth_error_breakdown: vec![crate::DepthErrorShare {
                class: crate::DepthErrorClass::InFront,
                pixel_share: 0.144,
                error_share: 0.494,
                mean_error_m: Some(0.27),
            }],
            ..paper
        };
        let md = broken_down.to_markdown();
        assert!(
            md.contains("| walls ≥ 2 m | 25.0 | 50.0 | 12.5 |\n| ceiling | 0.0 | — | — |\n"),
            "{md}"
        );
        assert!(
            md.contains("| in front of the truth (> 5 %) | 14.4 | 49.4 | 27.0 |\n"),
            "{md}"
        );
        assert!(
            !MetricsReport::default()
                .to_markdown()
                .contains("depth error comes from")
        );
        let in_front = broken_down
            .depth_error_contribution_m(crate::DepthErrorClass::InFront)
            .unwrap();
        assert!((in_front - 0.144 * 0.27).abs() < 1e-12, "{in_front}");
        assert_eq!(
            broken_down.depth_error_contribution_m(crate::DepthErrorClass::Behind),
            None
        );
        assert_eq!(
            MetricsReport::from_json(&broken_down.to_json()).unwrap(),
            broken_down
        );
        assert!(text.contains("\"valid\": true"), "{text}");
        let bad = text.replace("\"inf\"", "\"lots\"");
        assert!(
            MetricsReport::from_json(&bad)
                .unwrap_err()
                .to_string()
                .contains("lots")
        );
    }

    /// An invalid run says so in JSON (`"valid": false`, the warnings) and in Markdown (INVALID,
    /// the reasons, every figure struck); a metrics.json of an older `activemap eval` (no
    /// `warnings`, no view counts) reads as valid.
    #[test]
    fn invalid_runs_are_marked_and_old_files_read_as_valid() {
        use crate::validity::code;
        let mut r = MetricsReport {
            psnr_db: Some(f64::INFINITY),
            ssim: Some(1.0),
            completeness: Some(0.0),
            coverage_2d: Some(1.0),
            test_views: 20,
            empty_truth_views: 20,
            empty_render_views: 20,
            ..Default::default()
        };
        r.mark_missing("lpips", "disabled");
        r.warnings = vec![
            RunWarning::new(code::EMPTY_MAP, "the final map holds 0 observed Gaussians"),
            RunWarning::new(code::INFINITE_PSNR, "mean PSNR is +∞"),
        ];
        assert!(!r.is_valid());
        let text = r.to_json();
        assert!(text.contains("\"valid\": false"), "{text}");
        assert!(text.contains("\"code\": \"empty_map\""), "{text}");
        assert_eq!(MetricsReport::from_json(&text).unwrap(), r);
        let md = r.to_markdown();
        assert!(md.starts_with("**INVALID RUN**"), "{md}");
        assert!(
            md.contains("- `empty_map`: the final map holds 0 observed Gaussians\n")
                && md.contains("- `infinite_psnr`: mean PSNR is +∞\n"),
            "{md}"
        );
        assert!(
            md.contains("| ~~∞~~ | ~~1.0000~~ | — | — | — | ~~0.00~~ | ~~100.00~~ |"),
            "{md}"
        );
        assert!(!md.contains("| ∞ |") && !md.contains("| 100.00 |"), "{md}");
        assert!(
            md.contains("20 of 20 test views had an empty ground truth"),
            "{md}"
        );
        let old = MetricsReport::from_json(
            "{\"psnr_db\": 21.5, \"ssim\": null, \"lpips\": null, \"depth_mae_m\": null, \"ate_rmse_m\": null, \"completeness\": null, \"coverage_2d\": null, \"test_views\": 3, \"missing\": {}}",
        )
        .unwrap();
        assert!(old.is_valid() && old.warnings.is_empty() && old.empty_truth_views == 0);
        assert!(!old.to_markdown().contains("INVALID") && old.to_markdown().contains("| 21.50 |"));
    }
}
