//! Replays the fuzz targets' saved inputs (the regression inputs under
//! `tests/data/fuzz-regressions/<target>/` and the seed corpus `fuzz/corpus/<target>/seed-*`)
//! through the entry points the fuzz targets call: each must return, an error or not, without
//! panicking. The `llm_reply` target is replayed by `activemap-llm`'s own test.

use activemap_sim::load::SceneFormat;
use activemap_splat::fuzzing::replay;
use std::sync::LazyLock;

/// A fuzz target's name and the function it feeds its input to.
type Target<'a> = (&'static str, &'a dyn Fn(&[u8]));

static CATALOG: LazyLock<Vec<activemap_runtime::OperatorDescriptor>> =
    LazyLock::new(activemap_operators::catalog);

#[test]
fn fuzz_regressions_replay_without_panics() {
    use activemap_runtime::fuzzing as rt;
    let targets: [Target; 8] = [
        ("yaml", &rt::yaml),
        ("dataflow", &|d| rt::dataflow(&CATALOG, d)),
        ("delta", &rt::delta),
        ("ply_map", &activemap_splat::fuzzing::ply_map),
        ("scene_obj", &|d| {
            activemap_sim::fuzzing::scene(SceneFormat::Obj, d)
        }),
        ("scene_gltf", &|d| {
            activemap_sim::fuzzing::scene(SceneFormat::Gltf, d)
        }),
        ("scene_ply", &|d| {
            activemap_sim::fuzzing::scene(SceneFormat::Ply, d)
        }),
        ("payload_views", &activemap_schemas::fuzzing::payload),
    ];
    for (target, run) in targets {
        let n = replay(target, run);
        assert!(
            n > 0,
            "fuzz target {target} has no seed or regression input"
        );
    }
}
