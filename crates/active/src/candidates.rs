//! Candidate poses (SPEC §6 "Candidates", paper appendix) and uniform free-space poses
//! (SPEC §5, the Monte-Carlo poses of the model Fisher `I(w)`).
//!
//! Candidates: K draws around a focus point (a frontier, or a refine cluster's centre), the
//! distance uniform in `[r0, r1]`, the bearing uniform in [0, 2π), the camera yawed to face
//! the focus; a pose is kept when its cell is clear in the [`ClearanceMap`] (known free space
//! eroded by the robot radius). When none survives, both radii grow by a factor (release:
//! ×1.5) and all K are drawn again, up to a number of retries.
//!
//! Free-space poses: a clear cell uniformly at random, a position uniform inside it, a yaw
//! uniform in (−π, π]: together uniform over the clear area.

use activemap_geometry::PlanarPose;
use activemap_planning::clearance::ClearanceMap;
use nalgebra::Point2;
use rand::Rng;
use rand_chacha::ChaCha8Rng;

use crate::ActiveError;

/// Candidates around `focus`, facing it (SPEC §6 "Candidates"): `count` draws at a distance
/// uniform in `radius_m = [r0, r1]` metres and a uniform bearing, yaw = `atan2(focus − pose)`;
/// the poses whose cell is clear in `clear` are kept, in draw order. When none survives, the
/// radii are multiplied by `growth` and `count` poses drawn again, at most `retries` times;
/// the result is empty when every attempt failed (and may hold fewer than `count` poses).
///
/// Errors: a non-finite focus, radii not `0 <= r0 <= r1` finite, or a growth not finite and
/// at least 1.
pub fn sample_candidates(
    clear: &ClearanceMap,
    focus: Point2<f64>,
    count: usize,
    radius_m: [f64; 2],
    growth: f64,
    retries: usize,
    rng: &mut ChaCha8Rng,
) -> Result<Vec<PlanarPose>, ActiveError> {
    if !(focus.x.is_finite() && focus.y.is_finite()) {
        return Err(ActiveError::Input {
            what: "candidate focus",
            reason: format!("must be finite, got ({}, {})", focus.x, focus.y),
        });
    }
    let [mut r0, mut r1] = radius_m;
    if !(r0.is_finite() && r1.is_finite() && 0.0 <= r0 && r0 <= r1) {
        return Err(ActiveError::Input {
            what: "candidate radius",
            reason: format!("must be [min, max] with 0 <= min <= max, got [{r0}, {r1}]"),
        });
    }
    if !(growth.is_finite() && growth >= 1.0) {
        return Err(ActiveError::Input {
            what: "candidate radius growth",
            reason: format!("must be finite and at least 1, got {growth}"),
        });
    }
    let geometry = clear.geometry();
    for attempt in 0..=retries {
        if attempt > 0 {
            r0 *= growth;
            r1 *= growth;
        }
        let kept: Vec<PlanarPose> = (0..count)
            .filter_map(|_| {
                let r = r0 + (r1 - r0) * rng.random::<f64>();
                let bearing = std::f64::consts::TAU * rng.random::<f64>();
                let (x, y) = (focus.x + r * bearing.cos(), focus.y + r * bearing.sin());
                let yaw = (focus.y - y).atan2(focus.x - x);
                clear
                    .is_clear(geometry.cell_of(Point2::new(x, y)))
                    .then_some(PlanarPose::new(x, y, yaw))
            })
            .collect();
        if !kept.is_empty() {
            return Ok(kept);
        }
    }
    Ok(Vec::new())
}

/// `count` poses uniform in the clear (robot-radius eroded, known-free) space with a uniform
/// yaw in (−π, π] (SPEC §5, the paper's Monte-Carlo poses of `I(w)`): a clear cell uniformly
/// at random (all cells have the same area), then a position uniform inside its square.
/// Empty when no cell is clear.
pub fn sample_free_space_poses(
    clear: &ClearanceMap,
    count: usize,
    rng: &mut ChaCha8Rng,
) -> Vec<PlanarPose> {
    let geometry = *clear.geometry();
    let cells: Vec<_> = (0..geometry.len())
        .map(|i| geometry.cell_at(i))
        .filter(|&c| clear.is_clear(c))
        .collect();
    if cells.is_empty() {
        return Vec::new();
    }
    let side = geometry.resolution;
    (0..count)
        .map(|_| {
            let cell = cells[rng.random_range(0..cells.len())];
            let centre = geometry.center(cell);
            // Uniform in the square; a draw that rounds onto a neighbour's boundary (a
            // measure-zero event) is redrawn, so every pose lies in its clear cell.
            let mut p = centre;
            for _ in 0..8 {
                let q = Point2::new(
                    centre.x + side * (rng.random::<f64>() - 0.5),
                    centre.y + side * (rng.random::<f64>() - 0.5),
                );
                if geometry.cell_of(q) == cell {
                    p = q;
                    break;
                }
            }
            // (−π, π]: π − u·2π with u in [0, 1).
            let yaw = std::f64::consts::PI - std::f64::consts::TAU * rng.random::<f64>();
            PlanarPose::new(p.x, p.y, yaw)
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use activemap_planning::OccupancyGrid;
    use activemap_planning::clearance::ClearanceConfig;
    use rand::SeedableRng;

    /// A grid of `rows` at 5 cm with the default robot width (3 cells).
    fn clearance(rows: &[&str]) -> ClearanceMap {
        let grid = OccupancyGrid::from_ascii(rows, 0.05).unwrap();
        ClearanceMap::new(&grid, &ClearanceConfig::default()).unwrap()
    }

    /// A 2 m × 2 m free room with a wall border.
    fn room() -> Vec<String> {
        let n = 40;
        (0..n)
            .map(|r| {
                (0..n)
                    .map(|c| {
                        if r == 0 || c == 0 || r == n - 1 || c == n - 1 {
                            '#'
                        } else {
                            '.'
                        }
                    })
                    .collect()
            })
            .collect()
    }

    fn rows(v: &[String]) -> Vec<&str> {
        v.iter().map(|s| s.as_str()).collect()
    }

    #[test]
    fn candidates_are_clear_in_range_and_face_the_focus() {
        let room = room();
        let map = clearance(&rows(&room));
        let focus = Point2::new(1.0, 1.0);
        let mut rng = ChaCha8Rng::seed_from_u64(5);
        let c = sample_candidates(&map, focus, 256, [0.3, 0.8], 1.5, 3, &mut rng).unwrap();
        // The 0.8 m ring fits inside the room's clear part (0.1 m .. 1.9 m): all survive.
        assert_eq!(c.len(), 256);
        for p in &c {
            let d = ((p.x - focus.x).powi(2) + (p.y - focus.y).powi(2)).sqrt();
            assert!((0.3 - 1e-12..=0.8 + 1e-12).contains(&d), "distance {d}");
            let facing = (focus.y - p.y).atan2(focus.x - p.x);
            assert!((p.yaw - facing).abs() < 1e-12, "{} vs {facing}", p.yaw);
            assert!(map.is_clear(map.geometry().cell_of(Point2::new(p.x, p.y))));
        }
        // With a radius reaching beyond the walls, only the clear ones are kept, all clear.
        let mut rng = ChaCha8Rng::seed_from_u64(6);
        let far = sample_candidates(&map, focus, 256, [0.5, 1.5], 1.5, 0, &mut rng).unwrap();
        assert!(!far.is_empty() && far.len() < 256, "{}", far.len());
        assert!(
            far.iter()
                .all(|p| map.is_clear(map.geometry().cell_of(Point2::new(p.x, p.y))))
        );
    }

    #[test]
    fn the_radius_grows_when_the_inner_ring_is_blocked() {
        // A 2 m room whose middle block [0.4, 1.6)² m is occupied: with the robot radius
        // (1.5 cells) the nearest clear cells are 2 cells off it, at least 0.65 m from the
        // centre along x or y. So from the centre no pose at [0.2, 0.4] m nor, grown once,
        // at [0.3, 0.6] m is clear; grown twice ([0.45, 0.9] m) the ring reaches the margin.
        let mut room = room();
        for (r, row) in room.iter_mut().enumerate() {
            *row = row
                .chars()
                .enumerate()
                .map(|(c, ch)| {
                    if (8..32).contains(&r) && (8..32).contains(&c) {
                        '#'
                    } else {
                        ch
                    }
                })
                .collect();
        }
        let map = clearance(&rows(&room));
        let focus = Point2::new(1.0, 1.0);
        let draw = |retries: usize| {
            let mut rng = ChaCha8Rng::seed_from_u64(9);
            sample_candidates(&map, focus, 64, [0.2, 0.4], 1.5, retries, &mut rng).unwrap()
        };
        assert!(draw(0).is_empty());
        assert!(draw(1).is_empty());
        let grown = draw(2);
        assert!(!grown.is_empty());
        for p in &grown {
            let d = ((p.x - focus.x).powi(2) + (p.y - focus.y).powi(2)).sqrt();
            assert!((0.65..=0.9 + 1e-9).contains(&d), "distance {d}");
            assert!(map.is_clear(map.geometry().cell_of(Point2::new(p.x, p.y))));
        }
        // Further retries are not used once a ring succeeds.
        assert_eq!(draw(5), grown);
    }

    #[test]
    fn candidates_are_seeded_and_bad_inputs_refused() {
        let room = room();
        let map = clearance(&rows(&room));
        let focus = Point2::new(1.0, 1.0);
        let run = |seed| {
            let mut rng = ChaCha8Rng::seed_from_u64(seed);
            sample_candidates(&map, focus, 32, [0.3, 1.0], 1.5, 3, &mut rng).unwrap()
        };
        assert_eq!(run(1), run(1));
        assert_ne!(run(1), run(2));
        let mut rng = ChaCha8Rng::seed_from_u64(0);
        let mut bad = |f: Point2<f64>, r: [f64; 2], g: f64| {
            sample_candidates(&map, f, 4, r, g, 1, &mut rng)
                .unwrap_err()
                .to_string()
        };
        assert!(bad(Point2::new(f64::NAN, 0.0), [0.3, 1.0], 1.5).contains("focus"));
        assert!(bad(focus, [1.0, 0.3], 1.5).contains("radius"));
        assert!(bad(focus, [-0.1, 0.3], 1.5).contains("radius"));
        assert!(bad(focus, [0.3, 1.0], 0.5).contains("growth"));
    }

    #[test]
    fn free_space_poses_are_uniform_over_the_clear_cells() {
        // An L-shaped free area: its clear cells are not symmetric, so the mean position is a
        // real check of uniformity over cells.
        let mut room = room();
        for (r, row) in room.iter_mut().enumerate() {
            *row = row
                .chars()
                .enumerate()
                .map(|(c, ch)| if r < 20 && c >= 20 { '#' } else { ch })
                .collect();
        }
        let map = clearance(&rows(&room));
        let g = *map.geometry();
        let centres: Vec<Point2<f64>> = (0..g.len())
            .map(|i| g.cell_at(i))
            .filter(|&c| map.is_clear(c))
            .map(|c| g.center(c))
            .collect();
        let m = centres.len() as f64;
        let mean = |f: fn(&Point2<f64>) -> f64| centres.iter().map(f).sum::<f64>() / m;
        let (mx, my) = (mean(|p| p.x), mean(|p| p.y));
        // Variance of one draw per axis: the spread of the cell centres plus the uniform
        // offset inside a cell (side²/12).
        let var = |f: fn(&Point2<f64>) -> f64, mu: f64| {
            centres.iter().map(|p| (f(p) - mu).powi(2)).sum::<f64>() / m
                + g.resolution.powi(2) / 12.0
        };
        let (vx, vy) = (var(|p| p.x, mx), var(|p| p.y, my));
        let n = 20_000;
        let mut rng = ChaCha8Rng::seed_from_u64(17);
        let poses = sample_free_space_poses(&map, n, &mut rng);
        assert_eq!(poses.len(), n);
        for p in &poses {
            assert!(map.is_clear(g.cell_of(Point2::new(p.x, p.y))), "{p:?}");
            assert!(p.yaw > -std::f64::consts::PI && p.yaw <= std::f64::consts::PI);
        }
        let sx = poses.iter().map(|p| p.x).sum::<f64>() / n as f64;
        let sy = poses.iter().map(|p| p.y).sum::<f64>() / n as f64;
        let syaw = poses.iter().map(|p| p.yaw).sum::<f64>() / n as f64;
        let se = |v: f64| (v / n as f64).sqrt();
        assert!((sx - mx).abs() < 4.0 * se(vx), "x {sx} vs {mx}");
        assert!((sy - my).abs() < 4.0 * se(vy), "y {sy} vs {my}");
        // Yaw uniform on a 2π interval: mean 0, variance π²/3.
        let pi2 = std::f64::consts::PI.powi(2);
        assert!(syaw.abs() < 4.0 * se(pi2 / 3.0), "yaw mean {syaw}");
        // Seeded; nothing clear → nothing drawn.
        let mut a = ChaCha8Rng::seed_from_u64(3);
        let mut b = ChaCha8Rng::seed_from_u64(3);
        assert_eq!(
            sample_free_space_poses(&map, 50, &mut a),
            sample_free_space_poses(&map, 50, &mut b)
        );
        let blocked = clearance(&["###", "#.#", "###"]);
        assert!(sample_free_space_poses(&blocked, 10, &mut a).is_empty());
    }
}
