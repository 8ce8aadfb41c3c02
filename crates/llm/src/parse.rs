//! Reply parsing (SPEC §7): a free-text plan, then `{"target": <int>, "reason": "…"}`.
//!
//! The JSON may sit inside code fences or be followed by more text. Every `{` of the reply is
//! tried as the start of a JSON object (serde_json's stream reader stops at the object's end,
//! so trailing text is fine); the answer is the LAST object that has a `target` key, since the
//! plan comes first and a model may quote the prompt's example before its own choice (the
//! release takes the first `{…}`). The target must be a JSON integer in [−1, N−1] (−1 asks
//! to refine the map) and `reason` a string; anything else is a [`ParseError`] that the
//! planner records as the reason of its fallback.
//!
//! Reasoning models write `<think>…</think>` before their answer: those blocks are set aside
//! ([`split_thinking`]) and never parsed, so a JSON object inside them is not taken. A block
//! left open (the reply was cut while thinking) runs to the end of the reply; a `</think>`
//! with no opening tag before it (chat templates that open the block in the prompt) closes a
//! block that started at the reply's beginning.

use serde_json::Value;

/// A valid answer.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Answer {
    /// −1 (refine) or a candidate index in [0, N−1].
    pub target: i64,
    /// The model's reason.
    pub reason: String,
}

/// Why a reply holds no valid answer.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum ParseError {
    /// No `{` starts a JSON object anywhere.
    #[error("no JSON object in the reply")]
    NoJson,
    /// A `{` starts an object that is cut off before its end.
    #[error("truncated JSON: {0}")]
    Truncated(String),
    /// Objects were found but none has a `target`.
    #[error("no object with a `target` field")]
    MissingTarget,
    /// The object has no string `reason`.
    #[error("`reason` is missing or not a string")]
    MissingReason,
    /// The target is not a JSON integer (a string, a fraction, null…).
    #[error("target {0} is not an integer")]
    NotAnInteger(String),
    /// The target is an integer outside [−1, N−1].
    #[error("target {target} is outside [-1, {max}]")]
    OutOfRange {
        /// The target given.
        target: i64,
        /// N − 1.
        max: i64,
    },
}

impl ParseError {
    /// The failure kind recorded for it: `no_json` when no object was there at all,
    /// `bad_json` when one was cut off, `bad_target` otherwise.
    pub fn kind(&self) -> crate::provider::FailureKind {
        use crate::provider::FailureKind as K;
        match self {
            Self::NoJson => K::NoJson,
            Self::Truncated(_) => K::BadJson,
            _ => K::BadTarget,
        }
    }
}

const THINK_OPEN: &str = "<think>";
const THINK_CLOSE: &str = "</think>";

/// A reply split into its answer text and its `<think>` blocks.
#[derive(Debug, Clone, PartialEq, Eq, Default)]
pub struct Split {
    /// The reply without its `<think>` blocks (the only part parsed).
    pub answer: String,
    /// The blocks' contents, in order, each trimmed.
    pub thinking: Vec<String>,
}

/// Splits `reply` into the answer and the `<think>` blocks (module doc).
pub fn split_thinking(reply: &str) -> Split {
    let mut split = Split::default();
    let mut rest = reply;
    if let Some(close) = rest.find(THINK_CLOSE)
        && !rest[..close].contains(THINK_OPEN)
    {
        split.thinking.push(rest[..close].trim().to_string());
        rest = &rest[close + THINK_CLOSE.len()..];
    }
    while let Some(open) = rest.find(THINK_OPEN) {
        split.answer += &rest[..open];
        let inner = &rest[open + THINK_OPEN.len()..];
        match inner.find(THINK_CLOSE) {
            Some(close) => {
                split.thinking.push(inner[..close].trim().to_string());
                rest = &inner[close + THINK_CLOSE.len()..];
            }
            None => {
                split.thinking.push(inner.trim().to_string());
                rest = "";
            }
        }
    }
    split.answer += rest;
    split
}

/// Parses `reply` for a choice among `candidates` candidates; `<think>` blocks are skipped.
pub fn parse_reply(reply: &str, candidates: usize) -> Result<Answer, ParseError> {
    let split = split_thinking(reply);
    parse_answer(&split.answer, candidates)
}

/// Parses the answer text (no `<think>` blocks) of a reply.
fn parse_answer(reply: &str, candidates: usize) -> Result<Answer, ParseError> {
    let mut last_with_target: Option<serde_json::Map<String, Value>> = None;
    let mut any_object = false;
    let mut truncated: Option<String> = None;
    let mut from = 0;
    while let Some(offset) = reply[from..].find('{') {
        let start = from + offset;
        let mut stream = serde_json::Deserializer::from_str(&reply[start..]).into_iter::<Value>();
        match stream.next() {
            Some(Ok(Value::Object(map))) => {
                any_object = true;
                let end = start + stream.byte_offset();
                if map.contains_key("target") {
                    last_with_target = Some(map);
                }
                // Objects nested inside this one are not answers of their own.
                from = end.max(start + 1);
            }
            Some(Err(e)) if e.is_eof() => {
                truncated.get_or_insert_with(|| e.to_string());
                from = start + 1;
            }
            _ => from = start + 1,
        }
    }
    let Some(map) = last_with_target else {
        return Err(match (truncated, any_object) {
            (Some(e), _) => ParseError::Truncated(e),
            (None, true) => ParseError::MissingTarget,
            (None, false) => ParseError::NoJson,
        });
    };
    let max = candidates as i64 - 1;
    let target = match &map["target"] {
        Value::Number(n) if n.is_i64() => n.as_i64().unwrap_or(i64::MIN),
        Value::Number(n) if n.is_u64() => i64::MAX,
        other => return Err(ParseError::NotAnInteger(other.to_string())),
    };
    if !(-1..=max).contains(&target) {
        return Err(ParseError::OutOfRange { target, max });
    }
    let Some(Value::String(reason)) = map.get("reason") else {
        return Err(ParseError::MissingReason);
    };
    Ok(Answer {
        target,
        reason: reason.clone(),
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn ok(reply: &str, n: usize) -> (i64, String) {
        let a = parse_reply(reply, n).unwrap_or_else(|e| panic!("{reply:?}: {e}"));
        (a.target, a.reason)
    }

    #[test]
    fn a_plan_then_json_in_fences_or_followed_by_text() {
        let r = "Plan: the corridor leads on.\n```json\n{\"target\": 3, \"reason\": \"corridor\"}\n```\nGood luck!";
        assert_eq!(ok(r, 5), (3, "corridor".into()));
        let r = "{\"target\": 0, \"reason\": \"a\"} and then {\"target\": -1, \"reason\": \"refine\"} trailing";
        assert_eq!(ok(r, 2), (-1, "refine".into()), "the last answer wins");
        let r = "Like the example {\"target\": 2, \"reason\": \"x\"}, I pick {\"target\": 1, \"reason\": \"door {left}\"}.";
        assert_eq!(ok(r, 3), (1, "door {left}".into()));
        let nested = "{\"answer\": {\"target\": 1, \"reason\": \"n\"}}";
        assert_eq!(parse_reply(nested, 3), Err(ParseError::MissingTarget));
    }

    #[test]
    fn bad_replies_are_refused_with_their_reason() {
        assert_eq!(parse_reply("I would go left.", 3), Err(ParseError::NoJson));
        assert!(matches!(
            parse_reply("plan {\"target\": 2, \"reason\": \"The ta", 3),
            Err(ParseError::Truncated(_))
        ));
        assert_eq!(
            parse_reply("{\"target\": 3, \"reason\": \"r\"}", 3),
            Err(ParseError::OutOfRange { target: 3, max: 2 })
        );
        assert_eq!(
            parse_reply("{\"target\": -2, \"reason\": \"r\"}", 3),
            Err(ParseError::OutOfRange { target: -2, max: 2 })
        );
        assert_eq!(
            parse_reply("{\"target\": \"2\", \"reason\": \"r\"}", 3),
            Err(ParseError::NotAnInteger("\"2\"".into()))
        );
        assert_eq!(
            parse_reply("{\"target\": 1.5, \"reason\": \"r\"}", 3),
            Err(ParseError::NotAnInteger("1.5".into()))
        );
        assert_eq!(
            parse_reply("{\"target\": 1}", 3),
            Err(ParseError::MissingReason)
        );
        assert_eq!(
            parse_reply("{\"reason\": \"r\"}", 3),
            Err(ParseError::MissingTarget)
        );
        assert!(matches!(
            parse_reply("{\"target\": 99999999999999999999, \"reason\": \"r\"}", 3),
            Err(ParseError::OutOfRange { .. }) | Err(ParseError::NotAnInteger(_))
        ));
        assert_eq!(
            parse_reply("{\"target\": -1, \"reason\": \"r\"}", 0).map(|a| a.target),
            Ok(-1),
            "refine is valid with no candidates"
        );
    }

    /// JSON inside `<think>` is never the answer, whether the block is closed, left open by
    /// a cut reply, or opened by the chat template (only `</think>` in the reply).
    #[test]
    fn think_blocks_are_set_aside() {
        let r = "<think>maybe {\"target\": 0, \"reason\": \"t\"}</think>\n{\"target\": 2, \"reason\": \"hall\"}";
        assert_eq!(ok(r, 3), (2, "hall".into()));
        let s = split_thinking(r);
        assert_eq!(s.thinking, ["maybe {\"target\": 0, \"reason\": \"t\"}"]);
        assert_eq!(s.answer.trim(), "{\"target\": 2, \"reason\": \"hall\"}");
        let cut = "<think>I pick {\"target\": 1, \"reason\": \"x\"} or maybe";
        assert_eq!(parse_reply(cut, 3), Err(ParseError::NoJson));
        assert_eq!(split_thinking(cut).answer, "");
        let template = "so {\"target\": 1, \"reason\": \"x\"}</think>No JSON here.";
        assert_eq!(parse_reply(template, 3), Err(ParseError::NoJson));
        let two = "a<think>1</think>b<think>2</think>c";
        let s = split_thinking(two);
        assert_eq!((s.answer.as_str(), s.thinking.len()), ("abc", 2));
        assert_eq!(split_thinking("plain").thinking, Vec::<String>::new());
    }

    #[test]
    fn kinds_of_the_failures() {
        use crate::provider::FailureKind as K;
        assert_eq!(ParseError::NoJson.kind(), K::NoJson);
        assert_eq!(ParseError::Truncated(String::new()).kind(), K::BadJson);
        assert_eq!(ParseError::MissingReason.kind(), K::BadTarget);
    }
}
