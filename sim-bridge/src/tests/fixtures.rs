//! Small hand-built scenes with known geometry.

use crate::scene::{Material, Scene, Texture, Triangle, Vertex};

/// Appends a quad (corners in order) with the given uvs and material.
pub fn push_quad(s: &mut Scene, p: [[f32; 3]; 4], uv: [[f32; 2]; 4], material: u32) {
    let base = s.vertices.len() as u32;
    for k in 0..4 {
        s.vertices.push(Vertex {
            position: p[k],
            uv: uv[k],
            color: [1.0; 3],
        });
    }
    for t in [[0, 1, 2], [0, 2, 3]] {
        s.triangles.push(Triangle {
            vertices: t.map(|i| base + i),
            material,
        });
    }
}

/// Appends a quad (corners in order, no uvs) wound so that its surface faces `facing`.
pub fn facing_quad(s: &mut Scene, mut p: [[f32; 3]; 4], facing: [f64; 3], material: u32) {
    let v = |q: [f32; 3]| nalgebra::Vector3::new(q[0] as f64, q[1] as f64, q[2] as f64);
    let normal = (v(p[1]) - v(p[0])).cross(&(v(p[2]) - v(p[0])));
    if normal.dot(&nalgebra::Vector3::from(facing)) < 0.0 {
        p.reverse();
    }
    push_quad(s, p, [[0.0; 2]; 4], material);
}

/// Writes `scene` as an OBJ file (positions and faces only).
pub fn write_obj(path: &std::path::Path, scene: &Scene) {
    use std::fmt::Write as _;
    let mut text = String::new();
    for v in &scene.vertices {
        let p = v.position;
        writeln!(text, "v {:.7} {:.7} {:.7}", p[0], p[1], p[2]).unwrap();
    }
    for t in &scene.triangles {
        let [a, b, c] = t.vertices.map(|i| i + 1);
        writeln!(text, "f {a} {b} {c}").unwrap();
    }
    std::fs::write(path, text).unwrap();
}

/// Flat-coloured material.
pub fn flat(s: &mut Scene, rgb: [f32; 3]) -> u32 {
    s.materials.push(Material {
        name: format!("{rgb:?}"),
        base_color: rgb,
        texture: None,
    });
    (s.materials.len() - 1) as u32
}

/// The six faces of the box [lo, hi] (each face a different flat colour), floor included.
pub fn box_room(lo: [f32; 3], hi: [f32; 3]) -> Scene {
    let mut s = Scene {
        name: "box room".into(),
        ..Scene::default()
    };
    let colours = [
        [1.0, 0.0, 0.0],
        [0.0, 1.0, 0.0],
        [0.0, 0.0, 1.0],
        [1.0, 1.0, 0.0],
        [0.5, 0.5, 0.5],
        [1.0, 1.0, 1.0],
    ];
    let m: Vec<u32> = colours.iter().map(|c| flat(&mut s, *c)).collect();
    add_box_faces(&mut s, lo, hi, &m);
    s
}

/// Adds the six faces of the box [lo, hi]; materials in the order −x, +x, −y, +y, −z, +z.
pub fn add_box_faces(s: &mut Scene, lo: [f32; 3], hi: [f32; 3], m: &[u32]) {
    let uv = [[0.0, 0.0], [1.0, 0.0], [1.0, 1.0], [0.0, 1.0]];
    let (a, b) = (lo, hi);
    push_quad(
        s,
        [
            [a[0], a[1], a[2]],
            [a[0], b[1], a[2]],
            [a[0], b[1], b[2]],
            [a[0], a[1], b[2]],
        ],
        uv,
        m[0],
    );
    push_quad(
        s,
        [
            [b[0], a[1], a[2]],
            [b[0], b[1], a[2]],
            [b[0], b[1], b[2]],
            [b[0], a[1], b[2]],
        ],
        uv,
        m[1],
    );
    push_quad(
        s,
        [
            [a[0], a[1], a[2]],
            [b[0], a[1], a[2]],
            [b[0], a[1], b[2]],
            [a[0], a[1], b[2]],
        ],
        uv,
        m[2],
    );
    push_quad(
        s,
        [
            [a[0], b[1], a[2]],
            [b[0], b[1], a[2]],
            [b[0], b[1], b[2]],
            [a[0], b[1], b[2]],
        ],
        uv,
        m[3],
    );
    push_quad(
        s,
        [
            [a[0], a[1], a[2]],
            [b[0], a[1], a[2]],
            [b[0], b[1], a[2]],
            [a[0], b[1], a[2]],
        ],
        uv,
        m[4],
    );
    push_quad(
        s,
        [
            [a[0], a[1], b[2]],
            [b[0], a[1], b[2]],
            [b[0], b[1], b[2]],
            [a[0], b[1], b[2]],
        ],
        uv,
        m[5],
    );
}

/// A 4×4 texture whose texel (i, j) has colour (40·i + 20, 40·j + 20, 200).
pub fn gradient_texture() -> Texture {
    let mut texels = Vec::new();
    for j in 0..4u8 {
        for i in 0..4u8 {
            texels.push([40 * i + 20, 40 * j + 20, 200]);
        }
    }
    Texture {
        name: "gradient".into(),
        width: 4,
        height: 4,
        texels,
        wrap_u: crate::Wrap::ClampToEdge,
        wrap_v: crate::Wrap::ClampToEdge,
    }
}
