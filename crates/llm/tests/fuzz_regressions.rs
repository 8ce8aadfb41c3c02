//! Replays the `llm_reply` fuzz target's saved inputs (`tests/data/fuzz-regressions/llm_reply/`
//! and the seeds `fuzz/corpus/llm_reply/seed-*`) through `parse_reply`: each must give an
//! answer or an error, never a panic.

#[test]
fn llm_reply_fuzz_regressions_replay_without_panics() {
    let n = activemap_splat::fuzzing::replay("llm_reply", activemap_llm::fuzzing::llm_reply);
    assert!(n > 0, "no seed or regression input for llm_reply");
}
