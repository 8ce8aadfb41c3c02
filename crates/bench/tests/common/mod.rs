//! Shared by the bench crate's tests: the SLAM settings of the repository's `dataflow.yaml`
//! (the README's main flow), as its `tracker` and `mapper` operators build them.

use activemap_slam::SlamConfig;

/// The `tracker` and `mapper` node configs of the repository's `dataflow.yaml`.
pub fn flow_slam_nodes() -> (
    activemap_operators::tracker::Config,
    activemap_operators::mapper::Config,
) {
    let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../../dataflow.yaml");
    let flow = activemap_runtime::dataflow::Dataflow::load(&path, &activemap_operators::catalog())
        .unwrap_or_else(|d| panic!("{}: {d}", path.display()));
    activemap_operators::mapper::slam_nodes(&flow).expect("tracker and mapper nodes")
}

/// The SLAM settings of the repository's `dataflow.yaml`.
#[allow(dead_code)] // Not every test binary uses both helpers.
pub fn flow_slam_config() -> SlamConfig {
    let (tracker, mapper) = flow_slam_nodes();
    activemap_operators::mapper::slam_config(&tracker, &mapper).expect("SLAM config")
}
