//! Conversions between the wire messages of `activemap-schemas` and the library types the
//! pipeline operators wrap (poses, Gaussian maps, occupancy grids, RGB-D frames), and the scene
//! settings shared by the `sim` and `evaluator` operators.

use activemap_geometry::{Intrinsics, Isometry3, PlanarPose, RobotModel};
use activemap_planning::clearance::ClearanceConfig;
use activemap_planning::grid::{CellState as PlanCell, GridGeometry, OccupancyGrid as PlanGrid};
use activemap_schemas::{
    CellState as WireCell, GaussianMapHeader, GaussianMapMut, GaussianMapView,
    OccupancyGrid as WireGrid, OccupancyGridView, Pose, RgbdFrameView,
};
use activemap_splat::Gaussians;
use nalgebra::{Quaternion, Translation3, UnitQuaternion};

/// The collision check every planning operator shares (frontier reachability, A*, replan
/// triggers): the robot width for which a disc of the robot's radius
/// ([`RobotModel::radius_m`]) centred on a clear cell never overlaps a blocked cell of a grid
/// with `resolution_m` cells (≈ 4.47 cells at 5 cm for 0.1 m; SPEC §6's 3 cells would let the
/// agent touch mapped walls). One width everywhere, so a frontier's closest reachable cell is a
/// goal A* accepts.
pub fn robot_clearance(robot: &RobotModel, resolution_m: f64) -> anyhow::Result<ClearanceConfig> {
    Ok(ClearanceConfig::for_disc(robot.radius_m, resolution_m)?)
}

/// The SLAM world anchor: the camera pose of the robot at the planar origin (the start pose
/// defines the world frame, floor at z = 0; the robot is never told where it is in the scene).
pub fn start_anchor(robot: &RobotModel) -> Isometry3<f64> {
    robot.camera_pose(&PlanarPose::new(0.0, 0.0, 0.0), 0.0)
}

/// An isometry as a wire pose.
pub fn pose_to_wire(t: &Isometry3<f64>) -> Pose {
    let q = t.rotation.quaternion();
    Pose {
        translation: [t.translation.x, t.translation.y, t.translation.z],
        rotation_xyzw: [q.i, q.j, q.k, q.w],
    }
}

/// The tracker's pose-graph corrections as they go on the wire (`PoseEstimate`).
pub fn corrections_to_wire(
    corrections: &[activemap_slam::KeyframeCorrection],
) -> Vec<activemap_schemas::KeyframeCorrection> {
    corrections
        .iter()
        .map(|c| activemap_schemas::KeyframeCorrection {
            frame_id: c.frame_id,
            correction: pose_to_wire(&c.correction),
        })
        .collect()
}

/// The pose-graph corrections an estimate carries; fails on a bad pose, naming the frame and
/// the keyframe.
pub fn corrections_from_wire(
    estimate: &activemap_schemas::PoseEstimate,
) -> anyhow::Result<Vec<activemap_slam::KeyframeCorrection>> {
    estimate
        .keyframe_corrections
        .iter()
        .map(|c| {
            Ok(activemap_slam::KeyframeCorrection {
                frame_id: c.frame_id,
                correction: pose_from_wire(&c.correction).map_err(|e| {
                    anyhow::anyhow!(
                        "frame {}: the correction of keyframe {}: {e}",
                        estimate.frame_id,
                        c.frame_id
                    )
                })?,
            })
        })
        .collect()
}

/// A wire pose as an isometry (renormalised unless already unit); fails on a non-finite or
/// zero quaternion.
pub fn pose_from_wire(p: &Pose) -> anyhow::Result<Isometry3<f64>> {
    let [x, y, z, w] = p.rotation_xyzw;
    let q = Quaternion::new(w, x, y, z);
    anyhow::ensure!(
        q.coords
            .iter()
            .chain(p.translation.iter())
            .all(|v| v.is_finite())
            && q.norm() > 1e-9,
        "pose is not finite or has a zero quaternion: {p:?}"
    );
    // A quaternion that is unit to rounding is taken as it is, so that a pose goes through
    // the wire bit for bit (the in-process drivers and the pipeline then agree exactly).
    let rotation = if (q.norm_squared() - 1.0).abs() <= 4.0 * f64::EPSILON {
        UnitQuaternion::new_unchecked(q)
    } else {
        UnitQuaternion::from_quaternion(q)
    };
    Ok(Isometry3::from_parts(
        Translation3::new(p.translation[0], p.translation[1], p.translation[2]),
        rotation,
    ))
}

/// Header of the wire map of `g`: the snapshot of frame `frame_id`, whose newest keyframe is
/// `keyframe_id` (`None` before the first).
pub fn map_header(
    g: &Gaussians<f32>,
    frame_id: u64,
    stamp: f64,
    keyframe_id: Option<u64>,
) -> GaussianMapHeader {
    GaussianMapHeader::new(stamp, frame_id, g.len() as u64, keyframe_id)
}

/// Writes `g` and the stable id of each of its Gaussians (`ids`, parallel to `g`) into a
/// loaned wire-map buffer (colours are the SH DC coefficients; rotations go from the
/// library's `[w, x, y, z]` to the wire's xyzw).
pub fn write_map(
    buf: &mut [u8],
    header: GaussianMapHeader,
    g: &Gaussians<f32>,
    ids: &[u64],
) -> anyhow::Result<()> {
    anyhow::ensure!(
        ids.len() == g.len(),
        "map of frame {}: {} ids for {} Gaussians",
        header.frame_id,
        ids.len(),
        g.len()
    );
    let m = GaussianMapMut::init(buf, header)?;
    for i in 0..g.len() {
        m.means[3 * i..3 * i + 3].copy_from_slice(&g.means[i]);
        m.colors[3 * i..3 * i + 3].copy_from_slice(&g.sh_dc[i]);
        let [w, x, y, z] = g.rotations[i];
        m.rotations[4 * i..4 * i + 4].copy_from_slice(&[x, y, z, w]);
        m.opacities[i] = g.opacity_logits[i];
        m.log_scales[3 * i..3 * i + 3].copy_from_slice(&g.log_scales[i]);
    }
    m.ids.copy_from_slice(ids);
    Ok(())
}

/// Reads a wire map into library Gaussians (inverse of [`write_map`], ids left out).
pub fn read_map(bytes: &[u8]) -> anyhow::Result<(GaussianMapHeader, Gaussians<f32>)> {
    let v = GaussianMapView::parse(bytes)?;
    Ok((v.header, gaussians_of(&v)))
}

/// Reads a wire map into library Gaussians and the stable id of each (inverse of
/// [`write_map`]).
pub fn read_map_with_ids(
    bytes: &[u8],
) -> anyhow::Result<(GaussianMapHeader, Gaussians<f32>, Vec<u64>)> {
    let v = GaussianMapView::parse(bytes)?;
    Ok((v.header, gaussians_of(&v), v.ids().into_owned()))
}

/// Calls `f` with the policies' view of the wire map `bytes` ([`activemap_policy::MapSnapshot`]):
/// its header, and its Gaussians with their ids decoded only if a policy keeps a new map.
pub fn with_map_snapshot<R>(
    bytes: &[u8],
    f: impl FnOnce(&activemap_policy::MapSnapshot<'_>) -> anyhow::Result<R>,
) -> anyhow::Result<R> {
    let header = GaussianMapView::parse(bytes)?.header;
    let decode = || read_map_with_ids(bytes).map(|(_, gaussians, ids)| (gaussians, ids));
    f(&activemap_policy::MapSnapshot {
        frame_id: header.frame_id,
        keyframe: header.keyframe(),
        count: header.count,
        decode: &decode,
    })
}

fn gaussians_of(v: &GaussianMapView<'_>) -> Gaussians<f32> {
    let n = v.header.count as usize;
    let (means, colors, rotations, opacities, log_scales) = (
        v.means(),
        v.colors(),
        v.rotations(),
        v.opacities(),
        v.log_scales(),
    );
    let mut g = Gaussians::<f32>::new();
    for i in 0..n {
        g.means
            .push([means[3 * i], means[3 * i + 1], means[3 * i + 2]]);
        g.sh_dc
            .push([colors[3 * i], colors[3 * i + 1], colors[3 * i + 2]]);
        let r = &rotations[4 * i..4 * i + 4];
        g.rotations.push([r[3], r[0], r[1], r[2]]);
        g.opacity_logits.push(opacities[i]);
        g.log_scales.push([
            log_scales[3 * i],
            log_scales[3 * i + 1],
            log_scales[3 * i + 2],
        ]);
        g.flags.push(0);
    }
    g
}

/// The wire byte of a planning cell state.
pub fn cell_to_wire(c: PlanCell) -> u8 {
    match c {
        PlanCell::Free => WireCell::Free as u8,
        PlanCell::Occupied => WireCell::Occupied as u8,
        PlanCell::Unknown => WireCell::Unknown as u8,
    }
}

/// `grid` as a wire occupancy grid (small enough to encode and copy into the shared-memory
/// sample: 1 byte per 5 cm cell). The wire origin is the CENTRE of cell (0, 0) (the schema's
/// convention); the planning grid keeps its corner origin internally.
pub fn grid_to_wire(grid: &PlanGrid, frame_id: u64, stamp: f64) -> WireGrid {
    let g = &grid.geometry;
    let centre = g.center_origin();
    WireGrid {
        stamp,
        frame_id,
        origin: [centre.x, centre.y],
        resolution: g.resolution,
        width: g.width as u32,
        height: g.height as u32,
        cells: grid.data.iter().map(|c| cell_to_wire(*c)).collect(),
    }
}

/// Reads a wire grid (origin = centre of cell (0, 0)) into a planning grid; fails on a bad
/// cell byte.
pub fn read_grid(bytes: &[u8]) -> anyhow::Result<(u64, PlanGrid)> {
    let v = OccupancyGridView::parse(bytes)?;
    let h = v.header;
    let geometry = GridGeometry::from_center_origin(
        h.origin_x,
        h.origin_y,
        h.resolution,
        h.width as usize,
        h.height as usize,
    )?;
    let mut data = Vec::with_capacity(v.cells.len());
    for (i, b) in v.cells.iter().enumerate() {
        data.push(match WireCell::from_byte(*b) {
            Some(WireCell::Free) => PlanCell::Free,
            Some(WireCell::Occupied) => PlanCell::Occupied,
            Some(WireCell::Unknown) => PlanCell::Unknown,
            None => anyhow::bail!(
                "occupancy grid frame {}: cell {i} holds invalid byte {b}",
                h.frame_id
            ),
        });
    }
    Ok((h.frame_id, PlanGrid::from_data(geometry, data)?))
}

/// Intrinsics of a wire RGB-D frame.
pub fn frame_intrinsics(v: &RgbdFrameView<'_>) -> Intrinsics {
    let h = &v.header;
    Intrinsics {
        fx: h.fx,
        fy: h.fy,
        cx: h.cx,
        cy: h.cy,
        width: h.width,
        height: h.height,
    }
}

/// A wire RGB-D frame as a SLAM frame.
pub fn slam_frame(v: &RgbdFrameView<'_>) -> anyhow::Result<activemap_slam::Frame> {
    let k = frame_intrinsics(v);
    Ok(activemap_slam::Frame::from_rgb8(
        k,
        v.rgb,
        v.depth().into_owned(),
        v.header.stamp,
    )?)
}

#[cfg(test)]
mod tests {
    use super::*;
    use activemap_planning::grid::Cell;
    use activemap_schemas::Payload;

    /// The wire grid's origin is the centre of cell (0, 0) (schema convention), the planning
    /// grid's the corner; the round trip keeps every cell and its world position.
    #[test]
    fn grid_origin_is_the_cell_centre_on_the_wire_and_round_trips() {
        let geometry = GridGeometry::new(-2.0, 1.0, 0.05, 4, 3).unwrap();
        let mut data = vec![PlanCell::Unknown; 12];
        data[5] = PlanCell::Free;
        data[11] = PlanCell::Occupied;
        let grid = PlanGrid::from_data(geometry, data).unwrap();
        let wire = grid_to_wire(&grid, 7, 1.5);
        assert!((wire.origin[0] - -1.975).abs() < 1e-12, "{:?}", wire.origin);
        assert!((wire.origin[1] - 1.025).abs() < 1e-12, "{:?}", wire.origin);
        let bytes = wire.to_bytes().unwrap();
        let (k, back) = read_grid(&bytes).unwrap();
        assert_eq!(k, 7);
        assert_eq!(back.data, grid.data);
        for c in [Cell::new(0, 0), Cell::new(3, 2), Cell::new(1, 1)] {
            let (a, b) = (grid.geometry.center(c), back.geometry.center(c));
            assert!((a - b).norm() < 1e-12, "{c:?}: {a} vs {b}");
        }
    }

    /// A map goes through the shared-memory layout with every parameter and its ids bit for
    /// bit (rotations reordered and back); ids that do not match the map are refused naming
    /// the frame.
    #[test]
    fn a_map_and_its_ids_round_trip_through_the_wire_layout() {
        let mut g = Gaussians::<f32>::new();
        g.push(
            [0.1, 0.2, 0.3],
            [0.9, 0.5, 0.1],
            [0.9, 0.1, 0.2, 0.3],
            0.7,
            [0.01, 0.02, 0.03],
        );
        g.push(
            [-1.0, 2.0, 0.5],
            [0.2, 0.4, 0.6],
            [1.0, 0.0, 0.0, 0.0],
            0.2,
            [0.05, 0.05, 0.01],
        );
        let ids = [4u64, 17];
        let header = map_header(&g, 30, 3.0, Some(25));
        let mut storage = vec![0u64; header.payload_len().unwrap() / 8];
        let buf: &mut [u8] = bytemuck::cast_slice_mut(&mut storage);
        write_map(buf, header, &g, &ids).unwrap();
        let (h, back, back_ids) = read_map_with_ids(buf).unwrap();
        assert_eq!((h.frame_id, h.keyframe(), h.count), (30, Some(25), 2));
        assert_eq!(back, g);
        assert_eq!(back_ids, ids);
        assert_eq!(read_map(buf).unwrap().1, g);
        let e = write_map(buf, header, &g, &ids[..1])
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("frame 30") && e.contains("1 ids for 2 Gaussians"),
            "{e}"
        );
    }

    /// The planning footprint is the simulator's agent: the same robot model, and at 5 cm
    /// cells the shared clearance is wider than SPEC §6's 3 cells (which let the agent touch
    /// walls).
    #[test]
    fn robot_footprint_matches_the_simulator_agent() {
        let robot = RobotModel::default();
        assert_eq!(activemap_sim::SimConfig::default().robot, robot);
        assert_eq!(
            activemap_sim::house::HouseConfig::default().agent_radius,
            robot.radius_m
        );
        let c = robot_clearance(&robot, 0.05).unwrap();
        assert!(
            c.robot_width_cells > 4.4 && c.robot_width_cells < 4.5,
            "{c:?}"
        );
        assert!(c.unknown_is_blocked);
    }
}
