//! The metrics of one run (SPEC §8) as one serde struct, written later as `metrics.json` by
//! `activemap eval`. A metric that could not be computed is `None` (JSON `null`) and
//! [`MetricsReport::missing`] says why (e.g. the command that fetches the LPIPS weights).
//! PSNR can be +∞ (identical images): JSON has no infinity, so ±∞ are written as the strings
//! `"inf"` / `"-inf"` and read back from them.

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
    /// ATE RMSE after Umeyama SE(3) alignment, metres.
    pub ate_rmse_m: Option<f64>,
    /// Completeness at 5 cm, fraction in [0, 1] (the paper prints it ×100 %).
    pub completeness: Option<f64>,
    /// Seen / navigable floor area, fraction in [0, 1].
    pub coverage_2d: Option<f64>,
    /// Number of test views the image metrics average over.
    pub test_views: usize,
    /// Metric name → why it is missing.
    pub missing: BTreeMap<String, String>,
}

impl MetricsReport {
    /// Records that `metric` could not be computed and why; its value stays `None`.
    pub fn mark_missing(&mut self, metric: &str, reason: impl Into<String>) {
        self.missing.insert(metric.to_string(), reason.into());
    }

    /// Pretty JSON text (what `metrics.json` holds).
    pub fn to_json(&self) -> String {
        // Serialising plain numbers, strings and maps cannot fail.
        serde_json::to_string_pretty(self).unwrap_or_default()
    }

    /// A two-row Markdown table in the column order of the paper's Table 1 (PSNR ↑, SSIM ↑,
    /// LPIPS ↓, depth MAE ↓ m, ATE ↓ m, completeness ↑ %) plus 2-D coverage %; a missing value
    /// prints as `—`, +∞ as `∞`.
    pub fn to_markdown(&self) -> String {
        let cell = |v: Option<f64>, digits: usize, scale: f64| match v {
            None => "—".to_string(),
            Some(x) if x == f64::INFINITY => "∞".to_string(),
            Some(x) => format!("{:.*}", digits, x * scale),
        };
        format!(
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
        )
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
        let bad = text.replace("\"inf\"", "\"lots\"");
        assert!(
            MetricsReport::from_json(&bad)
                .unwrap_err()
                .to_string()
                .contains("lots")
        );
    }
}
