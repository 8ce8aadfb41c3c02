//! The pinhole camera a view is rendered from: the shared [`Intrinsics`] (OpenCV optical frame,
//! integer pixel centres, SPEC §2) and the world-to-camera pose `T_camera_world`.

use crate::SplatError;
use crate::real::Real;
use activemap_geometry::Intrinsics;
use nalgebra::Isometry3;

/// Default near plane (metres): Gaussians with camera depth `z ≤ near` are culled (SPEC §3).
pub const DEFAULT_NEAR: f64 = 0.01;

/// A camera: intrinsics, the world-to-camera pose, and the near and far planes.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Camera {
    /// Image size and pinhole parameters.
    pub intrinsics: Intrinsics,
    /// `T_camera_world`: maps world points into the camera optical frame.
    pub camera_from_world: Isometry3<f64>,
    /// Near plane, metres.
    pub near: f64,
    /// Far plane, metres: Gaussians with camera depth `z > far` are culled (infinite by
    /// default). A view whose every pixel sees a surface closer than some depth can set the far
    /// plane just beyond it: the Gaussians farther away are occluded and change no pixel, and
    /// culling them saves their projection, sorting and optimiser work (the mapper does this).
    pub far: f64,
}

impl Camera {
    /// A camera from its world-to-camera pose `T_camera_world`.
    pub fn new(intrinsics: Intrinsics, camera_from_world: Isometry3<f64>) -> Self {
        Self {
            intrinsics,
            camera_from_world,
            near: DEFAULT_NEAR,
            far: f64::INFINITY,
        }
    }

    /// The same camera with the far plane at `far` metres.
    pub fn with_far(self, far: f64) -> Self {
        Self { far, ..self }
    }

    /// A camera from its pose in the world, `T_world_camera` (the project-wide pose convention).
    pub fn from_world_pose(intrinsics: Intrinsics, world_from_camera: &Isometry3<f64>) -> Self {
        Self::new(intrinsics, world_from_camera.inverse())
    }

    /// Checks the image size, focal lengths and near plane.
    pub fn validate(&self) -> Result<(), SplatError> {
        let k = &self.intrinsics;
        if k.width == 0 || k.height == 0 {
            return Err(SplatError::Camera(format!(
                "image size {}x{} is empty",
                k.width, k.height
            )));
        }
        let finite = [k.fx, k.fy, k.cx, k.cy, self.near]
            .iter()
            .all(|v| v.is_finite());
        if !finite || k.fx == 0.0 || k.fy == 0.0 {
            return Err(SplatError::Camera(format!(
                "bad intrinsics {k:?} or near plane {}",
                self.near
            )));
        }
        if self.near <= 0.0 {
            return Err(SplatError::Camera(format!(
                "near plane {} must be positive",
                self.near
            )));
        }
        if self.far.is_nan() || self.far <= self.near {
            return Err(SplatError::Camera(format!(
                "far plane {} must lie beyond the near plane {}",
                self.far, self.near
            )));
        }
        Ok(())
    }
}

/// The camera in the renderer's scalar type, with the precomputed limits of `x/z`, `y/z` used
/// by the EWA Jacobian clamp (3DGS/gsplat: 1.3× the field of view).
#[derive(Debug, Clone, Copy)]
pub(crate) struct CameraT<T: Real> {
    /// Rotation `R_cw`, row-major.
    pub r: [[T; 3]; 3],
    /// Translation `t_cw`.
    pub t: [T; 3],
    pub fx: T,
    pub fy: T,
    pub cx: T,
    pub cy: T,
    pub width: usize,
    pub height: usize,
    pub near: T,
    /// Far plane (`T::of(f64::INFINITY)` when none).
    pub far: T,
    /// Lower and upper limits of `x/z`.
    pub lim_x: [T; 2],
    /// Lower and upper limits of `y/z`.
    pub lim_y: [T; 2],
}

impl<T: Real> CameraT<T> {
    pub fn new(cam: &Camera) -> Self {
        let k = &cam.intrinsics;
        let m = cam.camera_from_world.rotation.to_rotation_matrix();
        let m = m.matrix();
        let tr = cam.camera_from_world.translation.vector;
        let limits = |extent: f64, c: f64, f: f64| {
            let a = (-0.5 - c) / f;
            let b = (extent - 0.5 - c) / f;
            let margin = 0.3 * 0.5 * extent / f.abs();
            [T::of(a.min(b) - margin), T::of(a.max(b) + margin)]
        };
        Self {
            r: [0, 1, 2].map(|i| [0, 1, 2].map(|j| T::of(m[(i, j)]))),
            t: [T::of(tr.x), T::of(tr.y), T::of(tr.z)],
            fx: T::of(k.fx),
            fy: T::of(k.fy),
            cx: T::of(k.cx),
            cy: T::of(k.cy),
            width: k.width as usize,
            height: k.height as usize,
            near: T::of(cam.near),
            far: T::of(cam.far),
            lim_x: limits(k.width as f64, k.cx, k.fx),
            lim_y: limits(k.height as f64, k.cy, k.fy),
        }
    }
}
