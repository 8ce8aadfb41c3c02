//! The transport benchmark, run by hand: `cargo test --test integration bench -- --ignored --nocapture`.

use std::time::Duration;

use super::harness::{root, run};

#[test]
#[ignore = "benchmark: run by hand"]
fn transport_benchmark_prints_one_line_per_path() {
    let out = run(
        &["bench", "transport", "--frames", "100"],
        &root(),
        Duration::from_secs(300),
    );
    println!("{}", out.stdout);
    assert!(out.status.success(), "{}", out.stderr);
    for path in ["memcpy", "iceoryx2", "iceoryx2_inplace", "zenoh"] {
        assert!(
            out.stdout.contains(&format!("transport {path} median_us ")),
            "{}",
            out.stdout
        );
    }
}
