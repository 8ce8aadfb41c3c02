//! Where a scene file goes in the world: its up axis, then a similarity transform, then the
//! floor.
//!
//! A point `p` of the file lands at `p_world = t + R·(s·up(p))`: [`UpAxis`] turns the file's
//! up axis to +z, then [`Transform`] scales uniformly by `s` (e.g. 0.01 for a file in
//! centimetres), rotates by `R` and translates by `t`. With [`Floor::Auto`] the floor plane is
//! then found in the mesh and the scene levelled on it (see [`Floor::Auto`]), which is what a
//! scan needs whose floor is tilted by a few degrees (an RGB-D reconstruction in its first
//! camera's frame: `up_axis: -y`, `floor: auto`). With `up_axis: auto` the up direction itself
//! is found from the mesh's planes at any tilt ([`auto_up`]), so such a scan needs no hints:
//! `up_axis: auto`, `floor: auto`.
//!
//! Every step is a rotation (determinant +1) times a positive uniform scale plus a
//! translation, so triangle winding is kept and the normals the simulator derives from it
//! ([`Scene::scaled_normal`]) turn with the scene: `n' = s²·R·n`. A floor height or start pose
//! that the scene itself states is carried along when the total rotation keeps +z vertical,
//! and dropped with a warning otherwise (a tilted floor has no single height).
//!
//! In a node's configuration (`sim`, `evaluator`):
//!
//! ```yaml
//! scene: scans/room.obj
//! up_axis: -y                 # x, -x, y, -y, z, -z, auto
//! transform: { scale: 0.01, rotate_deg: [0, 0, 90], translate: [1.0, 0.0, 0.0] }
//! # or: transform: { matrix: [16 numbers, row-major 4×4] }
//! floor: auto                 # none (default) | auto | <floor height, metres>
//! ```

use super::{LoadWarning, UpAxis};
use crate::error::{Result, SimError};
use crate::scene::Scene;
use activemap_geometry::PlanarPose;
use nalgebra::{
    Matrix3, Matrix4, Point3, Rotation3, Similarity3, Translation3, UnitQuaternion, Vector3,
};
use rand::{Rng, SeedableRng};
use serde::{Deserialize, Serialize};
use std::path::PathBuf;

pub mod auto_up;
pub use auto_up::{FloorCandidate, UpDecision};

/// Where a scene file goes in the world (see the module doc): one type for the node configs,
/// [`crate::SceneSpec`] and [`super::LoadOptions`], so every consumer places a file alike.
#[derive(Debug, Clone, Copy, Default, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct Placement {
    /// The file's up axis; `None` = the format's default (y for glTF and OBJ, z for PLY);
    /// [`UpAxis::Auto`] = found from the mesh ([`auto_up`]).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub up_axis: Option<UpAxis>,
    /// Scale, rotation and translation, applied after the up axis; `None` = identity.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub transform: Option<Transform>,
    /// The floor, after the transform: as is (default), levelled automatically, or at a
    /// known height.
    #[serde(skip_serializing_if = "Floor::is_none")]
    pub floor: Floor,
}

/// A similarity transform `p ↦ t + R·(s·p)`, written either by its parts or as a matrix.
///
/// Parts: `scale` `s` (> 0, default 1), `rotate_deg: [roll, pitch, yaw]` in degrees with
/// `R = Rz(yaw)·Ry(pitch)·Rx(roll)` (rotations about the fixed world axes: roll about x
/// first, then pitch about y, then yaw about z; default none) and `translate: [x, y, z]`
/// metres (default 0). Matrix: `matrix`, 16 numbers of a row-major 4×4 `[s·R t; 0 0 0 1]`,
/// checked to be a rotation times a positive uniform scale (to 0.2 %) plus a translation; a
/// shear, a non-uniform scale or a reflection is refused. The two forms do not mix.
///
/// Deserialising checks the values, so a node's config check already refuses a bad one.
#[derive(Debug, Clone, Copy, Default, PartialEq, Serialize, Deserialize)]
#[serde(try_from = "TransformFields")]
pub struct Transform {
    /// Uniform scale `s` (e.g. 0.01 for a file in centimetres); `None` = 1.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub scale: Option<f64>,
    /// `[roll, pitch, yaw]`, degrees: `R = Rz(yaw)·Ry(pitch)·Rx(roll)`; `None` = no rotation.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub rotate_deg: Option<[f64; 3]>,
    /// Translation `t`, metres; `None` = none.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub translate: Option<[f64; 3]>,
    /// The whole transform as a row-major 4×4 matrix (instead of the three parts).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub matrix: Option<[f64; 16]>,
}

/// The serde shape of [`Transform`] before its values are checked.
#[derive(Default, Deserialize)]
#[serde(default, deny_unknown_fields)]
struct TransformFields {
    scale: Option<f64>,
    rotate_deg: Option<[f64; 3]>,
    translate: Option<[f64; 3]>,
    matrix: Option<[f64; 16]>,
}

impl TryFrom<TransformFields> for Transform {
    type Error = String;
    fn try_from(f: TransformFields) -> std::result::Result<Self, String> {
        let t = Transform {
            scale: f.scale,
            rotate_deg: f.rotate_deg,
            translate: f.translate,
            matrix: f.matrix,
        };
        t.similarity()?;
        Ok(t)
    }
}

/// Largest `max |RᵀR − I|` of a [`Transform::matrix`] divided by its scale: printed matrices
/// with 4 decimals pass, a shear or non-uniform scale of more than about 0.1 % does not.
const ORTHONORMAL_TOLERANCE: f64 = 2e-3;

impl Transform {
    /// The transform as a similarity (`t + R·(s·p)`), or why its values do not make one.
    pub fn similarity(&self) -> std::result::Result<Similarity3<f64>, String> {
        if let Some(m) = &self.matrix {
            if self.scale.is_some() || self.rotate_deg.is_some() || self.translate.is_some() {
                return Err(
                    "transform: give either `matrix` or `scale`/`rotate_deg`/`translate`, \
                     not both"
                        .into(),
                );
            }
            return similarity_from_matrix(m);
        }
        let scale = self.scale.unwrap_or(1.0);
        if !(scale.is_finite() && scale > 0.0) {
            return Err(format!(
                "transform.scale must be a positive number, got {scale}"
            ));
        }
        let [roll, pitch, yaw] = self.rotate_deg.unwrap_or([0.0; 3]);
        let t = self.translate.unwrap_or([0.0; 3]);
        if [roll, pitch, yaw].iter().chain(&t).any(|v| !v.is_finite()) {
            return Err(
                "transform.rotate_deg and transform.translate must be finite numbers".into(),
            );
        }
        let rotation = UnitQuaternion::from_euler_angles(
            roll.to_radians(),
            pitch.to_radians(),
            yaw.to_radians(),
        );
        Ok(Similarity3::from_parts(
            Translation3::new(t[0], t[1], t[2]),
            rotation,
            scale,
        ))
    }
}

fn similarity_from_matrix(m: &[f64; 16]) -> std::result::Result<Similarity3<f64>, String> {
    if m.iter().any(|v| !v.is_finite()) {
        return Err("transform.matrix holds a value that is not a finite number".into());
    }
    let m4 = Matrix4::from_row_slice(m);
    let bottom = [m4[(3, 0)], m4[(3, 1)], m4[(3, 2)], m4[(3, 3)]];
    if bottom[..3].iter().any(|v| v.abs() > 1e-9) || (bottom[3] - 1.0).abs() > 1e-9 {
        return Err(format!(
            "transform.matrix: the last row must be [0, 0, 0, 1], got {bottom:?}"
        ));
    }
    let a: Matrix3<f64> = m4.fixed_view::<3, 3>(0, 0).into_owned();
    let det = a.determinant();
    if det.is_nan() || det <= 0.0 {
        let what = if det < 0.0 {
            "a reflection (it would mirror the scene)"
        } else {
            "it collapses the scene"
        };
        return Err(format!(
            "transform.matrix is not a rotation times a positive uniform scale: its 3×3 block \
             has determinant {det:.6}, {what}"
        ));
    }
    let scale = det.cbrt();
    let r = a / scale;
    let err = (r.transpose() * r - Matrix3::identity()).abs().max();
    if err > ORTHONORMAL_TOLERANCE {
        return Err(format!(
            "transform.matrix is not a rotation times a positive uniform scale: divided by its \
             scale {scale:.6} (the cube root of the determinant), RᵀR differs from the identity \
             by {err:.2e} (more than {ORTHONORMAL_TOLERANCE:.0e}): a shear or a non-uniform scale"
        ));
    }
    // The closest rotation, so that a matrix printed with few decimals is exactly rigid.
    let rotation = UnitQuaternion::from_rotation_matrix(&Rotation3::from_matrix(&r));
    Ok(Similarity3::from_parts(
        Translation3::new(m4[(0, 3)], m4[(1, 3)], m4[(2, 3)]),
        rotation,
        scale,
    ))
}

impl std::fmt::Display for Transform {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        if let Some(m) = &self.matrix {
            return write!(f, "matrix {m:?}");
        }
        let mut parts = Vec::new();
        if let Some(s) = self.scale {
            parts.push(format!("scale {s}"));
        }
        if let Some(r) = self.rotate_deg {
            parts.push(format!("rotate_deg {r:?}"));
        }
        if let Some(t) = self.translate {
            parts.push(format!("translate {t:?}"));
        }
        if parts.is_empty() {
            parts.push("identity".into());
        }
        f.write_str(&parts.join(", "))
    }
}

/// What happens to the floor after the up axis and the transform.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub enum Floor {
    /// Nothing: the simulator uses the scene's own floor height, else estimates a horizontal
    /// one ([`crate::navigation::estimate_floor_z`]). Written `none`.
    #[default]
    None,
    /// Find the floor plane and level the scene on it. Written `auto`.
    ///
    /// Candidates are the upward-facing triangles (normal within 30° of +z by their winding)
    /// whose centroid lies in the lower half of the scene's height. A seeded RANSAC draws three
    /// area-weighted surface points per hypothesis and scores a plane by the area of the
    /// candidates lying on it (every corner within 3 cm, normal within 30°); an area-weighted
    /// least-squares fit (exact second moments of the inlier triangles) then refines the best
    /// plane, re-selecting its inliers a few times. The scene is rotated by the smallest
    /// rotation taking the plane's normal to +z (about the origin) and moved down so the floor
    /// is at z = 0, and its floor height is set to 0. Fewer than 1 m² on the plane is an error:
    /// usually a wrong `up_axis` (more than 30° of tilt cannot be levelled this way).
    ///
    /// With `up_axis: auto` the floor is the plane [`auto_up`] chose instead, at any tilt; the
    /// scene is levelled on it and moved down to z = 0 alike.
    Auto,
    /// The floor is the plane z = this (metres, after the up axis and transform): the scene's
    /// floor height, with no estimation and no move. Written as the number.
    Height(f64),
}

impl Floor {
    /// Whether this is [`Floor::None`] (the default).
    pub fn is_none(&self) -> bool {
        *self == Floor::None
    }
}

impl std::fmt::Display for Floor {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Floor::None => f.write_str("none"),
            Floor::Auto => f.write_str("auto"),
            Floor::Height(h) => write!(f, "{h}"),
        }
    }
}

/// `none`, `auto` or the height as a number.
impl Serialize for Floor {
    fn serialize<S: serde::Serializer>(&self, s: S) -> std::result::Result<S::Ok, S::Error> {
        match self {
            Floor::None => s.serialize_str("none"),
            Floor::Auto => s.serialize_str("auto"),
            Floor::Height(h) => s.serialize_f64(*h),
        }
    }
}

/// Reads `none` / `auto` (case-insensitive) or a finite number; anything else is an error
/// naming the accepted values.
impl<'de> Deserialize<'de> for Floor {
    fn deserialize<D: serde::Deserializer<'de>>(d: D) -> std::result::Result<Self, D::Error> {
        struct V;
        const EXPECTED: &str = "`none`, `auto` or the floor height in metres";
        impl serde::de::Visitor<'_> for V {
            type Value = Floor;
            fn expecting(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
                f.write_str(EXPECTED)
            }
            fn visit_str<E: serde::de::Error>(self, v: &str) -> std::result::Result<Floor, E> {
                match v.trim().to_ascii_lowercase().as_str() {
                    "none" => Ok(Floor::None),
                    "auto" => Ok(Floor::Auto),
                    _ => Err(E::custom(format!("floor must be {EXPECTED}, got \"{v}\""))),
                }
            }
            fn visit_f64<E: serde::de::Error>(self, v: f64) -> std::result::Result<Floor, E> {
                if v.is_finite() {
                    Ok(Floor::Height(v))
                } else {
                    Err(E::custom(format!("floor must be {EXPECTED}, got {v}")))
                }
            }
            fn visit_i64<E: serde::de::Error>(self, v: i64) -> std::result::Result<Floor, E> {
                self.visit_f64(v as f64)
            }
            fn visit_u64<E: serde::de::Error>(self, v: u64) -> std::result::Result<Floor, E> {
                self.visit_f64(v as f64)
            }
        }
        d.deserialize_any(V)
    }
}

/// The floor plane that [`Floor::Auto`] or [`UpAxis::Auto`] found and how the scene was
/// levelled on it.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Levelling {
    /// The tilt removed: the angle between the floor's normal and +z, degrees (with
    /// [`UpAxis::Auto`]: and the nearest of the six axes, which is turned up first).
    pub tilt_deg: f64,
    /// The horizontal unit axis the scene was turned about by `tilt_deg` (right-hand rule; any
    /// horizontal axis when the tilt is 0).
    pub axis: Vector3<f64>,
    /// The floor plane's unit normal before levelling (pointing up).
    pub normal: Vector3<f64>,
    /// The plane's offset before levelling (`normal · p = height`): how far the scene was
    /// moved down after the rotation with `floor: auto` (with `up_axis: auto` and another
    /// floor setting the scene is only turned, and its floor stays at this height), metres.
    pub height: f64,
    /// Area of the triangles on the plane, m².
    pub area: f64,
    /// Root-mean-square distance of that surface from the plane, metres.
    pub rms: f64,
    /// The levelling map itself: `p ↦ R·p − height·ẑ`.
    pub transform: Similarity3<f64>,
}

/// What a placement did, for the caller to print (`SceneSpec::simulator` writes it to stderr
/// with the loader warnings) or log.
#[derive(Debug, Clone, PartialEq)]
pub struct PlacementReport {
    /// The scene (file path).
    pub scene: String,
    /// The up axis used (the format's default when none was set).
    pub up_axis: UpAxis,
    /// The transform applied after the up axis.
    pub transform: Option<Transform>,
    /// The floor setting.
    pub floor: Floor,
    /// With [`Floor::Auto`] or [`UpAxis::Auto`]: the plane found and the tilt removed.
    pub levelling: Option<Levelling>,
    /// With [`UpAxis::Auto`]: the floor chosen and the runner-up.
    pub auto_up: Option<UpDecision>,
    /// The scene's floor height after placement (0 after levelling), if it has one.
    pub floor_z: Option<f64>,
}

impl std::fmt::Display for PlacementReport {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "placement: {}: up axis {}", self.scene, self.up_axis)?;
        if let Some(t) = &self.transform {
            write!(f, "; transform {t}")?;
        }
        if let (Some(d), Some(l)) = (&self.auto_up, &self.levelling) {
            let c = &d.chosen;
            let n = c.file_normal;
            write!(
                f,
                ": the floor faces ({:.3}, {:.3}, {:.3}) in the file's frame, read as up axis {} \
                 and removed a tilt of {:.2}° (turned about ({:.3}, {:.3}, {:.3})); floor plane \
                 fitted on {:.1} m², rms {:.1} mm, net facing area {:.1} m², walls {:.1} m²",
                n.x,
                n.y,
                n.z,
                c.up_axis,
                l.tilt_deg,
                l.axis.x,
                l.axis.y,
                l.axis.z,
                c.area,
                c.rms * 1e3,
                c.facing_area,
                c.wall_area
            )?;
            match self.floor {
                Floor::Auto => write!(f, ", moved from {:.3} m to z = 0", l.height)?,
                Floor::Height(h) => write!(f, "; floor at z = {h} m")?,
                Floor::None => write!(f, ", at z = {:.3} m", l.height)?,
            }
            write!(f, "; same as [{}]", c.pick)?;
            return match &d.runner_up {
                Some(r) => write!(
                    f,
                    "; runner-up: {}, lost: {}",
                    r.describe(),
                    d.runner_up_lost
                ),
                None => write!(f, "; no runner-up ({})", d.runner_up_lost),
            };
        }
        match (&self.floor, &self.levelling) {
            (Floor::Auto, Some(l)) => write!(
                f,
                "; floor auto: removed a tilt of {:.2}° (turned about ({:.3}, {:.3}, {:.3})), \
                 floor moved from {:.3} m to z = 0 (plane fitted on {:.1} m², rms {:.1} mm)",
                l.tilt_deg,
                l.axis.x,
                l.axis.y,
                l.axis.z,
                l.height,
                l.area,
                l.rms * 1e3
            ),
            (Floor::Height(h), _) => write!(f, "; floor at z = {h} m"),
            _ => Ok(()),
        }
    }
}

impl Placement {
    /// The placement keys that are set, with their values (e.g. to refuse them where they do
    /// not apply).
    pub fn keys(&self) -> Vec<(&'static str, String)> {
        let mut keys = Vec::new();
        if let Some(up) = self.up_axis {
            keys.push(("up_axis", up.name().to_string()));
        }
        if let Some(t) = &self.transform {
            keys.push(("transform", t.to_string()));
        }
        if !self.floor.is_none() {
            keys.push(("floor", self.floor.to_string()));
        }
        keys
    }

    /// Places an in-memory scene whose vertices are in a file's frame: up axis (default z,
    /// i.e. as is), transform, floor. Returns what was done and any warnings (a floor height
    /// or start pose of the scene that could not be carried along).
    pub fn apply(&self, scene: &mut Scene) -> Result<(PlacementReport, Vec<LoadWarning>)> {
        let up = self.up_axis.unwrap_or(UpAxis::Z);
        for v in &mut scene.vertices {
            v.position = up.to_world(v.position);
        }
        let pre = Similarity3::from_parts(
            Translation3::identity(),
            UnitQuaternion::from_rotation_matrix(&up.rotation()),
            1.0,
        );
        self.finish(scene, up, &pre)
    }

    /// Applies the transform and the floor to `scene`, whose vertices already went through
    /// the up axis `up` (the loaders do that per vertex). `pre` is what the vertices went
    /// through and the scene's own floor height and start pose did not yet.
    pub(crate) fn finish(
        &self,
        scene: &mut Scene,
        up: UpAxis,
        pre: &Similarity3<f64>,
    ) -> Result<(PlacementReport, Vec<LoadWarning>)> {
        let name = scene.name.clone();
        let fail = |reason: String| SimError::Placement {
            scene: name.clone(),
            reason,
        };
        let mut total = *pre;
        if let Some(t) = &self.transform {
            let s = t.similarity().map_err(fail)?;
            transform_vertices(scene, &s);
            total = s * total;
        }
        let mut levelling = None;
        let mut auto_up = None;
        if let (UpAxis::Auto, Floor::Height(h)) = (up, self.floor)
            && !h.is_finite()
        {
            return Err(fail(format!("floor must be a finite height, got {h}")));
        }
        match self.floor {
            _ if up == UpAxis::Auto => {
                let decision = auto_up::find_up(scene, &total, self.transform.as_ref(), self.floor)
                    .map_err(|why| fail(format!("`up_axis: auto` {why}")))?;
                let c = &decision.chosen;
                // The rotation keeps the plane's offset: n·p = d becomes z = d.
                let down = if self.floor == Floor::Auto {
                    -c.offset
                } else {
                    0.0
                };
                let level =
                    Similarity3::from_parts(Translation3::new(0.0, 0.0, down), c.rotation, 1.0);
                transform_vertices(scene, &level);
                total = level * total;
                // The tilt is what is left after the nearest axis: turn about its axis.
                let residual = Rotation3::rotation_between(
                    &(c.up_axis.rotation() * c.file_normal),
                    &Vector3::z(),
                )
                .unwrap_or_else(Rotation3::identity);
                levelling = Some(Levelling {
                    tilt_deg: c.tilt_deg,
                    axis: residual.axis().map_or_else(Vector3::x, |a| a.into_inner()),
                    normal: c.normal,
                    height: c.offset,
                    area: c.area,
                    rms: c.rms,
                    transform: level,
                });
                auto_up = Some(decision);
            }
            Floor::Auto => {
                let plane = find_floor(scene).map_err(|why| {
                    fail(format!(
                        "`floor: auto` found no floor: {why}; check `up_axis` (which axis of the \
                         file points up: {}; now {up}) or use `floor: none`",
                        UpAxis::NAMES
                    ))
                })?;
                let rotation = Rotation3::rotation_between(&plane.normal, &Vector3::z())
                    .unwrap_or_else(Rotation3::identity);
                let level = Similarity3::from_parts(
                    Translation3::new(0.0, 0.0, -plane.offset),
                    UnitQuaternion::from_rotation_matrix(&rotation),
                    1.0,
                );
                transform_vertices(scene, &level);
                total = level * total;
                let axis = rotation.axis().map_or_else(Vector3::x, |a| a.into_inner());
                levelling = Some(Levelling {
                    tilt_deg: rotation.angle().to_degrees(),
                    axis,
                    normal: plane.normal,
                    height: plane.offset,
                    area: plane.area,
                    rms: plane.rms,
                    transform: level,
                });
            }
            Floor::Height(h) if !h.is_finite() => {
                return Err(fail(format!("floor must be a finite height, got {h}")));
            }
            _ => {}
        }
        let mut warnings = Vec::new();
        let mut warn = |message: String| {
            warnings.push(LoadWarning {
                file: PathBuf::from(&scene.name),
                message,
            })
        };
        let upright = (total.isometry.rotation * Vector3::z() - Vector3::z()).norm() < 1e-4;
        let own_floor = scene.floor_z;
        scene.floor_z = match self.floor {
            Floor::Auto => Some(0.0),
            Floor::Height(h) => Some(h),
            Floor::None => match own_floor {
                Some(z) if upright => Some((total * Point3::new(0.0, 0.0, z)).z),
                Some(z) => {
                    warn(format!(
                        "the scene's floor height {z} m is dropped: the placement tilts the \
                         floor (it is estimated from the placed mesh instead)"
                    ));
                    None
                }
                None => None,
            },
        };
        if let Some(start) = scene.start {
            scene.start = if upright {
                let p = total * Point3::new(start.x, start.y, own_floor.unwrap_or(0.0));
                let r = total.isometry.rotation.to_rotation_matrix();
                let yaw = start.yaw + r[(1, 0)].atan2(r[(0, 0)]);
                Some(PlanarPose::new(p.x, p.y, wrap_angle(yaw)))
            } else {
                warn(
                    "the scene's start pose is dropped: the placement tilts the floor (the \
                     start is derived from the placed navigable floor instead)"
                        .into(),
                );
                None
            };
        }
        let report = PlacementReport {
            scene: scene.name.clone(),
            up_axis: up,
            transform: self.transform,
            floor: self.floor,
            levelling,
            auto_up,
            floor_z: scene.floor_z,
        };
        Ok((report, warnings))
    }
}

/// `a` in (−π, π].
fn wrap_angle(a: f64) -> f64 {
    let pi = std::f64::consts::PI;
    let w = (a + pi).rem_euclid(2.0 * pi) - pi;
    if w == -pi { pi } else { w }
}

fn transform_vertices(scene: &mut Scene, s: &Similarity3<f64>) {
    for v in &mut scene.vertices {
        let [x, y, z] = v.position.map(|c| c as f64);
        let p = s * Point3::new(x, y, z);
        v.position = [p.x as f32, p.y as f32, p.z as f32];
    }
}

/// cos 30°: how far from +z a floor triangle's normal may point.
const UP_COS: f64 = 0.866_025_403_784_438_6;
/// Least floor area for [`Floor::Auto`], m².
const MIN_FLOOR_AREA: f64 = 1.0;
/// Largest distance of an inlier triangle's corners from a floor plane, metres.
const INLIER_DISTANCE: f64 = 0.03;
/// RANSAC hypotheses.
const RANSAC_ITERATIONS: usize = 400;
/// Candidates a hypothesis is scored on (an area-weighted sample when there are more).
const SCORING_SAMPLES: usize = 20_000;
/// Seed of the RANSAC draws (fixed: a file always levels the same way).
const RANSAC_SEED: u64 = 0x0066_6c6f_6f72;
/// Least-squares refinements (each re-selects the inliers of the refined plane).
const REFINEMENTS: usize = 4;

/// A triangle of the scene: corners, unit normal, area.
struct Patch {
    corners: [Vector3<f64>; 3],
    normal: Vector3<f64>,
    area: f64,
}

/// Every non-degenerate triangle of `scene` as a patch.
fn all_patches(scene: &Scene) -> Vec<Patch> {
    scene
        .triangles
        .iter()
        .filter_map(|t| {
            let [a, b, c] = scene.corners(t).map(|p| p.coords);
            let n = (b - a).cross(&(c - a));
            let len = n.norm();
            (len > 0.0 && len.is_finite()).then(|| Patch {
                corners: [a, b, c],
                normal: n / len,
                area: 0.5 * len,
            })
        })
        .collect()
}

/// A plane `normal · p = offset` and the surface that supports it.
struct FloorPlane {
    normal: Vector3<f64>,
    offset: f64,
    area: f64,
    rms: f64,
}

fn is_inlier(p: &Patch, normal: &Vector3<f64>, offset: f64) -> bool {
    p.normal.dot(normal) >= UP_COS
        && p.corners
            .iter()
            .all(|c| (normal.dot(c) - offset).abs() <= INLIER_DISTANCE)
}

/// The floor plane of `scene` (see [`Floor::Auto`]), or why there is none.
fn find_floor(scene: &Scene) -> std::result::Result<FloorPlane, String> {
    let bounds = scene.bounds().ok_or("the scene is empty")?;
    let height = bounds.max.z - bounds.min.z;
    let top = if height > 0.5 {
        bounds.min.z + 0.5 * height
    } else {
        f64::INFINITY
    };
    // Upward-facing triangles in the lower half.
    let patches: Vec<Patch> = all_patches(scene)
        .into_iter()
        .filter(|p| p.normal.z >= UP_COS && p.corners.iter().map(|c| c.z).sum::<f64>() / 3.0 <= top)
        .collect();
    let total: f64 = patches.iter().map(|p| p.area).sum();
    if total.is_nan() || total < MIN_FLOOR_AREA {
        return Err(format!(
            "only {total:.2} m² of upward-facing surface (normal within 30° of +z) in the lower \
             half of the scene, need at least {MIN_FLOOR_AREA} m²"
        ));
    }
    let mut cdf = Vec::with_capacity(patches.len());
    let mut acc = 0.0;
    for p in &patches {
        acc += p.area;
        cdf.push(acc);
    }
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(RANSAC_SEED);
    let pick = |rng: &mut rand_chacha::ChaCha8Rng| {
        let u = rng.random::<f64>() * acc;
        cdf.partition_point(|&c| c <= u).min(patches.len() - 1)
    };
    // Scoring set: every candidate with its area, or an area-weighted sample of equal weights.
    let scoring: Vec<(usize, f64)> = if patches.len() <= SCORING_SAMPLES {
        patches
            .iter()
            .enumerate()
            .map(|(i, p)| (i, p.area))
            .collect()
    } else {
        let w = total / SCORING_SAMPLES as f64;
        (0..SCORING_SAMPLES).map(|_| (pick(&mut rng), w)).collect()
    };
    let mut best: Option<(f64, Vector3<f64>, f64)> = None;
    for _ in 0..RANSAC_ITERATIONS {
        let q: [Vector3<f64>; 3] = std::array::from_fn(|_| {
            let p = &patches[pick(&mut rng)];
            let (mut u, mut v) = (rng.random::<f64>(), rng.random::<f64>());
            if u + v > 1.0 {
                (u, v) = (1.0 - u, 1.0 - v);
            }
            let [a, b, c] = p.corners;
            a + u * (b - a) + v * (c - a)
        });
        let n = (q[1] - q[0]).cross(&(q[2] - q[0]));
        let len = n.norm();
        if len.is_nan() || len <= 1e-12 {
            continue;
        }
        let n = if n.z < 0.0 { -n / len } else { n / len };
        if n.z < UP_COS {
            continue;
        }
        let d = n.dot(&q[0]);
        let score: f64 = scoring
            .iter()
            .filter(|(i, _)| is_inlier(&patches[*i], &n, d))
            .map(|(_, w)| w)
            .sum();
        if best.is_none_or(|(s, _, _)| score > s) {
            best = Some((score, n, d));
        }
    }
    let (_, normal, offset) = best.ok_or("no plane hypothesis within 30° of +z")?;
    let FloorPlane {
        normal,
        offset,
        area,
        rms,
    } = refine_plane(&patches, normal, offset, &Vector3::z(), REFINEMENTS);
    if area.is_nan() || area < MIN_FLOOR_AREA {
        let on_plane: f64 = patches
            .iter()
            .filter(|p| is_inlier(p, &normal, offset))
            .map(|p| p.area)
            .sum();
        return Err(format!(
            "the best plane among the {total:.2} m² of upward-facing surface in the lower half \
             of the scene holds only {on_plane:.2} m², need at least {MIN_FLOOR_AREA} m²"
        ));
    }
    Ok(FloorPlane {
        normal,
        offset,
        area,
        rms,
    })
}

/// Refines the plane `normal · p = offset` by area-weighted least squares on the patches lying
/// on it ([`is_inlier`]: exact second moments of the inlier triangles), re-selecting them
/// `rounds` times, the normal kept on the side of `facing` and within 30° of it. The plane
/// returned has `area` 0 when no round held [`MIN_FLOOR_AREA`] (the input plane unchanged).
fn refine_plane(
    patches: &[Patch],
    mut normal: Vector3<f64>,
    mut offset: f64,
    facing: &Vector3<f64>,
    rounds: usize,
) -> FloorPlane {
    let (mut area, mut rms) = (0.0, 0.0);
    for _ in 0..rounds {
        // Taken about a reference point on the plane for numerical range.
        let origin = offset * normal;
        let (mut a_sum, mut first, mut second) = (0.0, Vector3::zeros(), Matrix3::zeros());
        for p in patches.iter().filter(|p| is_inlier(p, &normal, offset)) {
            let [a, b, c] = p.corners.map(|v| v - origin);
            let g = (a + b + c) / 3.0;
            a_sum += p.area;
            first += p.area * g;
            second += (p.area / 12.0)
                * (a * a.transpose()
                    + b * b.transpose()
                    + c * c.transpose()
                    + 9.0 * g * g.transpose());
        }
        if a_sum.is_nan() || a_sum < MIN_FLOOR_AREA {
            break;
        }
        let mean = first / a_sum;
        let cov = second / a_sum - mean * mean.transpose();
        let eigen = cov.symmetric_eigen();
        let k = eigen.eigenvalues.imin();
        let n = eigen.eigenvectors.column(k).normalize();
        let n = if n.dot(facing) < 0.0 { -n } else { n };
        if n.dot(facing) < UP_COS {
            break;
        }
        normal = n;
        offset = n.dot(&(mean + origin));
        area = a_sum;
        rms = eigen.eigenvalues[k].max(0.0).sqrt();
    }
    FloorPlane {
        normal,
        offset,
        area,
        rms,
    }
}
