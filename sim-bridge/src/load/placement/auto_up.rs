//! `up_axis: auto`: which way is up in a scene file, found from the mesh's own planes.
//!
//! A scan from an RGB-D reconstruction comes in its first camera's frame, tilted by however
//! the camera was pitched; a modelled file may use any of the six axes. The rule, at any tilt
//! and without hints (deterministic: seeded draws and fixed thresholds):
//!
//! 1. **Directions.** The dominant directions the surface faces (by triangle winding) are found
//!    by an area-weighted mean shift on the sphere of triangle normals (20° window), started
//!    from [`DIRECTION_SEEDS`] seeded area-weighted draws; modes within 10° of a stronger one
//!    are merged.
//! 2. **Planes.** Along each direction, the densest 6 cm slab of triangles facing it (within
//!    30°) seeds a plane, refined by the area-weighted least-squares fit of `floor: auto`;
//!    each holds at least 1 m².
//! 3. **The scan above it.** A plane is a floor candidate when at most 10 % of the mesh's area
//!    lies more than 5 cm behind it (on the side it does not face). Of each direction's
//!    candidates the largest is kept.
//! 4. **Ranking.** Candidates are ranked by their net facing area: the surface facing within
//!    30° of the candidate's normal minus the surface facing within 30° of its opposite. A
//!    scan sees the tops of things (the floor, seats, tables) and seldom their undersides, and
//!    a wall faces its opposite wall, so the floor's direction leads even when a wall is
//!    larger than the floor.
//! 5. **Walls.** The winner needs walls roughly perpendicular to it: at least 1 m² of surface
//!    within 15° of perpendicular and more than 1.2 m above the plane.
//! 6. **Refusal.** No candidate, a winner without walls, or a runner-up within 1 m² or 25 %
//!    of the winner's net facing area is an error listing the candidates, each with the
//!    `up_axis` and `transform` that level the scene on it, so the user picks one in one step.
//!
//! The scene is then turned by the nearest of the six axes ([`UpAxis`]) and the smallest
//! rotation that takes the floor's normal from there to +z: a scene whose floor is already
//! along an axis places exactly as with that `up_axis`, and the suggested `transform` of a
//! candidate is that small rotation (`rotate_deg`).

use super::{
    INLIER_DISTANCE, MIN_FLOOR_AREA, Patch, RANSAC_SEED, Transform, UP_COS, UpAxis, all_patches,
    refine_plane,
};
use crate::scene::Scene;
use nalgebra::{Rotation3, Similarity3, UnitQuaternion, Vector3};
use rand::{Rng, SeedableRng};

/// Seeds of the direction mean shift.
pub const DIRECTION_SEEDS: usize = 200;
/// cos 20°: the mean shift's window on the sphere of normals.
const WINDOW_COS: f64 = 0.939_692_620_785_908_4;
/// cos 10°: modes closer than this are one direction.
const MERGE_COS: f64 = 0.984_807_753_012_208;
/// Mean-shift steps per seed.
const SHIFT_STEPS: usize = 8;
/// Most directions examined (the strongest first).
const MAX_DIRECTIONS: usize = 16;
/// Most planes seeded along one direction.
const PLANES_PER_DIRECTION: usize = 6;
/// Width of the offset bins that seed planes, metres (a seed is three bins: 6 cm).
const OFFSET_BIN: f64 = 0.02;
/// Least-squares refinements of a seeded plane.
const AUTO_REFINEMENTS: usize = 8;
/// How far behind a plane the mesh counts as lying below it, metres.
const BEHIND_TOLERANCE: f64 = 0.05;
/// Largest share of the mesh's area behind a floor candidate.
const MAX_BEHIND: f64 = 0.10;
/// sin 15°: a wall's normal is within 15° of perpendicular to the floor's.
const WALL_SIN: f64 = 0.258_819_045_102_520_8;
/// Walls are counted from this height above the floor, metres (furniture is mostly lower).
const WALL_HEIGHT: f64 = 1.2;
/// Least wall area above [`WALL_HEIGHT`], m².
const MIN_WALL_AREA: f64 = 1.0;
/// The runner-up is too close when its net facing area is within this share of the winner's…
const AMBIGUOUS_SHARE: f64 = 0.25;
/// … or within this many m².
const AMBIGUOUS_MARGIN: f64 = 1.0;
/// Candidates listed in a refusal.
const LISTED: usize = 6;

/// A plane of the mesh that could be the floor, and how it fares under the rule of
/// [`self`](crate::load::placement::auto_up).
#[derive(Debug, Clone, PartialEq)]
pub struct FloorCandidate {
    /// The unit normal (the side its surface faces), in the frame after the transform.
    pub normal: Vector3<f64>,
    /// The same normal in the file's own frame.
    pub file_normal: Vector3<f64>,
    /// The plane's offset, `normal · p = offset`, metres.
    pub offset: f64,
    /// Area of the triangles on the plane, m².
    pub area: f64,
    /// Root-mean-square distance of that surface from the plane, metres.
    pub rms: f64,
    /// Net facing area: surface facing within 30° of `normal` minus surface facing within 30°
    /// of `−normal`, m².
    pub facing_area: f64,
    /// Share of the mesh's area more than 5 cm behind the plane (0–1).
    pub behind: f64,
    /// Surface within 15° of perpendicular to the plane and more than 1.2 m above it, m².
    pub wall_area: f64,
    /// The nearest of the six axes to `file_normal`.
    pub up_axis: UpAxis,
    /// The angle between `file_normal` and that axis, degrees: the tilt levelling removes.
    pub tilt_deg: f64,
    /// The rotation after `up_axis` that levels the plane, `[roll, pitch, yaw]` degrees (as
    /// [`Transform::rotate_deg`]).
    pub rotate_deg: [f64; 3],
    /// The rotation taking the frame after the transform to the levelled world frame.
    pub rotation: UnitQuaternion<f64>,
    /// The placement keys that level the scene on this plane without `up_axis: auto`.
    pub pick: String,
}

impl FloorCandidate {
    /// One line: where it faces, its support, and the placement that picks it.
    pub fn describe(&self) -> String {
        let n = self.file_normal;
        format!(
            "plane facing ({:.3}, {:.3}, {:.3}) in the file's frame ({:.1}° from {}): {:.1} m², \
             net facing area {:.1} m², {:.0} % of the scan behind it, walls {:.1} m² \
             [{}]",
            n.x,
            n.y,
            n.z,
            self.tilt_deg,
            self.up_axis,
            self.area,
            self.facing_area,
            100.0 * self.behind,
            self.wall_area,
            self.pick
        )
    }
}

/// What `up_axis: auto` decided: the floor and the candidate that came closest.
#[derive(Debug, Clone, PartialEq)]
pub struct UpDecision {
    /// The floor.
    pub chosen: FloorCandidate,
    /// The next candidate (or, with none left, the largest plane that is not one).
    pub runner_up: Option<FloorCandidate>,
    /// Why the runner-up lost.
    pub runner_up_lost: String,
}

/// A plane found along one direction.
struct Found {
    normal: Vector3<f64>,
    offset: f64,
    area: f64,
    rms: f64,
}

/// Area-weighted draws of patch indices (with replacement), seeded.
struct Draws {
    cdf: Vec<f64>,
    total: f64,
}

impl Draws {
    fn new(patches: &[Patch]) -> Self {
        let mut acc = 0.0;
        let cdf = patches
            .iter()
            .map(|p| {
                acc += p.area;
                acc
            })
            .collect();
        Self { cdf, total: acc }
    }
    fn pick(&self, rng: &mut impl Rng) -> usize {
        let u = rng.random::<f64>() * self.total;
        self.cdf
            .partition_point(|&c| c <= u)
            .min(self.cdf.len() - 1)
    }
}

/// The dominant facing directions with their support (step 1 of the rule), strongest first.
fn directions(patches: &[Patch], draws: &Draws, rng: &mut impl Rng) -> Vec<Vector3<f64>> {
    // A weighted sample keeps the mean shift's cost bounded on large meshes.
    let sample: Vec<(Vector3<f64>, f64)> = if patches.len() <= super::SCORING_SAMPLES {
        patches.iter().map(|p| (p.normal, p.area)).collect()
    } else {
        let w = draws.total / super::SCORING_SAMPLES as f64;
        (0..super::SCORING_SAMPLES)
            .map(|_| (patches[draws.pick(rng)].normal, w))
            .collect()
    };
    let mut modes: Vec<(f64, Vector3<f64>)> = Vec::new();
    for _ in 0..DIRECTION_SEEDS {
        let mut v = patches[draws.pick(rng)].normal;
        let mut support = 0.0;
        for _ in 0..SHIFT_STEPS {
            let (mut sum, mut s) = (Vector3::zeros(), 0.0);
            for (n, w) in &sample {
                if n.dot(&v) >= WINDOW_COS {
                    sum += *w * n;
                    s += w;
                }
            }
            support = s;
            match sum.try_normalize(1e-12) {
                Some(u) => v = u,
                None => break,
            }
        }
        modes.push((support, v));
    }
    modes.sort_by(|a, b| b.0.total_cmp(&a.0));
    let mut kept: Vec<Vector3<f64>> = Vec::new();
    for (support, v) in modes {
        if support < MIN_FLOOR_AREA || kept.len() == MAX_DIRECTIONS {
            break;
        }
        if kept.iter().all(|k| k.dot(&v) < MERGE_COS) {
            kept.push(v);
        }
    }
    kept
}

/// The planes facing `v` (step 2 of the rule).
fn planes_along(patches: &[Patch], v: &Vector3<f64>) -> Vec<Found> {
    let facing: Vec<&Patch> = patches
        .iter()
        .filter(|p| p.normal.dot(v) >= UP_COS)
        .collect();
    let mut used = vec![false; facing.len()];
    let mut found: Vec<Found> = Vec::new();
    for _ in 0..PLANES_PER_DIRECTION {
        let mut bins: std::collections::BTreeMap<i64, (f64, f64)> = Default::default();
        for (p, _) in facing.iter().zip(&used).filter(|(_, u)| !**u) {
            let h = v.dot(&((p.corners[0] + p.corners[1] + p.corners[2]) / 3.0));
            let e = bins.entry((h / OFFSET_BIN).round() as i64).or_default();
            e.0 += p.area;
            e.1 += p.area * h;
        }
        let window = |k: i64| {
            (k - 1..=k + 1)
                .filter_map(|j| bins.get(&j))
                .fold((0.0, 0.0), |acc, e| (acc.0 + e.0, acc.1 + e.1))
        };
        let Some((area, moment)) = bins
            .keys()
            .map(|&k| window(k))
            .max_by(|a, b| a.0.total_cmp(&b.0))
        else {
            break;
        };
        if area.is_nan() || area < MIN_FLOOR_AREA {
            break;
        }
        let plane = refine_plane(patches, *v, moment / area, v, AUTO_REFINEMENTS);
        // Whatever the seed covered is done with, whether or not it made a plane.
        let (lo, hi) = (
            moment / area - 2.0 * OFFSET_BIN,
            moment / area + 2.0 * OFFSET_BIN,
        );
        for (p, u) in facing.iter().zip(used.iter_mut()) {
            let h = v.dot(&((p.corners[0] + p.corners[1] + p.corners[2]) / 3.0));
            let on_plane = plane.area >= MIN_FLOOR_AREA
                && p.normal.dot(&plane.normal) >= UP_COS
                && p.corners
                    .iter()
                    .all(|c| (plane.normal.dot(c) - plane.offset).abs() <= INLIER_DISTANCE);
            if on_plane || (lo..=hi).contains(&h) {
                *u = true;
            }
        }
        let duplicate = found.iter().any(|f| {
            f.normal.dot(&plane.normal) >= MERGE_COS
                && (f.offset - plane.offset).abs() <= INLIER_DISTANCE
        });
        if plane.area >= MIN_FLOOR_AREA && !duplicate {
            found.push(Found {
                normal: plane.normal,
                offset: plane.offset,
                area: plane.area,
                rms: plane.rms,
            });
        }
    }
    found
}

/// Net facing area, share behind and wall area of the plane `n · p = d` (steps 3–5).
fn measures(patches: &[Patch], total: f64, n: &Vector3<f64>, d: f64) -> (f64, f64, f64) {
    let (mut facing, mut behind, mut walls) = (0.0, 0.0, 0.0);
    for p in patches {
        let c = n.dot(&p.normal);
        if c >= UP_COS {
            facing += p.area;
        } else if c <= -UP_COS {
            facing -= p.area;
        }
        let h = n.dot(&((p.corners[0] + p.corners[1] + p.corners[2]) / 3.0)) - d;
        if h < -BEHIND_TOLERANCE {
            behind += p.area;
        }
        if c.abs() <= WALL_SIN && h > WALL_HEIGHT {
            walls += p.area;
        }
    }
    (facing, behind / total, walls)
}

/// `[roll, pitch, yaw]` of `r` in degrees, as [`Transform::rotate_deg`] reads them.
fn euler_deg(r: &UnitQuaternion<f64>) -> [f64; 3] {
    let (roll, pitch, yaw) = r.euler_angles();
    [roll, pitch, yaw].map(|a| {
        let d = a.to_degrees();
        // No "-0.00" in the suggestions.
        if d.abs() < 5e-3 { 0.0 } else { d }
    })
}

/// Builds a candidate from a plane found in the frame after `placed` (the transform).
fn candidate(
    plane: &Found,
    measures: (f64, f64, f64),
    placed: &Similarity3<f64>,
    transform: Option<&Transform>,
    floor: super::Floor,
) -> FloorCandidate {
    let user = placed.isometry.rotation;
    let file_normal = user.inverse() * plane.normal;
    let up_axis = UpAxis::ALL
        .into_iter()
        .max_by(|a, b| {
            let za = (a.rotation() * file_normal).z;
            let zb = (b.rotation() * file_normal).z;
            za.total_cmp(&zb)
        })
        .unwrap_or(UpAxis::Z);
    let axis_rotation = up_axis.rotation();
    let after_axis = axis_rotation * file_normal;
    let residual =
        Rotation3::rotation_between(&after_axis, &Vector3::z()).unwrap_or_else(Rotation3::identity);
    let tilt_deg = residual.angle().to_degrees();
    let residual = UnitQuaternion::from_rotation_matrix(&residual);
    let file_to_world = residual * UnitQuaternion::from_rotation_matrix(&axis_rotation);
    let rotation = file_to_world * user.inverse();
    let rotate_deg = euler_deg(&residual);
    // The same placement written with this axis: the transform's scale, the residual rotation,
    // the transform's translation turned by the levelling.
    let t = rotation * placed.isometry.translation.vector;
    let mut parts = Vec::new();
    if let Some(s) = transform
        .and_then(|t| t.scale)
        .or_else(|| transform.and_then(|t| t.matrix).map(|_| placed.scaling()))
    {
        parts.push(format!("scale: {s}"));
    }
    if rotate_deg != [0.0; 3] {
        let [r, p, y] = rotate_deg;
        parts.push(format!("rotate_deg: [{r:.2}, {p:.2}, {y:.2}]"));
    }
    if t.norm() > 5e-4 {
        parts.push(format!("translate: [{:.3}, {:.3}, {:.3}]", t.x, t.y, t.z));
    }
    let mut pick = format!("up_axis: {up_axis}");
    if !parts.is_empty() {
        pick.push_str(&format!(", transform: {{{}}}", parts.join(", ")));
    }
    if !floor.is_none() {
        pick.push_str(&format!(", floor: {floor}"));
    }
    let (facing_area, behind, wall_area) = measures;
    FloorCandidate {
        normal: plane.normal,
        file_normal,
        offset: plane.offset,
        area: plane.area,
        rms: plane.rms,
        facing_area,
        behind,
        wall_area,
        up_axis,
        tilt_deg,
        rotate_deg,
        rotation,
        pick,
    }
}

/// The listing of a refusal: the candidates, best first, each with the placement that picks it.
fn listing(candidates: &[FloorCandidate]) -> String {
    candidates
        .iter()
        .take(LISTED)
        .enumerate()
        .map(|(k, c)| format!("\n  {}. {}", k + 1, c.describe()))
        .collect()
}

/// Finds the floor of `scene` by the rule of this module. `placed` is what the vertices went
/// through since the file (the transform), `transform` and `floor` the keys set, for the
/// suggestions of a refusal. The error says why no floor was chosen and lists the candidates.
pub(super) fn find_up(
    scene: &Scene,
    placed: &Similarity3<f64>,
    transform: Option<&Transform>,
    floor: super::Floor,
) -> Result<UpDecision, String> {
    let patches = all_patches(scene);
    let draws = Draws::new(&patches);
    let total = draws.total;
    if patches.is_empty() || total.is_nan() || total < MIN_FLOOR_AREA {
        return Err(format!(
            "found no floor: the mesh has only {total:.2} m² of surface, need at least \
             {MIN_FLOOR_AREA} m²"
        ));
    }
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(RANSAC_SEED);
    // Every plane of every direction, with its measures.
    let mut planes: Vec<FloorCandidate> = Vec::new();
    for v in directions(&patches, &draws, &mut rng) {
        for plane in planes_along(&patches, &v) {
            let m = measures(&patches, total, &plane.normal, plane.offset);
            planes.push(candidate(&plane, m, placed, transform, floor));
        }
    }
    // Step 3: the scan above it; the largest per direction.
    let mut candidates: Vec<FloorCandidate> = Vec::new();
    let mut others: Vec<FloorCandidate> = Vec::new();
    let mut by_area: Vec<FloorCandidate> = planes;
    by_area.sort_by(|a, b| b.area.total_cmp(&a.area));
    for p in by_area {
        let same_direction = candidates
            .iter()
            .any(|c| c.normal.dot(&p.normal) >= MERGE_COS);
        if p.behind <= MAX_BEHIND && !same_direction {
            candidates.push(p);
        } else {
            others.push(p);
        }
    }
    // Step 4: net facing area, then area, then offset for a total order.
    candidates.sort_by(|a, b| {
        b.facing_area
            .total_cmp(&a.facing_area)
            .then(b.area.total_cmp(&a.area))
            .then(a.offset.total_cmp(&b.offset))
    });
    let Some(best) = candidates.first().cloned() else {
        let largest = others
            .first()
            .map(|o| format!("; the largest plane: {}", o.describe()))
            .unwrap_or_default();
        return Err(format!(
            "found no floor: no plane of at least {MIN_FLOOR_AREA} m² has at most {:.0} % of \
             the scan behind it{largest}",
            100.0 * MAX_BEHIND
        ));
    };
    let choose = "; choose one by replacing `up_axis: auto` with the keys in brackets:";
    // Step 5: walls.
    if best.wall_area < MIN_WALL_AREA {
        return Err(format!(
            "cannot tell up from the mesh: the best floor candidate has no wall (only {:.2} m² \
             of surface within 15° of perpendicular to it and more than {WALL_HEIGHT} m above \
             it, need {MIN_WALL_AREA} m²){choose}{}",
            best.wall_area,
            listing(&candidates)
        ));
    }
    // Step 6: a clear winner.
    let runner = candidates.get(1).cloned();
    if let Some(r) = &runner {
        let gap = best.facing_area - r.facing_area;
        if gap < AMBIGUOUS_MARGIN || gap < AMBIGUOUS_SHARE * best.facing_area.abs() {
            return Err(format!(
                "cannot tell up from the mesh: two floor candidates have similar support (net \
                 facing area {:.1} m² and {:.1} m²: the surface facing each, less the surface \
                 facing away){choose}{}",
                best.facing_area,
                r.facing_area,
                listing(&candidates)
            ));
        }
    }
    let (runner_up, runner_up_lost) = match runner {
        Some(r) => {
            let why = format!(
                "net facing area {:.1} m² against {:.1} m²",
                r.facing_area, best.facing_area
            );
            (Some(r), why)
        }
        None => match others
            .into_iter()
            .find(|o| o.normal.dot(&best.normal) < MERGE_COS)
        {
            Some(o) => {
                let why = format!(
                    "{:.0} % of the scan lies behind it (at most {:.0} % may)",
                    100.0 * o.behind,
                    100.0 * MAX_BEHIND
                );
                (Some(o), why)
            }
            None => (None, "no other plane".into()),
        },
    };
    Ok(UpDecision {
        chosen: best,
        runner_up,
        runner_up_lost,
    })
}
