#![no_main]
//! Dataflow validation (`Dataflow::parse_with`, with `--set` overrides) against the real
//! operator catalogue.
use std::sync::LazyLock;

static CATALOG: LazyLock<Vec<activemap_runtime::OperatorDescriptor>> =
    LazyLock::new(activemap_operators::catalog);

libfuzzer_sys::fuzz_target!(|data: &[u8]| activemap_runtime::fuzzing::dataflow(&CATALOG, data));
