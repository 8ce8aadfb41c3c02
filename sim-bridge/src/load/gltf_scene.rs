//! glTF 2.0 / GLB loading with the `gltf` crate: node transforms, indexed triangles (strips
//! and fans are converted), base colour factor and texture with its sampler's wrap modes,
//! vertex colours (COLOR_0). Positions are converted from glTF's y-up to the z-up world.

use super::{LoadOptions, LoadWarning, UpAxis, panic_message, texture_from_image};
use crate::error::{Result, SimError};
use crate::scene::{Material, Scene, Triangle, Vertex, Wrap};
use gltf::mesh::Mode;
use nalgebra::{Matrix4, Point3};
use std::collections::HashMap;
use std::path::Path;

fn wrap_mode(w: gltf::texture::WrappingMode) -> Wrap {
    match w {
        gltf::texture::WrappingMode::ClampToEdge => Wrap::ClampToEdge,
        gltf::texture::WrappingMode::MirroredRepeat => Wrap::MirroredRepeat,
        gltf::texture::WrappingMode::Repeat => Wrap::Repeat,
    }
}

fn image_to_dynamic(data: &gltf::image::Data) -> Option<image::DynamicImage> {
    use gltf::image::Format as F;
    let (w, h) = (data.width, data.height);
    let px = data.pixels.clone();
    match data.format {
        F::R8 => image::GrayImage::from_raw(w, h, px).map(image::DynamicImage::ImageLuma8),
        F::R8G8 => image::GrayAlphaImage::from_raw(w, h, px).map(image::DynamicImage::ImageLumaA8),
        F::R8G8B8 => image::RgbImage::from_raw(w, h, px).map(image::DynamicImage::ImageRgb8),
        F::R8G8B8A8 => image::RgbaImage::from_raw(w, h, px).map(image::DynamicImage::ImageRgba8),
        _ => {
            // 16-bit and float formats: keep the high byte of each 16-bit channel, or scale floats.
            let channels = match data.format {
                F::R16 => 1,
                F::R16G16 => 2,
                F::R16G16B16 | F::R32G32B32FLOAT => 3,
                _ => 4,
            };
            let is_float = matches!(data.format, F::R32G32B32FLOAT | F::R32G32B32A32FLOAT);
            let n = (w * h) as usize;
            let mut rgb = Vec::with_capacity(3 * n);
            for i in 0..n {
                let chan = |c: usize| -> u8 {
                    let c = c.min(channels - 1);
                    let read = || -> Option<u8> {
                        if is_float {
                            let o = 4 * (i * channels + c);
                            let v = f32::from_le_bytes(data.pixels.get(o..o + 4)?.try_into().ok()?);
                            Some((v.clamp(0.0, 1.0) * 255.0 + 0.5) as u8)
                        } else {
                            let o = 2 * (i * channels + c);
                            let v = u16::from_le_bytes(data.pixels.get(o..o + 2)?.try_into().ok()?);
                            Some((v >> 8) as u8)
                        }
                    };
                    read().unwrap_or(0)
                };
                let grey = channels < 3;
                rgb.extend_from_slice(&if grey {
                    [chan(0); 3]
                } else {
                    [chan(0), chan(1), chan(2)]
                });
            }
            image::RgbImage::from_raw(w, h, rgb).map(image::DynamicImage::ImageRgb8)
        }
    }
}

/// Loads a `.gltf` or `.glb` file already read into `bytes`, its external buffers and images
/// relative to `base` (none read without one). The `gltf` crate can panic on some invalid
/// indices during validation; such a panic becomes a [`SimError::Malformed`].
pub(super) fn load(
    path: &Path,
    bytes: &[u8],
    base: Option<&Path>,
    options: &LoadOptions,
    warnings: &mut Vec<LoadWarning>,
) -> Result<Scene> {
    let outcome = std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| {
        load_checked(path, bytes, base, options, warnings)
    }));
    outcome.unwrap_or_else(|panic| {
        Err(SimError::Malformed {
            format: "glTF",
            path: path.to_path_buf(),
            reason: format!("invalid document ({})", panic_message(&*panic)),
        })
    })
}

fn load_checked(
    path: &Path,
    bytes: &[u8],
    base: Option<&Path>,
    options: &LoadOptions,
    warnings: &mut Vec<LoadWarning>,
) -> Result<Scene> {
    let malformed = |reason: String| SimError::Malformed {
        format: "glTF",
        path: path.to_path_buf(),
        reason,
    };
    let up = options.placement.up_axis.unwrap_or(UpAxis::Y);
    let gltf = gltf::Gltf::from_slice(bytes).map_err(|e| malformed(e.to_string()))?;
    let document = gltf.document;
    let buffers = gltf::import_buffers(&document, base, gltf.blob)
        .map_err(|e| malformed(format!("buffer data: {e}")))?;
    for (i, b) in document.buffers().enumerate() {
        if buffers[i].len() < b.length() {
            return Err(malformed(format!("buffer {i} is shorter than declared")));
        }
    }

    // Decode images; a failing one leaves its materials untextured, with a warning.
    let mut images: Vec<Option<image::DynamicImage>> = Vec::new();
    for image in document.images() {
        let label = match image.source() {
            gltf::image::Source::Uri { uri, .. } => uri.chars().take(80).collect::<String>(),
            gltf::image::Source::View { .. } => format!("embedded image {}", image.index()),
        };
        match gltf::image::Data::from_source(image.source(), base, &buffers) {
            Ok(data) => images.push(image_to_dynamic(&data)),
            Err(e) => {
                warnings.push(LoadWarning {
                    file: path.to_path_buf(),
                    message: format!(
                        "texture {label} cannot be loaded ({e}); using the flat base colour"
                    ),
                });
                images.push(None);
            }
        }
    }

    let mut scene = Scene {
        name: path.display().to_string(),
        ..Scene::default()
    };
    // One scene material per glTF material (plus a default grey one, created on demand).
    let mut texture_of: HashMap<(usize, Wrap, Wrap), u32> = HashMap::new();
    let mut material_tex_coord = Vec::new();
    for m in document.materials() {
        let pbr = m.pbr_metallic_roughness();
        let f = pbr.base_color_factor();
        let mut texture = None;
        let mut tex_coord = 0;
        if let Some(info) = pbr.base_color_texture() {
            let tex = info.texture();
            let image_index = tex.source().index();
            let sampler = tex.sampler();
            let (wu, wv) = (wrap_mode(sampler.wrap_s()), wrap_mode(sampler.wrap_t()));
            tex_coord = info.tex_coord();
            if let Some(Some(img)) = images.get(image_index) {
                let key = (image_index, wu, wv);
                let id = *texture_of.entry(key).or_insert_with(|| {
                    scene.textures.push(texture_from_image(
                        format!("{}#image{image_index}", path.display()),
                        img.clone(),
                        wu,
                        wv,
                    ));
                    (scene.textures.len() - 1) as u32
                });
                texture = Some(id);
            }
        }
        scene.materials.push(Material {
            name: m.name().unwrap_or("material").to_string(),
            base_color: [f[0], f[1], f[2]],
            texture,
        });
        material_tex_coord.push(tex_coord);
    }
    let mut default_material = None;

    let gltf_scene = document
        .default_scene()
        .or_else(|| document.scenes().next())
        .ok_or_else(|| malformed("the file holds no scene".into()))?;
    let mut stack: Vec<(gltf::Node, Matrix4<f32>)> = gltf_scene
        .nodes()
        .map(|n| (n, Matrix4::identity()))
        .collect();
    while let Some((node, parent)) = stack.pop() {
        let local = Matrix4::from(node.transform().matrix());
        let world = parent * local;
        for child in node.children() {
            stack.push((child, world));
        }
        let Some(mesh) = node.mesh() else { continue };
        for prim in mesh.primitives() {
            let mode = prim.mode();
            if !matches!(
                mode,
                Mode::Triangles | Mode::TriangleStrip | Mode::TriangleFan
            ) {
                warnings.push(LoadWarning {
                    file: path.to_path_buf(),
                    message: format!("mesh {} has a {mode:?} primitive; skipped", mesh.index()),
                });
                continue;
            }
            let reader = prim.reader(|b| buffers.get(b.index()).map(|d| &d.0[..]));
            let Some(positions) = reader.read_positions() else {
                return Err(malformed(format!(
                    "mesh {} has a primitive without POSITION",
                    mesh.index()
                )));
            };
            let positions: Vec<[f32; 3]> = positions.collect();
            let material = match prim.material().index() {
                Some(i) => i as u32,
                None => *default_material.get_or_insert_with(|| {
                    scene.materials.push(Material {
                        name: "default".into(),
                        base_color: [1.0; 3],
                        texture: None,
                    });
                    material_tex_coord.push(0);
                    (scene.materials.len() - 1) as u32
                }),
            };
            let set = material_tex_coord[material as usize];
            let uvs: Option<Vec<[f32; 2]>> =
                reader.read_tex_coords(set).map(|t| t.into_f32().collect());
            let colors: Option<Vec<[f32; 3]>> =
                reader.read_colors(0).map(|c| c.into_rgb_f32().collect());
            let base = scene.vertices.len() as u32;
            for (i, p) in positions.iter().enumerate() {
                let q = world.transform_point(&Point3::new(p[0], p[1], p[2]));
                scene.vertices.push(Vertex {
                    position: up.to_world([q.x, q.y, q.z]),
                    uv: uvs
                        .as_ref()
                        .and_then(|u| u.get(i).copied())
                        .unwrap_or([0.0; 2]),
                    color: colors
                        .as_ref()
                        .and_then(|c| c.get(i).copied())
                        .unwrap_or([1.0; 3]),
                });
            }
            let indices: Vec<u32> = match reader.read_indices() {
                Some(ix) => ix.into_u32().collect(),
                None => (0..positions.len() as u32).collect(),
            };
            if let Some(&bad) = indices.iter().find(|&&i| i as usize >= positions.len()) {
                return Err(malformed(format!(
                    "mesh {} index {bad} is out of range ({} vertices)",
                    mesh.index(),
                    positions.len()
                )));
            }
            let corners: Vec<[u32; 3]> = match mode {
                Mode::Triangles => indices
                    .chunks_exact(3)
                    .map(|c| [c[0], c[1], c[2]])
                    .collect(),
                Mode::TriangleStrip => (2..indices.len())
                    .map(|i| {
                        if i % 2 == 0 {
                            [indices[i - 2], indices[i - 1], indices[i]]
                        } else {
                            [indices[i - 1], indices[i - 2], indices[i]]
                        }
                    })
                    .collect(),
                _ => (2..indices.len())
                    .map(|i| [indices[0], indices[i - 1], indices[i]])
                    .collect(),
            };
            scene
                .triangles
                .extend(corners.into_iter().map(|c| Triangle {
                    vertices: c.map(|i| base + i),
                    material,
                }));
        }
    }
    Ok(scene)
}
