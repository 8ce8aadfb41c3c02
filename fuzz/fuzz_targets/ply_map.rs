#![no_main]
//! Gaussian-map PLY files (`ply::from_ply_bytes`, which `read_ply` calls).
libfuzzer_sys::fuzz_target!(|data: &[u8]| activemap_splat::fuzzing::ply_map(data));
