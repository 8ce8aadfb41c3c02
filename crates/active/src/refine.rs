//! The refine target (SPEC §6 "No frontier, or LLM says −1", paper appendix): when no
//! frontier is left, aim at the least-known part of the map. The caller scores every Gaussian
//! by `Σ_k 1/(I_k + λ)` (higher = less known); here the top `refine_top_fraction` (20 %) of
//! them are clustered with DBSCAN (`petal-clustering`, ball-tree neighbours; eps 0.5 m, min 20
//! points, on the 3D means) and the chosen cluster's centre becomes the focus of the
//! candidates: the largest cluster (the paper) or the one holding the best-scoring clustered
//! Gaussian (the release).
//!
//! The release also keeps only Gaussians within ±0.8 m of the camera height
//! (`refine_height_band_m`); here that filter applies to the top fraction (the share is taken
//! over the whole map first, then the band is cut out of it).
//!
//! Deterministic: the clustered points keep the map's order, and clusters are ranked by the
//! smallest map index among their points, not by DBSCAN's (hash-map) output order.

use ndarray::Array2;
use petal_clustering::{Dbscan, Fit};
use petal_neighbors::distance::Euclidean;

use crate::ActiveError;
use crate::config::{FisherConfig, RefineCluster};

/// The target of a refine replan (SPEC §6 "No frontier…").
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RefineTarget {
    /// Centre (mean of the cluster's points), world metres.
    pub centre: [f64; 3],
    /// Points in the chosen cluster.
    pub cluster_points: usize,
    /// Clusters found.
    pub clusters: usize,
    /// Gaussians handed to DBSCAN (the top fraction, after the height band).
    pub clustered: usize,
}

/// DBSCAN of the top `refine_top_fraction` of `scores` (higher = less known), see SPEC §6 "No
/// frontier…" and the module doc. `means[i]` and `scores[i]` describe Gaussian `i`;
/// `camera_z` is the camera height for `refine_height_band_m`. The top share is
/// `⌈fraction · n⌉` Gaussians (ties in score broken by the lower index). `Ok(None)` when no
/// cluster is found (e.g. fewer than `dbscan_min_points` points, or only noise).
///
/// Errors: `means` and `scores` of different lengths, a NaN score, or a non-finite mean among
/// the clustered Gaussians.
pub fn refine_target(
    means: &[[f32; 3]],
    scores: &[f64],
    camera_z: f64,
    config: &FisherConfig,
) -> Result<Option<RefineTarget>, ActiveError> {
    if means.len() != scores.len() {
        return Err(ActiveError::Input {
            what: "refine scores",
            reason: format!("{} scores for {} Gaussians", scores.len(), means.len()),
        });
    }
    if let Some(i) = scores.iter().position(|s| s.is_nan()) {
        return Err(ActiveError::Input {
            what: "refine scores",
            reason: format!("score of Gaussian {i} is NaN"),
        });
    }
    let n = means.len();
    if n == 0 {
        return Ok(None);
    }
    let top = ((config.refine_top_fraction * n as f64 - 1e-9).ceil() as usize).clamp(1, n);
    let mut order: Vec<usize> = (0..n).collect();
    order.sort_by(|&a, &b| scores[b].total_cmp(&scores[a]).then(a.cmp(&b)));
    let mut selected = order[..top].to_vec();
    selected.sort_unstable();
    if let Some(band) = config.refine_height_band_m {
        selected.retain(|&i| (means[i][2] as f64 - camera_z).abs() <= band);
    }
    if let Some(&i) = selected
        .iter()
        .find(|&&i| !means[i].iter().all(|v| v.is_finite()))
    {
        return Err(ActiveError::Input {
            what: "refine means",
            reason: format!("mean of Gaussian {i} is not finite: {:?}", means[i]),
        });
    }
    if selected.len() < config.dbscan_min_points {
        return Ok(None);
    }
    let points = Array2::from_shape_fn((selected.len(), 3), |(r, k)| means[selected[r]][k] as f64);
    let (found, _noise) = Dbscan::new(
        config.dbscan_eps_m,
        config.dbscan_min_points,
        Euclidean::default(),
    )
    .fit(&points, None);
    // Each cluster as (smallest row, rows); rows index `selected`, which is in map order.
    let mut clusters: Vec<(usize, Vec<usize>)> = found
        .into_values()
        .filter(|rows| !rows.is_empty())
        .map(|rows| (*rows.iter().min().expect("non-empty"), rows))
        .collect();
    clusters.sort_unstable_by_key(|(first, _)| *first);
    let chosen = match config.refine_cluster {
        // Largest; among equal sizes the one with the earliest point (`max_by` keeps the last
        // maximum, so the earlier first point must compare greater).
        RefineCluster::Largest => clusters
            .iter()
            .enumerate()
            .max_by(|(_, (fa, ra)), (_, (fb, rb))| ra.len().cmp(&rb.len()).then(fb.cmp(fa)))
            .map(|(i, _)| i),
        // The cluster holding the best-scoring clustered point (ties: the lower map index).
        RefineCluster::Best => {
            let selected = &selected;
            clusters
                .iter()
                .enumerate()
                .flat_map(|(c, (_, rows))| rows.iter().map(move |&r| (c, selected[r])))
                .max_by(|(_, a), (_, b)| scores[*a].total_cmp(&scores[*b]).then(b.cmp(a)))
                .map(|(c, _)| c)
        }
    };
    let Some(c) = chosen else {
        return Ok(None);
    };
    let rows = &clusters[c].1;
    let mut centre = [0.0; 3];
    for &r in rows {
        for k in 0..3 {
            centre[k] += points[[r, k]];
        }
    }
    let centre = centre.map(|v| v / rows.len() as f64);
    Ok(Some(RefineTarget {
        centre,
        cluster_points: rows.len(),
        clusters: clusters.len(),
        clustered: selected.len(),
    }))
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::seq::SliceRandom;
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;

    /// One synthetic Gaussian: mean and score.
    type Point = ([f32; 3], f64);

    /// `count` points uniform in the 0.3 m cube around `centre`, scores uniform in `score`.
    fn blob(rng: &mut ChaCha8Rng, centre: [f64; 3], count: usize, score: [f64; 2]) -> Vec<Point> {
        (0..count)
            .map(|_| {
                let m = centre.map(|c| (c + rng.random_range(-0.15..0.15)) as f32);
                (m, rng.random_range(score[0]..score[1]))
            })
            .collect()
    }

    /// `count` points uniform in [0, 6] × [0, 6] × [0, 3] m, scores uniform in `score`.
    fn uniform(rng: &mut ChaCha8Rng, count: usize, score: [f64; 2]) -> Vec<Point> {
        (0..count)
            .map(|_| {
                let m = [6.0, 6.0, 3.0].map(|s: f64| (s * rng.random::<f64>()) as f32);
                (m, rng.random_range(score[0]..score[1]))
            })
            .collect()
    }

    const A: [f64; 3] = [1.0, 1.0, 0.5];
    const B: [f64; 3] = [4.5, 1.0, 0.6];
    const C: [f64; 3] = [2.5, 4.5, 2.5];

    /// Three clusters with their exact sample centres: A (200 points, scores 2–3) and B (120,
    /// scores 5–6, the best) at camera height, C (300, scores 3–4, the largest) 2 m above;
    /// 80 sparse high-score noise points (≈0.4 neighbours within 0.5 m each: never core, though
    /// one may join a cluster as a border point) and
    /// 2800 well-known background Gaussians. 3500 in all, so the top 20 % is exactly the 700
    /// cluster and noise points. Shuffled (seeded) so no test depends on the input order.
    fn scene() -> (Vec<[f32; 3]>, Vec<f64>, [[f64; 3]; 3]) {
        let mut rng = ChaCha8Rng::seed_from_u64(42);
        let a = blob(&mut rng, A, 200, [2.0, 3.0]);
        let b = blob(&mut rng, B, 120, [5.0, 6.0]);
        let c = blob(&mut rng, C, 300, [3.0, 4.0]);
        let centre = |v: &[Point]| {
            let mut s = [0.0; 3];
            for (m, _) in v {
                for k in 0..3 {
                    s[k] += m[k] as f64 / v.len() as f64;
                }
            }
            s
        };
        let centres = [centre(&a), centre(&b), centre(&c)];
        let mut all: Vec<Point> = [a, b, c].concat();
        all.extend(uniform(&mut rng, 80, [1.5, 2.0]));
        all.extend(uniform(&mut rng, 2800, [0.0, 1.0]));
        all.shuffle(&mut rng);
        let (means, scores) = all.into_iter().unzip();
        (means, scores, centres)
    }

    fn close(a: [f64; 3], b: [f64; 3], tol: f64) -> bool {
        a.iter().zip(&b).all(|(x, y)| (x - y).abs() < tol)
    }

    #[test]
    fn the_largest_cluster_is_found_at_its_centre() {
        let (means, scores, centres) = scene();
        let config = FisherConfig::default();
        let t = refine_target(&means, &scores, 0.5, &config)
            .unwrap()
            .unwrap();
        assert_eq!(t.clustered, 700);
        assert_eq!(t.clusters, 3);
        // C, the largest; a stray noise point joining as a border point moves it by < 1 cm.
        assert!((300..=308).contains(&t.cluster_points), "{t:?}");
        assert!(
            close(t.centre, centres[2], 0.02),
            "{t:?} vs {:?}",
            centres[2]
        );
        assert!(close(t.centre, C, 0.03), "{t:?}");
    }

    #[test]
    fn best_takes_the_cluster_holding_the_top_score() {
        let (means, scores, centres) = scene();
        let config = FisherConfig {
            refine_cluster: RefineCluster::Best,
            ..FisherConfig::default()
        };
        let t = refine_target(&means, &scores, 0.5, &config)
            .unwrap()
            .unwrap();
        assert_eq!(t.clusters, 3);
        assert!((120..=128).contains(&t.cluster_points), "{t:?}");
        assert!(
            close(t.centre, centres[1], 0.02),
            "{t:?} vs {:?}",
            centres[1]
        );
        // The top-scoring Gaussian itself lies in it.
        let best = (0..scores.len())
            .max_by(|&a, &b| scores[a].total_cmp(&scores[b]))
            .unwrap();
        let m = means[best].map(|v| v as f64);
        assert!(close(m, B, 0.6), "best point {m:?}");
    }

    #[test]
    fn the_height_band_drops_a_cluster_outside_it() {
        let (means, scores, centres) = scene();
        let config = FisherConfig {
            refine_height_band_m: Some(0.8),
            ..FisherConfig::default()
        };
        // C (z = 2.5) is 2 m above the camera: gone; the largest left is A.
        let t = refine_target(&means, &scores, 0.5, &config)
            .unwrap()
            .unwrap();
        assert_eq!(t.clusters, 2);
        assert!(t.clustered <= 400, "{t:?}");
        assert!((200..=208).contains(&t.cluster_points), "{t:?}");
        assert!(
            close(t.centre, centres[0], 0.02),
            "{t:?} vs {:?}",
            centres[0]
        );
        // With the camera up at C's height, only C remains.
        let up = refine_target(&means, &scores, 2.5, &config)
            .unwrap()
            .unwrap();
        assert_eq!(up.clusters, 1);
        assert!(close(up.centre, centres[2], 0.02), "{up:?}");
    }

    #[test]
    fn too_few_points_or_only_noise_give_no_target() {
        let config = FisherConfig {
            refine_top_fraction: 1.0,
            ..FisherConfig::default()
        };
        let mut rng = ChaCha8Rng::seed_from_u64(1);
        // 19 points in a tight blob: one short of the 20 DBSCAN needs.
        let (means, scores): (Vec<_>, Vec<_>) =
            blob(&mut rng, A, 19, [1.0, 2.0]).into_iter().unzip();
        assert_eq!(refine_target(&means, &scores, 0.5, &config).unwrap(), None);
        // 20 do form a cluster.
        let (means, scores): (Vec<_>, Vec<_>) =
            blob(&mut rng, A, 20, [1.0, 2.0]).into_iter().unzip();
        let t = refine_target(&means, &scores, 0.5, &config)
            .unwrap()
            .unwrap();
        assert_eq!((t.clusters, t.cluster_points), (1, 20));
        // Sparse noise only: no cluster.
        let (means, scores): (Vec<_>, Vec<_>) =
            uniform(&mut rng, 80, [1.0, 2.0]).into_iter().unzip();
        assert_eq!(refine_target(&means, &scores, 0.5, &config).unwrap(), None);
        assert_eq!(refine_target(&[], &[], 0.5, &config).unwrap(), None);
    }

    #[test]
    fn equal_clusters_are_chosen_by_their_first_point_every_time() {
        let config = FisherConfig {
            refine_top_fraction: 1.0,
            ..FisherConfig::default()
        };
        let mut rng = ChaCha8Rng::seed_from_u64(8);
        let a = blob(&mut rng, A, 50, [1.0, 2.0]);
        let b = blob(&mut rng, B, 50, [1.0, 2.0]);
        for (first, expected) in [([a.clone(), b.clone()].concat(), A), ([b, a].concat(), B)] {
            let (means, scores): (Vec<_>, Vec<_>) = first.into_iter().unzip();
            // DBSCAN hands its clusters back in a hash map: repeat to catch any order leak.
            for _ in 0..8 {
                let t = refine_target(&means, &scores, 0.5, &config)
                    .unwrap()
                    .unwrap();
                assert_eq!((t.clusters, t.cluster_points), (2, 50));
                assert!(close(t.centre, expected, 0.05), "{t:?} vs {expected:?}");
            }
        }
    }

    #[test]
    fn bad_inputs_are_refused_by_name() {
        let config = FisherConfig::default();
        let e = refine_target(&[[0.0; 3]; 2], &[1.0], 0.5, &config).unwrap_err();
        assert!(e.to_string().contains("1 scores for 2 Gaussians"), "{e}");
        let e = refine_target(&[[0.0; 3]; 2], &[1.0, f64::NAN], 0.5, &config).unwrap_err();
        assert!(e.to_string().contains("Gaussian 1 is NaN"), "{e}");
        let e = refine_target(&[[f32::NAN, 0.0, 0.0]], &[1.0], 0.5, &config).unwrap_err();
        assert!(e.to_string().contains("not finite"), "{e}");
    }
}
