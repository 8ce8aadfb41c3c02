//! Completeness (SPEC §8, Active-Neural-Mapping style): sample the ground-truth mesh surface;
//! a sample is complete once some observed point lies within the threshold (5 cm); report the
//! complete fraction. Neighbour search uses a uniform grid hash with cells as wide as the
//! threshold, so only the 27 cells around a sample can hold a point close enough.

use crate::error::EvalError;
use nalgebra::{Point3, Vector3};
use rand::Rng;
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use rayon::prelude::*;
use rustc_hash::FxHashMap;
use serde::{Deserialize, Serialize};

/// The completeness threshold of SPEC §8, metres.
pub const COMPLETENESS_THRESHOLD_M: f64 = 0.05;

/// Cell key → points in that cell.
/// FxHash (`rustc-hash`): the keys come from our own points, so hash flooding is no concern.
type Buckets = FxHashMap<[i64; 3], Vec<Point3<f64>>>;

/// Observed points bucketed by grid cell for fixed-radius queries.
pub struct PointGrid {
    cell: f64,
    buckets: Buckets,
}

impl PointGrid {
    /// Buckets `points` into cubic cells of side `radius`; queries then find points within `radius`.
    pub fn new(points: &[Point3<f64>], radius: f64) -> Result<Self, EvalError> {
        if !(radius.is_finite() && radius > 0.0) {
            return Err(EvalError::InvalidParameter {
                metric: "completeness",
                detail: format!("threshold must be finite and positive, got {radius}"),
            });
        }
        check_points("observed", points)?;
        let mut buckets = Buckets::default();
        for p in points {
            buckets.entry(cell_of(p, radius)).or_default().push(*p);
        }
        Ok(Self {
            cell: radius,
            buckets,
        })
    }

    /// True when some bucketed point lies within the grid's radius of `query` (inclusive).
    pub fn has_neighbour(&self, query: &Point3<f64>) -> bool {
        let c = cell_of(query, self.cell);
        let r2 = self.cell * self.cell;
        for dx in -1..=1 {
            for dy in -1..=1 {
                for dz in -1..=1 {
                    if let Some(bucket) = self.buckets.get(&[c[0] + dx, c[1] + dy, c[2] + dz])
                        && bucket.iter().any(|p| (p - query).norm_squared() <= r2)
                    {
                        return true;
                    }
                }
            }
        }
        false
    }
}

/// Integer grid cell holding `p` for cells of side `cell`.
fn cell_of(p: &Point3<f64>, cell: f64) -> [i64; 3] {
    [
        (p.x / cell).floor() as i64,
        (p.y / cell).floor() as i64,
        (p.z / cell).floor() as i64,
    ]
}

/// Fails with the first non-finite point of `input`.
fn check_points(input: &'static str, points: &[Point3<f64>]) -> Result<(), EvalError> {
    match points
        .iter()
        .position(|p| !p.coords.iter().all(|v| v.is_finite()))
    {
        None => Ok(()),
        Some(i) => Err(EvalError::NonFinite {
            metric: "completeness",
            input,
            location: format!("point {i}"),
        }),
    }
}

/// Fraction of `truth_samples` with an `observed` point within `threshold` metres (inclusive).
/// No observed point gives 0.
pub fn completeness(
    truth_samples: &[Point3<f64>],
    observed: &[Point3<f64>],
    threshold: f64,
) -> Result<f64, EvalError> {
    Ok(complete_fraction(&complete_samples(
        truth_samples,
        observed,
        threshold,
    )?))
}

/// The fraction of true flags of [`complete_samples`]: the completeness (0 for no sample).
pub fn complete_fraction(complete: &[bool]) -> f64 {
    if complete.is_empty() {
        return 0.0;
    }
    complete.iter().filter(|&&c| c).count() as f64 / complete.len() as f64
}

/// Per sample of `truth_samples`: whether an `observed` point lies within `threshold` metres
/// (inclusive). The flags behind [`completeness`] and [`completeness_by_surface`].
pub fn complete_samples(
    truth_samples: &[Point3<f64>],
    observed: &[Point3<f64>],
    threshold: f64,
) -> Result<Vec<bool>, EvalError> {
    if truth_samples.is_empty() {
        return Err(EvalError::Empty {
            metric: "completeness",
            detail: "no ground-truth sample point".into(),
        });
    }
    check_points("truth", truth_samples)?;
    let grid = PointGrid::new(observed, threshold)?;
    Ok(truth_samples
        .par_iter()
        .map(|p| grid.has_neighbour(p))
        .collect())
}

/// The kind of surface a ground-truth sample lies on, for the completeness breakdown: where in
/// the scene the unobserved surface is (a ground robot's camera sees the floor and the lower
/// walls easily, the upper walls and the ceiling only from a distance).
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum SurfaceClass {
    /// Horizontal (normal within 45° of vertical) and within [`FLOOR_BAND_M`] of the floor.
    Floor,
    /// Steeper than 45°, lower than 1 m above the floor (by the sample's height).
    WallBelow1m,
    /// Steeper than 45°, 1–2 m above the floor.
    Wall1To2m,
    /// Steeper than 45°, 2 m or more above the floor.
    WallAbove2m,
    /// Horizontal, neither floor nor ceiling: furniture tops and undersides, shelves, sills.
    OtherHorizontal,
    /// Horizontal and within [`FLOOR_BAND_M`] of the scene's top (the ceiling).
    Ceiling,
}

/// How close to the floor (or to the scene's top) a horizontal sample counts as floor (ceiling),
/// metres.
pub const FLOOR_BAND_M: f64 = 0.15;

impl SurfaceClass {
    /// Every class, in the order the breakdown lists them.
    pub const ALL: [SurfaceClass; 6] = [
        SurfaceClass::Floor,
        SurfaceClass::WallBelow1m,
        SurfaceClass::Wall1To2m,
        SurfaceClass::WallAbove2m,
        SurfaceClass::OtherHorizontal,
        SurfaceClass::Ceiling,
    ];

    /// The class of a sample at `point` with unit `normal` (either sign) in a scene whose floor
    /// is at height `floor_z` and whose top is at `ceiling_z` (z up, metres).
    pub fn of(point: &Point3<f64>, normal: &Vector3<f64>, floor_z: f64, ceiling_z: f64) -> Self {
        let height = point.z - floor_z;
        let horizontal = normal.z.abs() >= std::f64::consts::FRAC_1_SQRT_2;
        if horizontal {
            if height <= FLOOR_BAND_M {
                SurfaceClass::Floor
            } else if point.z >= ceiling_z - FLOOR_BAND_M {
                SurfaceClass::Ceiling
            } else {
                SurfaceClass::OtherHorizontal
            }
        } else if height < 1.0 {
            SurfaceClass::WallBelow1m
        } else if height < 2.0 {
            SurfaceClass::Wall1To2m
        } else {
            SurfaceClass::WallAbove2m
        }
    }

    /// Words for tables.
    pub fn label(self) -> &'static str {
        match self {
            SurfaceClass::Floor => "floor",
            SurfaceClass::WallBelow1m => "walls < 1 m",
            SurfaceClass::Wall1To2m => "walls 1–2 m",
            SurfaceClass::WallAbove2m => "walls ≥ 2 m",
            SurfaceClass::OtherHorizontal => "other horizontal",
            SurfaceClass::Ceiling => "ceiling",
        }
    }
}

/// Completeness of one kind of surface.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct SurfaceCompleteness {
    /// The kind of surface.
    pub surface: SurfaceClass,
    /// Fraction of all ground-truth samples on this kind of surface (its share of the mesh area).
    pub share: f64,
    /// Fraction of this kind's observable samples that are complete; `None` when it has no
    /// observable sample.
    pub completeness: Option<f64>,
    /// Fraction of this kind's samples that a camera pose of the robot can see
    /// ([`crate::observable`]); `None` when it has no sample (absent in older files).
    #[serde(default)]
    pub observable: Option<f64>,
}

/// Completeness broken down by [`SurfaceClass`]: each class's share of the mesh area and its
/// own completeness over its observable samples and the share of them that is observable,
/// every class listed (in [`SurfaceClass::ALL`] order). `normals`, `complete` (e.g. from
/// [`complete_samples`]) and `observable` pair with `truth_samples`; `floor_z` and `ceiling_z`
/// as in [`SurfaceClass::of`].
pub fn completeness_by_surface(
    truth_samples: &[Point3<f64>],
    normals: &[Vector3<f64>],
    complete: &[bool],
    observable: &[bool],
    floor_z: f64,
    ceiling_z: f64,
) -> Result<Vec<SurfaceCompleteness>, EvalError> {
    let n = truth_samples.len();
    if normals.len() != n || complete.len() != n || observable.len() != n {
        return Err(EvalError::SizeMismatch {
            metric: "completeness",
            detail: format!(
                "{} normals, {} completeness flags and {} observability flags for {n} \
                 ground-truth samples",
                normals.len(),
                complete.len(),
                observable.len(),
            ),
        });
    }
    if truth_samples.is_empty() {
        return Err(EvalError::Empty {
            metric: "completeness",
            detail: "no ground-truth sample point".into(),
        });
    }
    // Per class: samples, observable samples, complete observable samples.
    let mut counts = [(0usize, 0usize, 0usize); SurfaceClass::ALL.len()];
    for (((p, n), done), seen) in truth_samples
        .iter()
        .zip(normals)
        .zip(complete)
        .zip(observable)
    {
        let class = SurfaceClass::of(p, n, floor_z, ceiling_z);
        let slot = &mut counts[class as usize];
        slot.0 += 1;
        slot.1 += usize::from(*seen);
        slot.2 += usize::from(*seen && *done);
    }
    let total = n as f64;
    Ok(SurfaceClass::ALL
        .iter()
        .zip(counts)
        .map(|(&surface, (samples, seen, done))| SurfaceCompleteness {
            surface,
            share: samples as f64 / total,
            completeness: (seen > 0).then(|| done as f64 / seen as f64),
            observable: (samples > 0).then(|| seen as f64 / samples as f64),
        })
        .collect())
}

/// Draws `count` points uniformly on the surface of a triangle mesh (area-weighted triangle
/// choice, uniform barycentric point), seeded for determinism. Degenerate triangles are never
/// chosen.
pub fn sample_mesh_surface(
    vertices: &[Point3<f64>],
    triangles: &[[u32; 3]],
    count: usize,
    seed: u64,
) -> Result<Vec<Point3<f64>>, EvalError> {
    let metric = "mesh sampling";
    if let Some(i) = vertices
        .iter()
        .position(|p| !p.coords.iter().all(|v| v.is_finite()))
    {
        return Err(EvalError::NonFinite {
            metric,
            input: "vertices",
            location: format!("vertex {i}"),
        });
    }
    let mut cumulative = Vec::with_capacity(triangles.len());
    let mut total = 0.0;
    for (t, tri) in triangles.iter().enumerate() {
        if let Some(&bad) = tri.iter().find(|&&v| v as usize >= vertices.len()) {
            return Err(EvalError::InvalidParameter {
                metric,
                detail: format!(
                    "triangle {t} uses vertex {bad}, but there are {} vertices",
                    vertices.len()
                ),
            });
        }
        let [a, b, c] = tri.map(|v| vertices[v as usize]);
        total += 0.5 * (b - a).cross(&(c - a)).norm();
        cumulative.push(total);
    }
    if total <= 0.0 || !total.is_finite() {
        return Err(EvalError::Empty {
            metric,
            detail: format!(
                "the {} triangles have zero (or non-finite) total area",
                triangles.len()
            ),
        });
    }
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let samples = (0..count)
        .map(|_| {
            let pick = rng.random::<f64>() * total;
            // first triangle whose cumulative area exceeds `pick`: zero-area ones never qualify
            let t = cumulative
                .partition_point(|&c| c <= pick)
                .min(triangles.len() - 1);
            let [a, b, c] = triangles[t].map(|v| vertices[v as usize]);
            let (mut u, mut v): (f64, f64) = (rng.random(), rng.random());
            if u + v > 1.0 {
                (u, v) = (1.0 - u, 1.0 - v);
            }
            a + (b - a) * u + (c - a) * v
        })
        .collect();
    Ok(samples)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn exact_on_a_synthetic_point_set() {
        // Samples on a line every 1 cm from x = 0 to 0.99; one observed point at x = 0.505, 3 cm
        // off the line. Within 5 cm ⇔ dx² + 0.03² ≤ 0.05² ⇔ |dx| ≤ 0.04 → x in [0.465, 0.545]:
        // the 8 samples 0.47..=0.54 of 100 (no sample sits on the boundary).
        let truth: Vec<Point3<f64>> = (0..100)
            .map(|i| Point3::new(f64::from(i) * 0.01, 0.0, 0.0))
            .collect();
        let observed = [Point3::new(0.505, 0.03, 0.0)];
        let c = completeness(&truth, &observed, 0.05).unwrap();
        assert!((c - 0.08).abs() < 1e-12, "{c}");
        assert_eq!(completeness(&truth, &[], 0.05).unwrap(), 0.0);
        assert_eq!(completeness(&truth, &truth, 0.05).unwrap(), 1.0);
    }

    /// A 4 m × 4 m room 2.5 m high, sampled on a 5 cm lattice (cell centres): the shares are the
    /// surfaces' areas over the 72 m² total, and a map that holds only the floor and the walls'
    /// lowest metre completes exactly those classes. Either normal sign classifies alike.
    #[test]
    fn completeness_by_surface_in_a_box_room() {
        let (side, height, step) = (4.0, 2.5, 0.05);
        let cells = |length: f64| {
            (0..(length / step).round() as usize).map(move |i| (i as f64 + 0.5) * step)
        };
        let mut samples = Vec::new();
        let mut normals: Vec<Vector3<f64>> = Vec::new();
        for x in cells(side) {
            for y in cells(side) {
                samples.push(Point3::new(x, y, 0.0));
                normals.push(Vector3::z());
                samples.push(Point3::new(x, y, height));
                normals.push(-Vector3::z());
            }
        }
        for u in cells(side) {
            for z in cells(height) {
                for (p, n) in [
                    (Point3::new(u, 0.0, z), Vector3::y()),
                    (Point3::new(u, side, z), -Vector3::y()),
                    (Point3::new(0.0, u, z), Vector3::x()),
                    (Point3::new(side, u, z), -Vector3::x()),
                ] {
                    samples.push(p);
                    normals.push(n);
                }
            }
        }
        // A 3 cm threshold under the 5 cm lattice: each sample is complete by itself alone.
        let observed: Vec<Point3<f64>> = samples.iter().filter(|p| p.z < 1.0).copied().collect();
        let complete = complete_samples(&samples, &observed, 0.03).unwrap();
        let all = vec![true; samples.len()];
        let rows =
            completeness_by_surface(&samples, &normals, &complete, &all, 0.0, height).unwrap();
        let expected = [
            (SurfaceClass::Floor, 16.0, Some(1.0)),
            (SurfaceClass::WallBelow1m, 16.0, Some(1.0)),
            (SurfaceClass::Wall1To2m, 16.0, Some(0.0)),
            (SurfaceClass::WallAbove2m, 8.0, Some(0.0)),
            (SurfaceClass::OtherHorizontal, 0.0, None),
            (SurfaceClass::Ceiling, 16.0, Some(0.0)),
        ];
        assert_eq!(rows.len(), expected.len());
        for (row, (class, area, done)) in rows.iter().zip(expected) {
            assert_eq!(row.surface, class);
            assert!((row.share - area / 72.0).abs() < 1e-12, "{row:?}");
            assert_eq!(row.completeness, done, "{row:?}");
            assert_eq!(row.observable, done.map(|_| 1.0), "{row:?}");
        }
        // Only the lower half of the walls below 1 m observable (z < 0.5): they stay complete,
        // and the class reports half of its samples observable.
        let low: Vec<bool> = samples
            .iter()
            .zip(&normals)
            .map(|(p, n)| n.z != 0.0 || p.z < 0.5)
            .collect();
        let rows =
            completeness_by_surface(&samples, &normals, &complete, &low, 0.0, height).unwrap();
        let walls = &rows[SurfaceClass::WallBelow1m as usize];
        assert_eq!(walls.completeness, Some(1.0));
        assert_eq!(walls.observable, Some(0.5));
        assert_eq!(rows[SurfaceClass::Wall1To2m as usize].completeness, None);
        // A table top is "other horizontal"; a steep roof panel near the top is a wall.
        let table = SurfaceClass::of(&Point3::new(0.0, 0.0, 0.75), &-Vector3::z(), 0.0, height);
        assert_eq!(table, SurfaceClass::OtherHorizontal);
        let steep = Vector3::new(0.8, 0.0, 0.6);
        assert_eq!(
            SurfaceClass::of(&Point3::new(0.0, 0.0, 2.45), &steep, 0.0, height),
            SurfaceClass::WallAbove2m
        );
        let e = completeness_by_surface(&samples, &normals[1..], &complete, &all, 0.0, height)
            .unwrap_err()
            .to_string();
        assert!(e.contains("normals"), "{e}");
    }

    #[test]
    fn grid_matches_brute_force_across_cell_borders() {
        let mut rng = ChaCha8Rng::seed_from_u64(7);
        let mut cloud = |n: usize| -> Vec<Point3<f64>> {
            (0..n)
                .map(|_| {
                    Point3::new(
                        rng.random_range(-0.3..0.3),
                        rng.random_range(-0.3..0.3),
                        rng.random_range(-0.3..0.3),
                    )
                })
                .collect()
        };
        let truth = cloud(2000);
        let observed = cloud(300);
        let brute = truth
            .iter()
            .filter(|t| observed.iter().any(|o| (o - *t).norm() <= 0.05))
            .count() as f64
            / truth.len() as f64;
        let fast = completeness(&truth, &observed, 0.05).unwrap();
        assert_eq!(fast, brute);
        assert!(
            fast > 0.05 && fast < 0.95,
            "the test should exercise both outcomes: {fast}"
        );
    }

    #[test]
    fn mesh_samples_cover_the_surface_uniformly() {
        // Unit square in z = 0 from two triangles, plus a degenerate one that must never be hit.
        let v = [
            Point3::new(0.0, 0.0, 0.0),
            Point3::new(1.0, 0.0, 0.0),
            Point3::new(1.0, 1.0, 0.0),
            Point3::new(0.0, 1.0, 0.0),
            Point3::new(5.0, 5.0, 5.0),
        ];
        let tris = [[0, 1, 2], [4, 4, 4], [0, 2, 3]];
        let s = sample_mesh_surface(&v, &tris, 20_000, 3).unwrap();
        assert!(
            s.iter()
                .all(|p| p.z == 0.0 && (0.0..=1.0).contains(&p.x) && (0.0..=1.0).contains(&p.y))
        );
        // Observed: the left half of the square on a 1 cm lattice. Complete samples are those
        // with x ≤ 0.5 + 0.05 (within 5 cm of the lattice) → expected fraction 0.55; binomial
        // standard deviation √(.55·.45/20000) ≈ 0.0035, tolerance 5σ.
        let observed: Vec<Point3<f64>> = (0..=50)
            .flat_map(|i| {
                (0..=100).map(move |j| Point3::new(f64::from(i) * 0.01, f64::from(j) * 0.01, 0.0))
            })
            .collect();
        let c = completeness(&s, &observed, 0.05).unwrap();
        assert!((c - 0.55).abs() < 0.018, "{c}");
        // same seed, same samples
        assert_eq!(s, sample_mesh_surface(&v, &tris, 20_000, 3).unwrap());
    }

    #[test]
    fn bad_inputs_are_named() {
        let p = [Point3::new(0.0, f64::NAN, 0.0)];
        let ok = [Point3::new(0.0, 0.0, 0.0)];
        let e = completeness(&p, &ok, 0.05).unwrap_err().to_string();
        assert!(e.contains("truth") && e.contains("point 0"), "{e}");
        let e = completeness(&ok, &p, 0.05).unwrap_err().to_string();
        assert!(e.contains("observed"), "{e}");
        assert!(
            completeness(&[], &ok, 0.05)
                .unwrap_err()
                .to_string()
                .contains("empty")
        );
        assert!(completeness(&ok, &ok, 0.0).is_err());
        let e = sample_mesh_surface(&ok, &[[0, 0, 1]], 10, 0)
            .unwrap_err()
            .to_string();
        assert!(e.contains("triangle 0 uses vertex 1"), "{e}");
        let e = sample_mesh_surface(&ok, &[[0, 0, 0]], 10, 0)
            .unwrap_err()
            .to_string();
        assert!(e.contains("zero (or non-finite) total area"), "{e}");
    }
}
