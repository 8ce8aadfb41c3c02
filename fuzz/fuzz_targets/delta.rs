#![no_main]
//! The recording's delta decoder (`delta::decode`), with the Gaussian maps' column codec
//! registered as the CLI registers it.
libfuzzer_sys::fuzz_target!(|data: &[u8]| {
    activemap_operators::register_recording_codecs();
    activemap_runtime::fuzzing::delta(data)
});
