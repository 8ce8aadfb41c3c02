#![no_main]
//! The runtime's YAML reader (`yaml::parse`, and `emit` of what it parsed).
libfuzzer_sys::fuzz_target!(|data: &[u8]| activemap_runtime::fuzzing::yaml(data));
