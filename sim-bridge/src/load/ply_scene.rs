//! PLY loading (ASCII and binary) with `ply-rs`: a `vertex` element with x, y, z and optional
//! red/green/blue (8-bit or float; also `diffuse_red`…), and a `face` element whose
//! `vertex_indices` (or `vertex_index`) lists are fan-triangulated. Z-up by default.

use super::{LoadOptions, UpAxis};
use crate::error::{Result, SimError};
use crate::scene::{Material, Scene, Triangle, Vertex};
use ply_rs::ply::Property;
use std::path::Path;

fn scalar(p: &Property) -> Option<f64> {
    Some(match *p {
        Property::Char(v) => v as f64,
        Property::UChar(v) => v as f64,
        Property::Short(v) => v as f64,
        Property::UShort(v) => v as f64,
        Property::Int(v) => v as f64,
        Property::UInt(v) => v as f64,
        Property::Float(v) => v as f64,
        Property::Double(v) => v,
        _ => return None,
    })
}

fn colour(p: &Property) -> Option<f32> {
    match *p {
        Property::Float(v) => Some(v),
        Property::Double(v) => Some(v as f32),
        ref other => scalar(other).map(|v| (v / 255.0) as f32),
    }
}

fn index_list(p: &Property) -> Option<Vec<i64>> {
    Some(match p {
        Property::ListChar(v) => v.iter().map(|&x| x as i64).collect(),
        Property::ListUChar(v) => v.iter().map(|&x| x as i64).collect(),
        Property::ListShort(v) => v.iter().map(|&x| x as i64).collect(),
        Property::ListUShort(v) => v.iter().map(|&x| x as i64).collect(),
        Property::ListInt(v) => v.iter().map(|&x| x as i64).collect(),
        Property::ListUInt(v) => v.iter().map(|&x| x as i64).collect(),
        _ => return None,
    })
}

/// Checks the header's `format` and `element` lines before `ply-rs` reads them: its grammar
/// panics on a run of digits there (the version's `MAJOR.MINOR`, an element count) that does
/// not fit in 64 bits, and it allocates an element per count even when no data follows. Every
/// element takes at least one byte of the file (its ASCII line, or a binary property), so a
/// count above the file's size is refused.
fn check_header_numbers(bytes: &[u8]) -> std::result::Result<(), String> {
    for (no, line) in bytes.split(|&b| b == b'\n').enumerate() {
        let line = String::from_utf8_lossy(line);
        let words: Vec<&str> = line.split_whitespace().collect();
        match words.first().copied() {
            Some("end_header") => break,
            Some(keyword @ ("format" | "element")) => {
                let too_long = line
                    .split(|c: char| !c.is_ascii_digit())
                    .find(|run| !run.is_empty() && run.parse::<u64>().is_err());
                if let Some(run) = too_long {
                    return Err(format!(
                        "header line {}: number {run} of the `{keyword}` line does not fit in 64 bits",
                        no + 1
                    ));
                }
                if let ["element", name, count] = words.as_slice()
                    && count.parse::<u64>().is_ok_and(|n| n > bytes.len() as u64)
                {
                    return Err(format!(
                        "header line {}: element `{name}` declares {count} items, more than the file's {} bytes can hold",
                        no + 1,
                        bytes.len()
                    ));
                }
            }
            _ => {}
        }
    }
    Ok(())
}

/// Loads a `.ply` file already read into `bytes`.
pub(super) fn load(path: &Path, bytes: &[u8], options: &LoadOptions) -> Result<Scene> {
    let malformed = |reason: String| SimError::Malformed {
        format: "PLY",
        path: path.to_path_buf(),
        reason,
    };
    let up = options.placement.up_axis.unwrap_or(UpAxis::Z);
    check_header_numbers(bytes).map_err(malformed)?;
    let parser = ply_rs::parser::Parser::<ply_rs::ply::DefaultElement>::new();
    let mut reader = std::io::Cursor::new(bytes);
    let ply = parser
        .read_ply(&mut reader)
        .map_err(|e| malformed(e.to_string()))?;
    let vertices = ply
        .payload
        .get("vertex")
        .ok_or_else(|| malformed("no `vertex` element".into()))?;
    let faces = ply
        .payload
        .get("face")
        .ok_or_else(|| malformed("no `face` element (point clouds are not scenes)".into()))?;
    let mut scene = Scene {
        name: path.display().to_string(),
        ..Scene::default()
    };
    for (i, v) in vertices.iter().enumerate() {
        let coord = |k: &str| {
            v.get(k)
                .and_then(scalar)
                .ok_or_else(|| malformed(format!("vertex {i} has no numeric `{k}`")))
        };
        let p = [coord("x")? as f32, coord("y")? as f32, coord("z")? as f32];
        let chan = |names: [&str; 2]| names.iter().find_map(|n| v.get(*n)).and_then(colour);
        let color = match (
            chan(["red", "diffuse_red"]),
            chan(["green", "diffuse_green"]),
            chan(["blue", "diffuse_blue"]),
        ) {
            (Some(r), Some(g), Some(b)) => [r, g, b],
            _ => [1.0; 3],
        };
        scene.vertices.push(Vertex {
            position: up.to_world(p),
            uv: [0.0; 2],
            color,
        });
    }
    scene.materials.push(Material {
        name: "vertex colours".into(),
        base_color: [1.0; 3],
        texture: None,
    });
    let n = scene.vertices.len() as i64;
    for (fi, f) in faces.iter().enumerate() {
        let list = f
            .get("vertex_indices")
            .or_else(|| f.get("vertex_index"))
            .and_then(index_list)
            .ok_or_else(|| malformed(format!("face {fi} has no `vertex_indices` list")))?;
        if let Some(bad) = list.iter().find(|&&i| i < 0 || i >= n) {
            return Err(malformed(format!(
                "face {fi} references vertex {bad} of {n}"
            )));
        }
        for k in 2..list.len() {
            scene.triangles.push(Triangle {
                vertices: [list[0] as u32, list[k - 1] as u32, list[k] as u32],
                material: 0,
            });
        }
    }
    Ok(scene)
}
