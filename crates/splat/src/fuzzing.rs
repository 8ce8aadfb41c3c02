//! Entry point of the `ply_map` fuzz target (`fuzz/`), and the inputs every fuzz target's
//! replay test feeds back (this crate is the one both replay tests, the root package's and
//! `activemap-llm`'s, depend on). Not part of the public API.

use crate::ply::from_ply_bytes;
use std::path::{Path, PathBuf};

/// Reads `data` as a Gaussian-map PLY file, in `f32` and in `f64`.
pub fn ply_map(data: &[u8]) {
    let _ = from_ply_bytes::<f32>(data, "fuzz input");
    let _ = from_ply_bytes::<f64>(data, "fuzz input");
}

/// The saved inputs of fuzz target `target`, sorted: every file of
/// `tests/data/fuzz-regressions/<target>/` (the crashes found, minimised) and the seed files
/// `fuzz/corpus/<target>/seed-*` (not the corpus libFuzzer grows there).
pub fn replay_inputs(target: &str) -> Vec<PathBuf> {
    let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("../..");
    let mut files = Vec::new();
    for (dir, seeds_only) in [
        (root.join("tests/data/fuzz-regressions").join(target), false),
        (root.join("fuzz/corpus").join(target), true),
    ] {
        let Ok(entries) = std::fs::read_dir(&dir) else {
            continue;
        };
        files.extend(entries.flatten().map(|e| e.path()).filter(|p| {
            p.is_file()
                && (!seeds_only
                    || p.file_name()
                        .and_then(|n| n.to_str())
                        .is_some_and(|n| n.starts_with("seed-")))
        }));
    }
    files.sort();
    files
}

/// Feeds every [`replay_inputs`] file of `target` to `run`, each under `catch_unwind`, and
/// panics naming the inputs that panicked; returns how many inputs were replayed.
pub fn replay(target: &str, run: impl Fn(&[u8])) -> usize {
    let files = replay_inputs(target);
    let mut panicked = Vec::new();
    for file in &files {
        let data =
            std::fs::read(file).unwrap_or_else(|e| panic!("cannot read {}: {e}", file.display()));
        if std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| run(&data))).is_err() {
            panicked.push(file.display().to_string());
        }
    }
    assert!(
        panicked.is_empty(),
        "fuzz target {target}: these inputs panic:\n{}",
        panicked.join("\n")
    );
    files.len()
}
