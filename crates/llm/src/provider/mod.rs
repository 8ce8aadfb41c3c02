//! Model providers: `openai` (Chat Completions at any compatible base URL), `ollama` (native
//! `/api/chat`) and `recorded` (the replies of a recording, in order).
//!
//! A provider never fails the caller: every outcome, good or bad, is a [`Completion`] with the
//! request as sent (secrets left out, the image replaced by a placeholder naming its size),
//! the HTTP status, the attempts, the latency, the token usage and either the reply text or a
//! [`Failure`] of a named [`FailureKind`]. The planner records it and, on a failure, falls
//! back to the largest frontier.

mod http;
mod ollama;
mod openai;
mod recorded;

pub use http::{HttpClient, HttpOutcome, RetryPolicy};
pub use ollama::OllamaProvider;
pub use openai::OpenAiProvider;
pub use recorded::RecordedProvider;

use serde::{Deserialize, Serialize};

use crate::config::{HttpProviderConfig, ProviderConfig};
use crate::error::LlmError;

/// Why a decision fell back to the largest frontier.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum FailureKind {
    /// No provider is configured (the offline default).
    NoProvider,
    /// The connection was refused or failed.
    Connect,
    /// An attempt took longer than `timeout_s` (or the connect timeout).
    Timeout,
    /// 429 or 503 with a `Retry-After` longer than allowed, or still after the retries.
    RateLimited,
    /// Another HTTP status that is not success (after the retries for 5xx).
    HttpStatus,
    /// The body is not the API's JSON (not JSON, or no reply text where it should be).
    BadBody,
    /// The body is longer than `max_reply_bytes`.
    TooLarge,
    /// The reply text holds no JSON object.
    NoJson,
    /// The reply's JSON is cut off.
    BadJson,
    /// The JSON's target is missing, not an integer or out of range, or `reason` is missing.
    BadTarget,
    /// The episode's call or token budget is spent.
    Budget,
    /// A recorded provider has no reply left, or the query differs from the recorded one.
    Replay,
}

impl FailureKind {
    /// The snake_case name, as in the recording and `summary.json`.
    pub fn name(self) -> &'static str {
        match self {
            Self::NoProvider => "no_provider",
            Self::Connect => "connect",
            Self::Timeout => "timeout",
            Self::RateLimited => "rate_limited",
            Self::HttpStatus => "http_status",
            Self::BadBody => "bad_body",
            Self::TooLarge => "too_large",
            Self::NoJson => "no_json",
            Self::BadJson => "bad_json",
            Self::BadTarget => "bad_target",
            Self::Budget => "budget",
            Self::Replay => "replay",
        }
    }

    /// Every kind, in declaration order.
    pub const ALL: [FailureKind; 12] = [
        Self::NoProvider,
        Self::Connect,
        Self::Timeout,
        Self::RateLimited,
        Self::HttpStatus,
        Self::BadBody,
        Self::TooLarge,
        Self::NoJson,
        Self::BadJson,
        Self::BadTarget,
        Self::Budget,
        Self::Replay,
    ];

    /// The kind of a snake_case name.
    pub fn from_name(name: &str) -> Option<Self> {
        Self::ALL.into_iter().find(|k| k.name() == name)
    }
}

/// A failed query or reply: its kind and what exactly happened.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Failure {
    /// The kind.
    pub kind: FailureKind,
    /// Details (never a secret).
    pub detail: String,
}

impl Failure {
    /// A failure of `kind`.
    pub fn new(kind: FailureKind, detail: impl Into<String>) -> Self {
        Self {
            kind,
            detail: detail.into(),
        }
    }
}

impl std::fmt::Display for Failure {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "{}: {}", self.kind.name(), self.detail)
    }
}

/// Tokens as the server reports them.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
pub struct Usage {
    /// Prompt tokens.
    pub prompt_tokens: Option<u64>,
    /// Completion tokens.
    pub completion_tokens: Option<u64>,
}

impl Usage {
    /// Prompt plus completion tokens (missing counts as 0).
    pub fn total(&self) -> u64 {
        self.prompt_tokens.unwrap_or(0) + self.completion_tokens.unwrap_or(0)
    }
}

/// One query to a provider.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ChatRequest<'a> {
    /// System message.
    pub system: &'a str,
    /// User message text.
    pub user: &'a str,
    /// The annotated BEV as PNG bytes (`None` for the text prompt).
    pub image_png: Option<&'a [u8]>,
    /// The follow-up turn of the same conversation, if this request is one.
    pub follow_up: Option<FollowUpTurn<'a>>,
}

/// The second turn of a conversation whose first reply was cut or held no JSON: the model's
/// own text as the assistant's message, then a user message asking only for the JSON.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct FollowUpTurn<'a> {
    /// The model's first reply (its visible text; its reasoning if that is all there was).
    pub assistant: &'a str,
    /// The user's follow-up message.
    pub user: &'a str,
    /// Completion token limit of this turn.
    pub max_tokens: u32,
}

/// What a provider made of one query.
#[derive(Debug, Clone, PartialEq)]
pub struct Completion {
    /// `openai`, `ollama` (or what a recording says).
    pub provider: String,
    /// The model asked.
    pub model: String,
    /// The request body as sent, without secrets, the image replaced by
    /// `<bev.png: N bytes>`.
    pub request: String,
    /// Status of the last HTTP attempt, if one got an answer.
    pub http_status: Option<u16>,
    /// HTTP attempts made (0 when none was, e.g. budget spent).
    pub attempts: u32,
    /// Wall time of the whole query, retries and waits included, milliseconds.
    pub latency_ms: f64,
    /// Tokens used.
    pub usage: Usage,
    /// The model's reply text (`<think>` blocks included, as sent), or on failure the body
    /// excerpt (≤ 64 KiB) if any.
    pub reply: String,
    /// Why the model stopped, as the server says (`stop`, `length`, …).
    pub finish_reason: Option<String>,
    /// The reasoning the server returned beside the reply (`reasoning_content` of
    /// OpenAI-compatible servers, Ollama's `thinking`); empty when none.
    pub reasoning: String,
    /// The server refused the JSON schema (`response_format` / `format`): the request was
    /// sent again without it.
    pub schema_refused: bool,
    /// `None` when a reply text came back.
    pub failure: Option<Failure>,
}

/// What a provider's reader finds in a 2xx body.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct Reply {
    /// The reply text.
    pub text: String,
    /// Tokens used.
    pub usage: Usage,
    /// Why the model stopped.
    pub finish_reason: Option<String>,
    /// Reasoning returned beside the text.
    pub reasoning: String,
}

/// A provider's reader of a 2xx body: the reply, or why it is not the API's answer.
pub(crate) type ReadReply = fn(&[u8]) -> Result<Reply, Failure>;

impl Completion {
    /// A query that made no HTTP request and failed with `kind` (budget spent, nothing
    /// recorded left).
    pub fn failed(provider: &str, kind: FailureKind, detail: impl Into<String>) -> Self {
        Self {
            provider: provider.into(),
            model: String::new(),
            request: String::new(),
            http_status: None,
            attempts: 0,
            latency_ms: 0.0,
            usage: Usage::default(),
            reply: String::new(),
            finish_reason: None,
            reasoning: String::new(),
            schema_refused: false,
            failure: Some(Failure::new(kind, detail)),
        }
    }

    /// The completion of an HTTP exchange `out` with `provider`'s `model` for the recorded
    /// `request`: the reply text and usage that `read_reply` finds in a 2xx body, else the
    /// body excerpt and the failure (the transport's, or the body's).
    pub(crate) fn from_http(
        provider: &str,
        model: &str,
        request: String,
        out: http::HttpOutcome,
        read_reply: ReadReply,
    ) -> Self {
        let mut completion = Self {
            provider: provider.into(),
            model: model.into(),
            request,
            http_status: out.status,
            attempts: out.attempts,
            latency_ms: out.latency_ms,
            usage: Usage::default(),
            reply: String::new(),
            finish_reason: None,
            reasoning: String::new(),
            schema_refused: false,
            failure: out.failure,
        };
        let parsed = match completion.failure {
            Some(_) => None,
            None => Some(read_reply(&out.body)),
        };
        match parsed {
            Some(Ok(reply)) => {
                completion.reply = reply.text;
                completion.usage = reply.usage;
                completion.finish_reason = reply.finish_reason;
                completion.reasoning = reply.reasoning;
            }
            Some(Err(f)) => {
                completion.reply = excerpt(&out.body);
                completion.failure = Some(f);
            }
            None => completion.reply = excerpt(&out.body),
        }
        completion
    }
}

/// One POST of a provider's body, with the JSON schema if `schema` is wanted and the server
/// has not refused it before; a refusal (see [`refuses_field`]) unless `strict` sends the
/// body again without the schema and is remembered in `refused` for the rest of the episode.
/// `build(schema)` gives the body to send and the body to record. Returns the exchange's
/// outcome (attempts and latency of both posts), the recorded body, and whether the schema
/// was refused.
pub(crate) fn post_with_schema(
    http: &mut http::HttpClient,
    url: &str,
    field: &str,
    schema: bool,
    strict: bool,
    refused: &mut bool,
    build: impl Fn(bool) -> (Vec<u8>, String),
) -> (http::HttpOutcome, String, bool) {
    let with = schema && (strict || !*refused);
    let (sent, recorded) = build(with);
    let out = http.post_json(url, &sent);
    if !(with && !strict && refuses_field(&out, field)) {
        return (out, recorded, false);
    }
    *refused = true;
    let (sent, recorded) = build(false);
    let mut again = http.post_json(url, &sent);
    again.attempts += out.attempts;
    again.latency_ms += out.latency_ms;
    (again, recorded, true)
}

/// True when `out` is a 400 or 422 whose body names `field` (`"response_format"`,
/// `"format"`): the server does not take that request field.
pub fn refuses_field(out: &http::HttpOutcome, field: &str) -> bool {
    matches!(out.status, Some(400 | 422)) && String::from_utf8_lossy(&out.body).contains(field)
}

/// A model service.
pub trait Provider: Send {
    /// Asks; never panics or blocks beyond its configured timeouts.
    fn complete(&mut self, request: &ChatRequest<'_>) -> Completion;
    /// One line for the node's log at start (provider, model, URL; never a key).
    fn describe(&self) -> String;
}

/// Longest body excerpt kept in a failed [`Completion`].
pub const EXCERPT_BYTES: usize = 64 * 1024;

/// The first [`EXCERPT_BYTES`] of `body` as text (lossy, cut on a character boundary).
pub fn excerpt(body: &[u8]) -> String {
    let cut = &body[..body.len().min(EXCERPT_BYTES)];
    String::from_utf8_lossy(cut).into_owned()
}

/// The placeholder that stands for the image in a recorded request.
pub fn image_placeholder(png: &[u8]) -> String {
    format!("<bev.png: {} bytes>", png.len())
}

/// The API key named by `config.api_key_env`, read from the environment once.
pub(crate) fn api_key(config: &HttpProviderConfig) -> Result<Option<http::Secret>, LlmError> {
    let Some(name) = &config.api_key_env else {
        return Ok(None);
    };
    match std::env::var(name) {
        Ok(v) if !v.trim().is_empty() => Ok(Some(http::Secret::new(v.trim().to_string()))),
        Ok(_) => Err(LlmError::Provider(format!(
            "environment variable `{name}` (api_key_env) is empty"
        ))),
        Err(_) => Err(LlmError::Provider(format!(
            "environment variable `{name}` (api_key_env) is not set"
        ))),
    }
}

/// The provider of `config` (`recorded` replies must be passed in: reading a recording is
/// the caller's, who knows its format); `seed` seeds the retry jitter.
pub fn from_config(
    config: &ProviderConfig,
    recorded: Option<Vec<recorded::RecordedReply>>,
    seed: u64,
) -> Result<Box<dyn Provider>, LlmError> {
    Ok(match config {
        ProviderConfig::Openai(c) => Box::new(OpenAiProvider::new(c, seed)?),
        ProviderConfig::Ollama(c) => Box::new(OllamaProvider::new(c, seed)?),
        ProviderConfig::Recorded { recording, .. } => {
            let replies = recorded.ok_or_else(|| {
                LlmError::Provider(format!(
                    "recorded provider: the replies of {} were not loaded",
                    recording.display()
                ))
            })?;
            Box::new(RecordedProvider::new(replies))
        }
    })
}

pub use recorded::RecordedReply;
