//! Entry points of the fuzz targets (`fuzz/`) and their regression replay test: each feeds
//! arbitrary bytes to a scene loader and ignores the result. Not part of the public API.

use crate::load::{LoadOptions, SceneFormat, load_scene_bytes};
use std::path::Path;

/// Loads `data` as a scene file of format `format` with default options, reading no other
/// file. Malformed input must give an error, never a panic.
pub fn scene(format: SceneFormat, data: &[u8]) {
    let name = match format {
        SceneFormat::Gltf => "fuzz-input.glb",
        SceneFormat::Obj => "fuzz-input.obj",
        SceneFormat::Ply => "fuzz-input.ply",
    };
    let _ = load_scene_bytes(data, format, Path::new(name), None, &LoadOptions::default());
}

/// For the fuzz targets, whose libFuzzer panic hook aborts at once: wraps the hook (the first
/// call only) so that a panic located in a format crate the loaders guard with `catch_unwind`
/// (`gltf`, `tobj`) unwinds to the loader, which turns it into an error; any other panic still
/// reaches libFuzzer's hook and is a crash.
pub fn let_guarded_crates_unwind() {
    static ONCE: std::sync::Once = std::sync::Once::new();
    ONCE.call_once(|| {
        let fuzzer_hook = std::panic::take_hook();
        std::panic::set_hook(Box::new(move |info| {
            let file = info.location().map_or("", |l| l.file());
            let guarded = ["/gltf-", "/tobj-"].iter().any(|c| file.contains(c));
            if !guarded {
                fuzzer_hook(info);
            }
        }));
    });
}
