//! The paper's multimodal-LLM long-horizon planner (SPEC §7), without any transport: the
//! `planner` operator's `policy: llm` only wires messages to it.
//!
//! Stages, each testable alone:
//! - [`bev`]: the bird's-eye view of the 3DGS map (orthographic top-down splat, ceiling cut,
//!   white background, cropped) and its annotations (blue star, green path, yellow diamond,
//!   red numbers), encoded as PNG;
//! - [`prompt`]: the paper's appendix prompt, its `json_first` order, or the `text` and
//!   `text_compact` variants for models without vision; the follow-up turn;
//! - [`provider`]: `openai` (Chat Completions), `ollama` (`/api/chat`) and `recorded`, with
//!   timeouts, bounded retries, `Retry-After`, a body cap, the key from the environment only;
//! - [`parse`]: the reply's `{"target", "reason"}`, `<think>` blocks set aside;
//! - [`planner`]: when to ask, the budget, the fallback to the largest frontier, the exchange
//!   record and the episode's totals.
//!
//! Settings: [`config::LlmConfig`] (the `llm:` block of the `planner` node).

pub mod bev;
pub mod config;
pub mod error;
#[doc(hidden)]
pub mod fuzzing;
pub mod parse;
pub mod planner;
pub mod prompt;
pub mod provider;

pub use config::{
    AskMode, FollowUpConfig, LlmConfig, PromptStyle, ProviderConfig, StructuredOutput,
};
pub use error::LlmError;
pub use planner::{Choice, Decision, Exchange, FollowUp, LlmPlanner, Query, Source, Stats};
pub use prompt::Candidate;
pub use provider::{Completion, Failure, FailureKind, Provider};
