#![no_main]
//! OBJ scene files (`load::load_scene_bytes`, which `load_scene` calls). The loader turns a
//! panic of the `tobj` crate into an error; see `fuzzing::let_guarded_crates_unwind`.
use activemap_sim::load::SceneFormat;

libfuzzer_sys::fuzz_target!(|data: &[u8]| {
    activemap_sim::fuzzing::let_guarded_crates_unwind();
    activemap_sim::fuzzing::scene(SceneFormat::Obj, data);
});
