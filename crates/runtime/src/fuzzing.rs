//! Entry points of the fuzz targets (`fuzz/`) and their regression replay test: each feeds
//! arbitrary bytes to a parser and ignores the result. Not part of the public API.

use crate::OperatorDescriptor;
use crate::dataflow::{Dataflow, Override};
use crate::{delta, yaml};
use std::path::PathBuf;

/// Parses `data` as YAML; a document that parses is also written back and parsed again.
pub fn yaml(data: &[u8]) {
    let Ok(text) = std::str::from_utf8(data) else {
        return;
    };
    if let Ok(node) = yaml::parse(text) {
        let _ = node.to_json();
        let _ = yaml::parse(&yaml::emit(&node));
    }
}

/// Validates `data` as a dataflow file against `catalog`. Lines before the first NUL byte, if
/// any, are `--set` overrides (`NODE.KEY=VALUE`, one a line) and the rest is the file.
pub fn dataflow(catalog: &[OperatorDescriptor], data: &[u8]) {
    let Ok(text) = std::str::from_utf8(data) else {
        return;
    };
    let (sets, source) = text.split_once('\0').unwrap_or(("", text));
    let overrides: Vec<Override> = sets
        .lines()
        .filter_map(|l| Override::parse(l).ok())
        .collect();
    let _ = Dataflow::parse_with("fuzz.yaml", source, PathBuf::new(), catalog, &overrides);
}

/// Decodes a delta-encoded recording message. The first byte `n` splits the input: with
/// `n = 0` there is no previous payload and the rest is the message; otherwise the next `n - 1`
/// bytes (or fewer, if the input ends) are the previous payload and the rest the message. A
/// decoded payload is encoded again against the previous one and decoded back.
pub fn delta(data: &[u8]) {
    let Some((&n, rest)) = data.split_first() else {
        return;
    };
    let (previous, message) = match n {
        0 => (None, rest),
        n => {
            let (p, m) = rest.split_at((n as usize - 1).min(rest.len()));
            (Some(p), m)
        }
    };
    if let Ok(payload) = delta::decode(previous, message) {
        let mut encoded = Vec::new();
        delta::encode(previous, &payload, &mut encoded);
        let _ = delta::decode(previous, &encoded);
    }
}
