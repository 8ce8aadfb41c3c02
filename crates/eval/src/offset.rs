//! Surface offset of a Gaussian map (issue 33): where the Gaussian centres sit relative to the
//! ground-truth surface, signed.
//!
//! For each centre `c` the nearest ground-truth surface sample `s` (a k-d tree over samples drawn
//! on the mesh, e.g. by `activemap_sim::ground_truth::oriented_surface_samples`) gives the
//! signed distance `d = (c − s)·n` along that sample's unit normal `n`, the normal oriented
//! towards the side the cameras see ([`orient_towards`]): `d > 0` in front of the surface,
//! `d < 0` behind it. Projecting on the normal makes `d` exact for a planar surface however
//! sparse the samples are along it; only within a sample spacing of an edge can the nearest
//! sample lie on the neighbouring surface. Each centre weighs as its opacity. Reported
//! ([`SurfaceOffsets`]): the weighted median of `d`, the weighted 90th percentile of `|d|` and
//! the weighted share of centres with `|d| ≤` [`ON_SURFACE_M`], over all centres and over the
//! centres whose nearest sample is on the floor ([`crate::SurfaceClass::Floor`]).

use crate::completeness::SurfaceClass;
use crate::error::EvalError;
use kiddo::{ImmutableKdTree, SquaredEuclidean};
use nalgebra::{Point3, Vector3};
use rayon::prelude::*;

/// A centre this close to the surface (|d|, metres) counts as on it (2 cm).
pub const ON_SURFACE_M: f64 = 0.02;

/// Signed offsets of one set of centres (see the module doc), centimetres.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct OffsetStats {
    /// Weighted median of the signed distance `d` (positive in front of the surface), cm.
    pub median_cm: f64,
    /// Weighted 90th percentile of `|d|`, cm.
    pub p90_abs_cm: f64,
    /// Weighted share of centres with `|d| ≤` [`ON_SURFACE_M`], in [0, 1].
    pub within_2cm: f64,
    /// Centres counted (weight > 0).
    pub count: usize,
}

/// [`OffsetStats`] over all centres and over the floor's.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SurfaceOffsets {
    /// Over every centre of positive weight.
    pub all: OffsetStats,
    /// Over the centres whose nearest sample lies on the floor; `None` if there is none.
    pub floor: Option<OffsetStats>,
}

/// Flips each unit normal to point towards the nearest of `viewpoints` (e.g. the camera
/// centres of the trajectory), so that "in front" is the side the cameras see; normals are left
/// as they are without viewpoints. Scene files do not keep their winding consistent, hence this.
pub fn orient_towards(
    points: &[Point3<f64>],
    normals: &mut [Vector3<f64>],
    viewpoints: &[Point3<f64>],
) {
    if viewpoints.is_empty() {
        return;
    }
    let sites: Vec<[f64; 3]> = viewpoints.iter().map(|p| [p.x, p.y, p.z]).collect();
    let tree: ImmutableKdTree<f64, 3> = ImmutableKdTree::new_from_slice(&sites);
    points
        .par_iter()
        .zip(normals.par_iter_mut())
        .for_each(|(p, n)| {
            let nearest = tree.nearest_one::<SquaredEuclidean>(&[p.x, p.y, p.z]);
            let v = &viewpoints[nearest.item as usize];
            if (v - p).dot(n) < 0.0 {
                *n = -*n;
            }
        });
}

/// The weighted `q`-quantile of `values` (sorted by value, the first whose cumulative weight
/// reaches `q` of the total); `pairs` holds (value, weight > 0).
fn weighted_quantile(pairs: &mut [(f64, f64)], q: f64) -> f64 {
    pairs.sort_by(|a, b| a.0.total_cmp(&b.0));
    let total: f64 = pairs.iter().map(|p| p.1).sum();
    let mut cumulative = 0.0;
    for &(v, w) in pairs.iter() {
        cumulative += w;
        if cumulative >= q * total {
            return v;
        }
    }
    pairs.last().map_or(f64::NAN, |p| p.0)
}

fn stats(signed: &[(f64, f64)]) -> Option<OffsetStats> {
    if signed.is_empty() {
        return None;
    }
    let total: f64 = signed.iter().map(|p| p.1).sum();
    let near: f64 = signed
        .iter()
        .filter(|p| p.0.abs() <= ON_SURFACE_M)
        .map(|p| p.1)
        .sum();
    let mut sorted = signed.to_vec();
    let median = weighted_quantile(&mut sorted, 0.5);
    let mut abs: Vec<(f64, f64)> = signed.iter().map(|&(d, w)| (d.abs(), w)).collect();
    let p90 = weighted_quantile(&mut abs, 0.9);
    Some(OffsetStats {
        median_cm: median * 100.0,
        p90_abs_cm: p90 * 100.0,
        within_2cm: near / total,
        count: signed.len(),
    })
}

/// The surface offsets (module doc) of `centres` weighted by `weights` (opacities; centres of
/// weight ≤ 0 are left out) against ground-truth `samples` with unit `normals` already oriented
/// ([`orient_towards`]); a sample is floor as [`SurfaceClass::of`] with `floor_z` and
/// `ceiling_z` says. Fails on mismatched lengths, non-finite input or nothing to measure.
pub fn surface_offsets(
    centres: &[Point3<f64>],
    weights: &[f64],
    samples: &[Point3<f64>],
    normals: &[Vector3<f64>],
    floor_z: f64,
    ceiling_z: f64,
) -> Result<SurfaceOffsets, EvalError> {
    let metric = "surface offset";
    if centres.len() != weights.len() || samples.len() != normals.len() {
        return Err(EvalError::SizeMismatch {
            metric,
            detail: format!(
                "{} centres with {} weights, {} samples with {} normals",
                centres.len(),
                weights.len(),
                samples.len(),
                normals.len()
            ),
        });
    }
    let finite = |p: &Point3<f64>| p.coords.iter().all(|v| v.is_finite());
    if let Some(i) = centres.iter().position(|p| !finite(p)) {
        return Err(EvalError::NonFinite {
            metric,
            input: "centres",
            location: format!("centre {i}"),
        });
    }
    if let Some(i) = samples.iter().position(|p| !finite(p)) {
        return Err(EvalError::NonFinite {
            metric,
            input: "samples",
            location: format!("sample {i}"),
        });
    }
    if samples.is_empty() {
        return Err(EvalError::Empty {
            metric,
            detail: "no ground-truth sample".into(),
        });
    }
    let points: Vec<[f64; 3]> = samples.iter().map(|p| [p.x, p.y, p.z]).collect();
    let tree: ImmutableKdTree<f64, 3> = ImmutableKdTree::new_from_slice(&points);
    // (signed distance, weight, nearest sample is floor)
    let measured: Vec<(f64, f64, bool)> = centres
        .par_iter()
        .zip(weights)
        .filter(|(_, w)| **w > 0.0)
        .map(|(c, &w)| {
            let j = tree.nearest_one::<SquaredEuclidean>(&[c.x, c.y, c.z]).item as usize;
            let (s, n) = (&samples[j], &normals[j]);
            let floor = SurfaceClass::of(s, n, floor_z, ceiling_z) == SurfaceClass::Floor;
            ((c - s).dot(n), w, floor)
        })
        .collect();
    let all: Vec<(f64, f64)> = measured.iter().map(|&(d, w, _)| (d, w)).collect();
    let floor: Vec<(f64, f64)> = measured
        .iter()
        .filter(|m| m.2)
        .map(|&(d, w, _)| (d, w))
        .collect();
    let all = stats(&all).ok_or_else(|| EvalError::Empty {
        metric,
        detail: format!(
            "{} centres of positive weight, {} samples",
            all.len(),
            samples.len()
        ),
    })?;
    Ok(SurfaceOffsets {
        all,
        floor: stats(&floor),
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Samples on a grid of the floor z = 0 (10 cm spacing), normals down (the wrong way up).
    fn floor_samples() -> (Vec<Point3<f64>>, Vec<Vector3<f64>>) {
        let mut points = Vec::new();
        for i in 0..21 {
            for j in 0..21 {
                points.push(Point3::new(i as f64 * 0.1, j as f64 * 0.1, 0.0));
            }
        }
        let normals = vec![-Vector3::z(); points.len()];
        (points, normals)
    }

    #[test]
    fn offsets_of_points_at_known_heights_above_and_below_a_plane() {
        let (samples, mut normals) = floor_samples();
        // A camera above the floor: the normals turn up.
        orient_towards(&samples, &mut normals, &[Point3::new(1.0, 1.0, 1.2)]);
        assert!(normals.iter().all(|n| n.z == 1.0));
        // Centres at offsets −3, −1, −1, +0.5, +4 cm, away from the sample grid along the plane.
        let heights = [-0.03, -0.01, -0.01, 0.005, 0.04];
        let centres: Vec<Point3<f64>> = heights
            .iter()
            .enumerate()
            .map(|(k, &z)| Point3::new(0.53 + 0.2 * k as f64, 0.97, z))
            .collect();
        let weights = [1.0, 1.0, 1.0, 1.0, 1.0];
        let m = surface_offsets(&centres, &weights, &samples, &normals, 0.0, 2.5).unwrap();
        assert!((m.all.median_cm - -1.0).abs() < 1e-9, "{m:?}");
        // |d| sorted: 0.5 1 1 3 4: the 90th weighted percentile is the fifth.
        assert!((m.all.p90_abs_cm - 4.0).abs() < 1e-9, "{m:?}");
        assert!((m.all.within_2cm - 0.6).abs() < 1e-12, "{m:?}");
        assert_eq!(m.all.count, 5);
        assert_eq!(m.floor, Some(m.all));
        // Opacity weights move the median; zero weight leaves a centre out.
        let weights = [0.0, 0.1, 0.1, 1.0, 1.0];
        let m = surface_offsets(&centres, &weights, &samples, &normals, 0.0, 2.5).unwrap();
        assert!((m.all.median_cm - 0.5).abs() < 1e-9, "{m:?}");
        assert_eq!(m.all.count, 4);
        // Well above the floor band, the plane is no floor.
        let m = surface_offsets(&centres, &weights, &samples, &normals, -1.0, 2.5).unwrap();
        assert_eq!(m.floor, None);
    }

    #[test]
    fn bad_inputs_are_refused() {
        let (samples, normals) = floor_samples();
        let c = [Point3::new(0.0, 0.0, f64::NAN)];
        assert!(surface_offsets(&c, &[1.0], &samples, &normals, 0.0, 2.5).is_err());
        let c = [Point3::origin()];
        assert!(surface_offsets(&c, &[1.0, 1.0], &samples, &normals, 0.0, 2.5).is_err());
        assert!(surface_offsets(&c, &[0.0], &samples, &normals, 0.0, 2.5).is_err());
        assert!(surface_offsets(&c, &[1.0], &[], &[], 0.0, 2.5).is_err());
    }
}
