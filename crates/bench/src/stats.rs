//! Small statistics for the benchmarks: medians and quantiles of timings, and the Spearman rank
//! correlation of the EIG–PSNR benchmark (ranks with average ties, then the Pearson correlation
//! of the ranks, as `scipy.stats.spearmanr`), and the percentile bootstrap interval of a mean
//! that the paired comparisons of `bench results` print.

/// The `q`-quantile (`q` in [0, 1]) of `values` with linear interpolation between order
/// statistics (numpy's default); `None` when empty. NaNs sort last.
pub fn quantile(values: &[f64], q: f64) -> Option<f64> {
    if values.is_empty() {
        return None;
    }
    let mut v = values.to_vec();
    v.sort_by(f64::total_cmp);
    let pos = q.clamp(0.0, 1.0) * (v.len() - 1) as f64;
    let (lo, hi) = (pos.floor() as usize, pos.ceil() as usize);
    let frac = pos - lo as f64;
    Some(if lo == hi {
        v[lo]
    } else {
        v[lo] + (v[hi] - v[lo]) * frac
    })
}

/// The quantiles the benchmarks' tables print: min, 10 %, quartiles, 90 %, max.
pub const TABLE_QUANTILES: [f64; 7] = [0.0, 0.1, 0.25, 0.5, 0.75, 0.9, 1.0];

/// A table of [`TABLE_QUANTILES`] of each named row of values: a header `quantile q0 q10 …`,
/// then one line per row, the name left in `label_width` columns and each quantile with
/// `decimals` decimals (NaN for an empty row).
pub fn quantile_table(rows: &[(&str, &[f64])], label_width: usize, decimals: usize) -> String {
    let mut s = format!("{:<label_width$}", "quantile");
    for q in TABLE_QUANTILES {
        s.push_str(&format!(" {:>10}", format!("q{:.0}", q * 100.0)));
    }
    s.push('\n');
    for (name, values) in rows {
        s.push_str(&format!("{name:<label_width$}"));
        for q in TABLE_QUANTILES {
            let v = quantile(values, q).unwrap_or(f64::NAN);
            s.push_str(&format!(" {:>10}", format!("{v:.decimals$}")));
        }
        s.push('\n');
    }
    s
}

/// The indices of `key` in four groups by rank (lowest quarter first), each about a quarter of
/// them: the quartile rows of the benchmarks' tables.
pub fn quartiles_by(key: &[f64]) -> [Vec<usize>; 4] {
    let mut order: Vec<usize> = (0..key.len()).collect();
    order.sort_by(|&a, &b| key[a].total_cmp(&key[b]));
    let n = order.len();
    std::array::from_fn(|k| order[k * n / 4..(k + 1) * n / 4].to_vec())
}

/// The median of `values` (the mean of the middle two for an even count); `None` when empty.
pub fn median(values: &[f64]) -> Option<f64> {
    quantile(values, 0.5)
}

/// Ranks of `values`, 1-based, tied values sharing the mean of their ranks (so `[10, 20, 20,
/// 30]` ranks `[1, 2.5, 2.5, 4]`). Values compare by `total_cmp`.
pub fn ranks(values: &[f64]) -> Vec<f64> {
    let mut order: Vec<usize> = (0..values.len()).collect();
    order.sort_by(|&a, &b| values[a].total_cmp(&values[b]));
    let mut out = vec![0.0; values.len()];
    let mut i = 0;
    while i < order.len() {
        let mut j = i + 1;
        while j < order.len() && values[order[j]].total_cmp(&values[order[i]]).is_eq() {
            j += 1;
        }
        // Ranks i+1 ..= j share their mean.
        let rank = (i + 1 + j) as f64 / 2.0;
        for &k in &order[i..j] {
            out[k] = rank;
        }
        i = j;
    }
    out
}

/// The Pearson correlation of `a` and `b`; `None` when the lengths differ, fewer than two
/// pairs are given, a value is not finite, or either side is constant.
pub fn pearson(a: &[f64], b: &[f64]) -> Option<f64> {
    if a.len() != b.len() || a.len() < 2 || a.iter().chain(b).any(|v| !v.is_finite()) {
        return None;
    }
    let n = a.len() as f64;
    let (ma, mb) = (a.iter().sum::<f64>() / n, b.iter().sum::<f64>() / n);
    let (mut sab, mut saa, mut sbb) = (0.0, 0.0, 0.0);
    for (x, y) in a.iter().zip(b) {
        let (dx, dy) = (x - ma, y - mb);
        sab += dx * dy;
        saa += dx * dx;
        sbb += dy * dy;
    }
    (saa > 0.0 && sbb > 0.0).then(|| (sab / (saa * sbb).sqrt()).clamp(-1.0, 1.0))
}

/// The Spearman rank correlation of `a` and `b`: the Pearson correlation of their
/// average-tie ranks; `None` as for [`pearson`] (a NaN or infinite value, a constant side).
pub fn spearman(a: &[f64], b: &[f64]) -> Option<f64> {
    if a.iter().chain(b).any(|v| !v.is_finite()) {
        return None;
    }
    pearson(&ranks(a), &ranks(b))
}

/// Kendall's rank correlation τ-b of `a` and `b` (as `scipy.stats.kendalltau`):
/// `(C − D)/√((n₀ − n_a)(n₀ − n_b))` over the `n₀ = n(n−1)/2` pairs, `C`/`D` the concordant
/// and discordant pairs, `n_a`/`n_b` the pairs tied in `a`/`b`. `None` when the lengths
/// differ, fewer than two pairs are given, a value is NaN, or either side is constant.
/// Infinite values rank as the extremes they are. O(n²): meant for rankings of tens.
pub fn kendall_tau(a: &[f64], b: &[f64]) -> Option<f64> {
    if a.len() != b.len() || a.len() < 2 || a.iter().chain(b).any(|v| v.is_nan()) {
        return None;
    }
    let n = a.len();
    let (mut concordant, mut discordant, mut tied_a, mut tied_b) = (0i64, 0i64, 0i64, 0i64);
    for i in 0..n {
        for j in i + 1..n {
            let da = a[i].total_cmp(&a[j]);
            let db = b[i].total_cmp(&b[j]);
            match (da.is_eq(), db.is_eq()) {
                (true, true) => {
                    tied_a += 1;
                    tied_b += 1;
                }
                (true, false) => tied_a += 1,
                (false, true) => tied_b += 1,
                (false, false) if da == db => concordant += 1,
                (false, false) => discordant += 1,
            }
        }
    }
    let pairs = (n * (n - 1) / 2) as i64;
    let denominator = (((pairs - tied_a) * (pairs - tied_b)) as f64).sqrt();
    (denominator > 0.0).then(|| ((concordant - discordant) as f64 / denominator).clamp(-1.0, 1.0))
}

/// Resamples [`bootstrap_mean_interval`] draws.
pub const BOOTSTRAP_RESAMPLES: usize = 10_000;

/// Seed of the bootstrap's random stream: fixed, so the same values always give the same
/// interval.
pub const BOOTSTRAP_SEED: u64 = 0x5eed_b007;

/// The percentile bootstrap interval of the mean of `values` at `level` (0.95 for 95 %):
/// `resamples` means of `values.len()` draws with replacement (ChaCha8 seeded with `seed`),
/// then their (1 − level)/2 and (1 + level)/2 quantiles ([`quantile`]). `None` when `values`
/// is empty or holds a value that is not finite. Deterministic for a given `seed`.
pub fn bootstrap_mean_interval(
    values: &[f64],
    level: f64,
    resamples: usize,
    seed: u64,
) -> Option<(f64, f64)> {
    use rand::{Rng as _, SeedableRng as _};
    if values.is_empty() || values.iter().any(|v| !v.is_finite()) || resamples == 0 {
        return None;
    }
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
    let n = values.len();
    let means: Vec<f64> = (0..resamples)
        .map(|_| (0..n).map(|_| values[rng.random_range(0..n)]).sum::<f64>() / n as f64)
        .collect();
    let tail = (1.0 - level.clamp(0.0, 1.0)) / 2.0;
    Some((quantile(&means, tail)?, quantile(&means, 1.0 - tail)?))
}

#[cfg(test)]
mod tests {
    use super::*;

    /// x = 1..5, y = [3, 1, 2, 5, 4]: of the 10 pairs, (1,2), (1,3) and (4,5) are discordant,
    /// the other 7 concordant: τ = (7 − 3)/10 = 0.4 (scipy.stats.kendalltau gives 0.4). With
    /// a tie, x = 1..4, y = [1, 2, 2, 3]: 5 concordant, one pair tied in y: τ-b = 5/√(6·5).
    #[test]
    fn kendall_tau_matches_hand_computed_examples() {
        let x = [1.0, 2.0, 3.0, 4.0, 5.0];
        let tau = kendall_tau(&x, &[3.0, 1.0, 2.0, 5.0, 4.0]).unwrap();
        assert!((tau - 0.4).abs() < 1e-15, "{tau}");
        let tied = kendall_tau(&[1.0, 2.0, 3.0, 4.0], &[1.0, 2.0, 2.0, 3.0]).unwrap();
        assert!((tied - 5.0 / 30f64.sqrt()).abs() < 1e-15, "{tied}");
        let reversed: Vec<f64> = x.iter().map(|v| -v).collect();
        assert_eq!(kendall_tau(&x, &reversed), Some(-1.0));
        assert_eq!(kendall_tau(&x, &[1.0; 5]), None);
        assert_eq!(kendall_tau(&[1.0], &[2.0]), None);
        assert_eq!(kendall_tau(&x, &x[..4]), None);
    }

    #[test]
    fn ranks_average_ties() {
        assert_eq!(ranks(&[10.0, 20.0, 20.0, 30.0]), [1.0, 2.5, 2.5, 4.0]);
        assert_eq!(ranks(&[3.0, 1.0, 2.0]), [3.0, 1.0, 2.0]);
        assert_eq!(ranks(&[5.0, 5.0, 5.0]), [2.0, 2.0, 2.0]);
        assert!(ranks(&[]).is_empty());
    }

    /// x = 1..5, y = [5, 6, 7, 8, 7]: y ranks [1, 2, 3.5, 5, 3.5]; with deviations
    /// dx = [−2, −1, 0, 1, 2], dy = [−2, −1, 0.5, 2, 0.5]: Σdxdy = 8, Σdx² = 10, Σdy² = 9.5,
    /// ρ = 8/√95 (scipy.stats.spearmanr gives 0.8207826816681233).
    #[test]
    fn spearman_matches_a_hand_computed_example() {
        let x = [1.0, 2.0, 3.0, 4.0, 5.0];
        let y = [5.0, 6.0, 7.0, 8.0, 7.0];
        let rho = spearman(&x, &y).unwrap();
        assert!((rho - 8.0 / 95f64.sqrt()).abs() < 1e-15, "{rho}");
        assert!((rho - 0.8207826816681233).abs() < 1e-15);
    }

    /// A strictly monotone transform leaves the ranks, so ρ = ±1 exactly (Pearson would not).
    #[test]
    fn spearman_is_one_under_a_monotone_transform() {
        let x: Vec<f64> = (0..50)
            .map(|i| (i as f64 * 0.37).sin() * 3.0 + i as f64 * 0.01)
            .collect();
        let up: Vec<f64> = x.iter().map(|v| v.exp() * 7.0 + 2.0).collect();
        let down: Vec<f64> = x.iter().map(|v| -v.powi(3)).collect();
        assert_eq!(spearman(&x, &up), Some(1.0));
        assert_eq!(spearman(&x, &down), Some(-1.0));
        assert!(pearson(&x, &up).unwrap() < 0.99);
    }

    #[test]
    fn degenerate_inputs_give_none() {
        assert_eq!(spearman(&[1.0, 2.0], &[3.0]), None);
        assert_eq!(spearman(&[1.0], &[3.0]), None);
        assert_eq!(spearman(&[1.0, 2.0, 3.0], &[4.0, 4.0, 4.0]), None);
        assert_eq!(spearman(&[1.0, f64::NAN, 3.0], &[1.0, 2.0, 3.0]), None);
        assert_eq!(spearman(&[1.0, f64::INFINITY], &[1.0, 2.0]), None);
    }

    #[test]
    fn quantiles_interpolate_like_numpy() {
        let v = [4.0, 1.0, 3.0, 2.0];
        assert_eq!(median(&v), Some(2.5));
        assert_eq!(quantile(&v, 0.0), Some(1.0));
        assert_eq!(quantile(&v, 1.0), Some(4.0));
        // numpy.quantile([1, 2, 3, 4], 0.25) = 1.75
        assert_eq!(quantile(&v, 0.25), Some(1.75));
        assert_eq!(median(&[7.0]), Some(7.0));
        assert_eq!(median(&[]), None);
    }

    /// Two values {0, 1}: the resampled means are 0, 0.5 and 1 with chances ¼, ½, ¼, so the
    /// 2.5 % and 97.5 % quantiles of 10 000 of them are 0 and 1; the same call gives the same
    /// interval, and a constant sample gives a point.
    #[test]
    fn bootstrap_interval_matches_the_exact_distribution_and_repeats() {
        let ci = |v: &[f64]| bootstrap_mean_interval(v, 0.95, BOOTSTRAP_RESAMPLES, BOOTSTRAP_SEED);
        assert_eq!(ci(&[0.0, 1.0]), Some((0.0, 1.0)));
        assert_eq!(ci(&[2.5, 2.5, 2.5]), Some((2.5, 2.5)));
        let v = [1.0, -1.0, 1.0, 3.0, 0.5, 2.0, -0.5];
        let (lo, hi) = ci(&v).unwrap();
        let mean = v.iter().sum::<f64>() / v.len() as f64;
        assert!(lo < mean && mean < hi, "{lo} {mean} {hi}");
        assert!(
            lo > -1.0 && hi < 3.0,
            "inside the sample's range: {lo} {hi}"
        );
        assert_eq!(ci(&v), Some((lo, hi)), "deterministic");
        assert_eq!(ci(&[]), None);
        assert_eq!(ci(&[1.0, f64::INFINITY]), None);
    }
}
