#![no_main]
//! PLY scene files (`load::load_scene_bytes`, which `load_scene` calls).
use activemap_sim::load::SceneFormat;
libfuzzer_sys::fuzz_target!(|data: &[u8]| activemap_sim::fuzzing::scene(SceneFormat::Ply, data));
