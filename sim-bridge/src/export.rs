//! Writes a [`Scene`] as a binary glTF 2.0 file (GLB), by hand: one mesh with a primitive per
//! material (POSITION, TEXCOORD_0, COLOR_0, u32 indices), PNG-embedded textures with their
//! wrap modes, unlit-friendly materials (metallic 0, roughness 1, double-sided). Positions are
//! converted from the z-up world to glTF's y-up: `(x, y, z) → (x, z, −y)`.

use crate::error::{Result, SimError};
use crate::load::UpAxis;
use crate::scene::{Scene, Wrap};
use serde_json::{Value, json};
use std::path::Path;

fn wrap_code(w: Wrap) -> u32 {
    match w {
        Wrap::Repeat => 10497,
        Wrap::ClampToEdge => 33071,
        Wrap::MirroredRepeat => 33648,
    }
}

/// Binary buffer under construction with 4-byte aligned views.
struct Bin {
    data: Vec<u8>,
    views: Vec<Value>,
}

impl Bin {
    fn view(&mut self, bytes: &[u8], target: Option<u32>) -> usize {
        while !self.data.len().is_multiple_of(4) {
            self.data.push(0);
        }
        let mut v = json!({"buffer": 0, "byteOffset": self.data.len(), "byteLength": bytes.len()});
        if let Some(t) = target {
            v["target"] = json!(t);
        }
        self.data.extend_from_slice(bytes);
        self.views.push(v);
        self.views.len() - 1
    }
}

/// Encodes `scene` as GLB bytes.
pub fn to_glb(scene: &Scene) -> Result<Vec<u8>> {
    scene.validate()?;
    let mut bin = Bin {
        data: Vec::new(),
        views: Vec::new(),
    };
    let mut images = Vec::new();
    let mut samplers = Vec::new();
    let mut textures = Vec::new();
    for (i, t) in scene.textures.iter().enumerate() {
        let mut png = Vec::new();
        let raw: Vec<u8> = t.texels.iter().flatten().copied().collect();
        image::ImageEncoder::write_image(
            image::codecs::png::PngEncoder::new(&mut png),
            &raw,
            t.width,
            t.height,
            image::ExtendedColorType::Rgb8,
        )
        .map_err(|e| SimError::Write {
            path: scene.name.clone().into(),
            reason: format!("texture {i} ({}): {e}", t.name),
        })?;
        let view = bin.view(&png, None);
        images.push(json!({"bufferView": view, "mimeType": "image/png", "name": t.name}));
        samplers.push(json!({"magFilter": 9729, "minFilter": 9729,
            "wrapS": wrap_code(t.wrap_u), "wrapT": wrap_code(t.wrap_v)}));
        textures.push(json!({"sampler": i, "source": i}));
    }
    let materials: Vec<Value> = scene
        .materials
        .iter()
        .map(|m| {
            let c = m.base_color;
            let mut pbr = json!({"baseColorFactor": [c[0], c[1], c[2], 1.0],
                "metallicFactor": 0.0, "roughnessFactor": 1.0});
            if let Some(t) = m.texture {
                pbr["baseColorTexture"] = json!({"index": t});
            }
            json!({"name": m.name, "pbrMetallicRoughness": pbr, "doubleSided": true})
        })
        .collect();

    let mut accessors = Vec::new();
    let mut primitives = Vec::new();
    for mi in 0..scene.materials.len() {
        let tris: Vec<_> = scene
            .triangles
            .iter()
            .filter(|t| t.material as usize == mi)
            .collect();
        if tris.is_empty() {
            continue;
        }
        let mut remap = std::collections::HashMap::new();
        let mut order = Vec::new();
        let mut indices = Vec::with_capacity(3 * tris.len());
        for t in &tris {
            for &v in &t.vertices {
                let next = order.len() as u32;
                let id = *remap.entry(v).or_insert_with(|| {
                    order.push(v);
                    next
                });
                indices.push(id);
            }
        }
        let (mut pos, mut uv, mut col) = (Vec::new(), Vec::new(), Vec::new());
        let (mut lo, mut hi) = ([f32::INFINITY; 3], [f32::NEG_INFINITY; 3]);
        for &v in &order {
            let vx = &scene.vertices[v as usize];
            let p = UpAxis::Y.from_world(vx.position);
            for k in 0..3 {
                lo[k] = lo[k].min(p[k]);
                hi[k] = hi[k].max(p[k]);
            }
            p.iter()
                .for_each(|c| pos.extend_from_slice(&c.to_le_bytes()));
            vx.uv
                .iter()
                .for_each(|c| uv.extend_from_slice(&c.to_le_bytes()));
            vx.color
                .iter()
                .for_each(|c| col.extend_from_slice(&c.to_le_bytes()));
        }
        let idx: Vec<u8> = indices.iter().flat_map(|i| i.to_le_bytes()).collect();
        let n = order.len();
        let mut add = |bytes: &[u8], target: u32, acc: Value| {
            let view = bin.view(bytes, Some(target));
            let mut a = acc;
            a["bufferView"] = json!(view);
            accessors.push(a);
            accessors.len() - 1
        };
        let p = add(
            &pos,
            34962,
            json!({"componentType": 5126, "count": n, "type": "VEC3", "min": lo, "max": hi}),
        );
        let t = add(
            &uv,
            34962,
            json!({"componentType": 5126, "count": n, "type": "VEC2"}),
        );
        let c = add(
            &col,
            34962,
            json!({"componentType": 5126, "count": n, "type": "VEC3"}),
        );
        let i = add(
            &idx,
            34963,
            json!({"componentType": 5125, "count": indices.len(), "type": "SCALAR"}),
        );
        primitives.push(
            json!({"attributes": {"POSITION": p, "TEXCOORD_0": t, "COLOR_0": c},
            "indices": i, "material": mi, "mode": 4}),
        );
    }
    while !bin.data.len().is_multiple_of(4) {
        bin.data.push(0);
    }
    let mut root = json!({
        "asset": {"version": "2.0", "generator": "activemap-sim"},
        "scene": 0,
        "scenes": [{"nodes": [0]}],
        "nodes": [{"mesh": 0, "name": scene.name}],
        "meshes": [{"primitives": primitives}],
        "materials": materials,
        "accessors": accessors,
        "bufferViews": bin.views,
        "buffers": [{"byteLength": bin.data.len()}],
    });
    if !images.is_empty() {
        root["images"] = json!(images);
        root["samplers"] = json!(samplers);
        root["textures"] = json!(textures);
    }
    let mut json_bytes = serde_json::to_vec(&root).map_err(|e| SimError::Write {
        path: scene.name.clone().into(),
        reason: e.to_string(),
    })?;
    while json_bytes.len() % 4 != 0 {
        json_bytes.push(b' ');
    }
    let total = 12 + 8 + json_bytes.len() + 8 + bin.data.len();
    let mut out = Vec::with_capacity(total);
    out.extend_from_slice(b"glTF");
    out.extend_from_slice(&2u32.to_le_bytes());
    out.extend_from_slice(&(total as u32).to_le_bytes());
    out.extend_from_slice(&(json_bytes.len() as u32).to_le_bytes());
    out.extend_from_slice(b"JSON");
    out.extend_from_slice(&json_bytes);
    out.extend_from_slice(&(bin.data.len() as u32).to_le_bytes());
    out.extend_from_slice(b"BIN\0");
    out.extend_from_slice(&bin.data);
    Ok(out)
}

/// Writes `scene` to `path` as GLB.
pub fn write_glb(scene: &Scene, path: &Path) -> Result<()> {
    let bytes = to_glb(scene)?;
    std::fs::write(path, bytes).map_err(|e| SimError::Write {
        path: path.to_path_buf(),
        reason: e.to_string(),
    })
}
