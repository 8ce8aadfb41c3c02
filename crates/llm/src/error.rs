//! Errors of the planner library. A model that fails is not an error (it is a recorded
//! [`crate::provider::Failure`] and a fallback decision); these are the caller's mistakes.

/// What went wrong, naming the field or the input.
#[derive(Debug, thiserror::Error)]
pub enum LlmError {
    /// A bad setting, naming its field.
    #[error("llm config: {0}")]
    Config(String),
    /// A bad input to a decision (non-finite pose, empty candidate list where one is needed).
    #[error("llm planner: {0}")]
    Input(String),
    /// The BEV could not be rendered.
    #[error("llm planner: bird's-eye view: {0}")]
    Bev(String),
    /// The provider could not be set up (missing key variable, HTTP client).
    #[error("llm provider: {0}")]
    Provider(String),
}
