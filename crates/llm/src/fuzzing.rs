//! Entry point of the `llm_reply` fuzz target (`fuzz/`) and its regression replay test. Not
//! part of the public API.

use crate::parse::parse_reply;

/// Parses a model reply: the first byte is the number of candidates, the rest (UTF-8) the
/// reply text.
pub fn llm_reply(data: &[u8]) {
    let Some((&candidates, rest)) = data.split_first() else {
        return;
    };
    if let Ok(reply) = std::str::from_utf8(rest) {
        let _ = parse_reply(reply, candidates as usize);
    }
}
