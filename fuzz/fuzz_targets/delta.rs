#![no_main]
//! The recording's delta decoder (`delta::decode`).
libfuzzer_sys::fuzz_target!(|data: &[u8]| activemap_runtime::fuzzing::delta(data));
