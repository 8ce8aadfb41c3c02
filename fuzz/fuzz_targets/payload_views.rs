#![no_main]
//! Shared-memory payload views and message decoders (`RgbdFrameView::parse`,
//! `GaussianMapView::parse`, `OccupancyGridView::parse`, `decode`, `Payload::from_bytes`).
libfuzzer_sys::fuzz_target!(|data: &[u8]| activemap_schemas::fuzzing::payload(data));
