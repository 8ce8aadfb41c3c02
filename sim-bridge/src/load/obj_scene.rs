//! Wavefront OBJ + MTL loading with `tobj`: polygons are triangulated, `Kd` gives the flat
//! colour and `map_Kd` the texture (JPEG or PNG, relative to the OBJ's folder). OBJ texture
//! coordinates have v up, so v is flipped to the scene's top-left convention. Material
//! libraries and textures are read relative to a base folder, and not at all without one.

use super::{LoadOptions, LoadWarning, UpAxis, panic_message, texture_from_image};
use crate::error::{Result, SimError};
use crate::scene::{Material, Scene, Triangle, Vertex, Wrap};
use std::collections::HashMap;
use std::path::{Path, PathBuf};

/// Loads an `.obj` file already read into `bytes` (and its `.mtl` and textures, relative to
/// `base`).
pub(super) fn load(
    path: &Path,
    bytes: &[u8],
    base: Option<&Path>,
    options: &LoadOptions,
    warnings: &mut Vec<LoadWarning>,
) -> Result<Scene> {
    let up = options.placement.up_axis.unwrap_or(UpAxis::Y);
    let opts = tobj::LoadOptions {
        single_index: true,
        triangulate: true,
        ..Default::default()
    };
    let malformed = |reason: String| SimError::Malformed {
        format: "OBJ",
        path: path.to_path_buf(),
        reason,
    };
    // `tobj` overflows (a panic with overflow checks, as in tests) on a face index far out of
    // range; such a panic becomes an error naming it.
    let parsed = std::panic::catch_unwind(|| {
        let mut reader = std::io::Cursor::new(bytes);
        tobj::load_obj_buf(&mut reader, &opts, |mtl| match base {
            Some(base) => tobj::load_mtl(base.join(mtl)),
            None => Err(tobj::LoadError::OpenFileFailed),
        })
    });
    let (models, materials) = parsed
        .map_err(|panic| malformed(format!("invalid face index ({})", panic_message(&*panic))))?
        .map_err(|e| malformed(e.to_string()))?;
    let obj_materials = match materials {
        Ok(m) => m,
        Err(e) => {
            warnings.push(LoadWarning {
                file: path.to_path_buf(),
                message: format!("material library cannot be loaded ({e}); using grey"),
            });
            Vec::new()
        }
    };
    let mut scene = Scene {
        name: path.display().to_string(),
        ..Scene::default()
    };
    let mut texture_of: HashMap<String, Option<u32>> = HashMap::new();
    for m in &obj_materials {
        let mut texture = None;
        if let Some(file) = m.diffuse_texture.as_deref().filter(|f| !f.is_empty()) {
            texture = *texture_of.entry(file.to_string()).or_insert_with(|| {
                let file = file.replace('\\', "/");
                let tex_path = base.map_or_else(|| PathBuf::from(&file), |b| b.join(&file));
                let image = match base {
                    Some(_) => image::open(&tex_path),
                    None => Err(image::ImageError::IoError(std::io::Error::new(
                        std::io::ErrorKind::Unsupported,
                        "no folder to read external files from",
                    ))),
                };
                match image {
                    Ok(img) => {
                        scene.textures.push(texture_from_image(
                            tex_path.display().to_string(),
                            img,
                            Wrap::Repeat,
                            Wrap::Repeat,
                        ));
                        Some((scene.textures.len() - 1) as u32)
                    }
                    Err(e) => {
                        warnings.push(LoadWarning {
                            file: path.to_path_buf(),
                            message: format!(
                                "texture {} of material {} cannot be loaded ({e}); using its flat colour",
                                tex_path.display(),
                                m.name
                            ),
                        });
                        None
                    }
                }
            });
        }
        scene.materials.push(Material {
            name: m.name.clone(),
            base_color: m.diffuse.unwrap_or([0.8; 3]),
            texture,
        });
    }
    let mut default_material = None;
    for model in &models {
        let mesh = &model.mesh;
        let n = mesh.positions.len() / 3;
        let material = match mesh.material_id.filter(|&i| i < scene.materials.len()) {
            Some(i) => i as u32,
            None => *default_material.get_or_insert_with(|| {
                scene.materials.push(Material {
                    name: "default".into(),
                    base_color: [0.8; 3],
                    texture: None,
                });
                (scene.materials.len() - 1) as u32
            }),
        };
        let first = scene.vertices.len() as u32;
        for i in 0..n {
            let p = [
                mesh.positions[3 * i],
                mesh.positions[3 * i + 1],
                mesh.positions[3 * i + 2],
            ];
            let uv = if mesh.texcoords.len() >= 2 * n {
                [mesh.texcoords[2 * i], 1.0 - mesh.texcoords[2 * i + 1]]
            } else {
                [0.0; 2]
            };
            let color = if mesh.vertex_color.len() >= 3 * n {
                [
                    mesh.vertex_color[3 * i],
                    mesh.vertex_color[3 * i + 1],
                    mesh.vertex_color[3 * i + 2],
                ]
            } else {
                [1.0; 3]
            };
            scene.vertices.push(Vertex {
                position: up.to_world(p),
                uv,
                color,
            });
        }
        for c in mesh.indices.chunks_exact(3) {
            if c.iter().any(|&i| i as usize >= n) {
                return Err(SimError::Malformed {
                    format: "OBJ",
                    path: path.to_path_buf(),
                    reason: format!("object {} has a face index out of range", model.name),
                });
            }
            scene.triangles.push(Triangle {
                vertices: [first + c[0], first + c[1], first + c[2]],
                material,
            });
        }
    }
    Ok(scene)
}
