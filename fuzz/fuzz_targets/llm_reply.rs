#![no_main]
//! LLM replies (`parse::parse_reply`).
libfuzzer_sys::fuzz_target!(|data: &[u8]| activemap_llm::fuzzing::llm_reply(data));
