//! The planner's settings (the `llm:` block of the `planner` node in `dataflow.yaml`), with the
//! paper's choices as defaults (SPEC §7) and the authors' release facts named where they differ.
//!
//! ```yaml
//! llm:
//!   prompt: image              # image (the paper) | json_first | text | text_compact
//!   follow_up: { enabled: true, max_tokens: 256 }   # one "only the JSON" turn after a cut reply
//!   provider:                  # absent: the offline default (largest frontier, SPEC §7 fallback)
//!     kind: openai             # openai | ollama | recorded
//!     base_url: http://127.0.0.1:8088/v1
//!     model: gpt-4o
//!     api_key_env: OPENAI_API_KEY   # the key is read from this variable only, never the YAML
//!     max_tokens: 1000
//!     structured_output: follow_up  # off | follow_up | auto | on (the reply's JSON schema)
//!   ask: { min_interval_steps: 0, skip_unchanged_map: true }
//!   budget: { max_calls: 200, max_tokens: 2000000 }
//! ```

use std::path::PathBuf;

use serde::Deserialize;

use crate::bev::BevConfig;
use crate::error::LlmError;

/// Which prompt the model gets (SPEC §7).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum PromptStyle {
    /// The paper's: the appendix text with the annotated bird's-eye view as an image, asking
    /// for the exploration plan first and the JSON last (suits hosted models).
    #[default]
    Image,
    /// The paper's image prompt, but asking for the JSON object first and the reasoning after
    /// it: a reply cut by the token limit still holds the answer.
    JsonFirst,
    /// For models without vision: the paper's task, with each candidate's id, position, size
    /// and path distance listed in the text instead of the image; plan first, JSON last.
    Text,
    /// For small models without vision: a short instruction, the candidate list, and the JSON
    /// object asked for first with a one-sentence reason.
    TextCompact,
}

impl PromptStyle {
    /// True when the prompt carries the annotated bird's-eye view (`image`, `json_first`).
    pub fn sends_image(self) -> bool {
        matches!(self, Self::Image | Self::JsonFirst)
    }
}

/// The follow-up turn after a reply that was cut (finish reason `length`) or holds no JSON
/// answer: the model's own text goes back as the assistant's turn, followed by a short user
/// turn asking only for the JSON object (with the schema when `structured_output` allows).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct FollowUpConfig {
    /// Ask the follow-up at all.
    #[serde(default = "yes")]
    pub enabled: bool,
    /// Completion token limit of the follow-up reply.
    #[serde(default = "default_follow_up_tokens")]
    pub max_tokens: u32,
}

fn default_follow_up_tokens() -> u32 {
    256
}

impl Default for FollowUpConfig {
    fn default() -> Self {
        Self {
            enabled: true,
            max_tokens: default_follow_up_tokens(),
        }
    }
}

/// When the request carries the reply's JSON schema (OpenAI-compatible `response_format`
/// with `json_schema`, Ollama `format`). YAML `true` reads as `on`, `false` as `off`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum StructuredOutput {
    /// Never.
    Off,
    /// Only on the follow-up turn (which asks for the JSON alone); a server that refuses the
    /// field gets the turn again without it, and never again this episode. The default: the
    /// first reply stays the paper's free-text plan.
    #[default]
    FollowUp,
    /// On every request, with the same fallback as `follow_up` when the server refuses it.
    Auto,
    /// On every request, required: a refusal is the query's failure (`http_status`).
    On,
}

impl StructuredOutput {
    /// The setting's name in the YAML.
    pub fn name(self) -> &'static str {
        match self {
            Self::Off => "off",
            Self::FollowUp => "follow_up",
            Self::Auto => "auto",
            Self::On => "on",
        }
    }

    /// Whether a request asks for the schema: the first one (`follow_up` false) or the
    /// follow-up turn.
    pub fn wanted(self, follow_up: bool) -> bool {
        match self {
            Self::Off => false,
            Self::FollowUp => follow_up,
            Self::Auto | Self::On => true,
        }
    }
}

impl<'de> Deserialize<'de> for StructuredOutput {
    fn deserialize<D: serde::Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        #[derive(Deserialize)]
        #[serde(untagged)]
        enum Raw {
            Flag(bool),
            Name(String),
        }
        match Raw::deserialize(d)? {
            Raw::Flag(true) => Ok(Self::On),
            Raw::Flag(false) => Ok(Self::Off),
            Raw::Name(n) => [Self::Off, Self::FollowUp, Self::Auto, Self::On]
                .into_iter()
                .find(|v| v.name() == n)
                .ok_or_else(|| {
                    serde::de::Error::custom(format!(
                        "structured_output: `{n}` is not off, follow_up, auto or on"
                    ))
                }),
        }
    }
}

/// Everything the LLM policy of the `planner` needs.
#[derive(Debug, Clone, Default, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct LlmConfig {
    /// Prompt variant.
    #[serde(default)]
    pub prompt: PromptStyle,
    /// The follow-up turn after a cut reply or one without JSON.
    #[serde(default)]
    pub follow_up: FollowUpConfig,
    /// The model service; `None` is the offline default: the paper's fallback (the largest
    /// frontier) at every decision, announced once at start.
    #[serde(default)]
    pub provider: Option<ProviderConfig>,
    /// The bird's-eye view.
    #[serde(default)]
    pub bev: BevConfig,
    /// When the planner asks.
    #[serde(default)]
    pub ask: AskPolicy,
    /// Per-episode limits.
    #[serde(default)]
    pub budget: Budget,
    /// Total steps of the episode told to the model (`<TOTAL_STEPS>`); `None`: the run's
    /// `--max-steps`, else the paper's 2000.
    #[serde(default)]
    pub total_steps: Option<u64>,
}

/// When a replan turns into a model query (SPEC §7: at each replan that has frontiers).
#[derive(Debug, Clone, Copy, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct AskPolicy {
    /// At least this many steps between two queries; a replan sooner keeps the last target
    /// (its frontier, if still offered, else the largest). 0: ask at every replan.
    #[serde(default)]
    pub min_interval_steps: u64,
    /// Do not ask again while the map (its keyframe), the robot cell and the candidates are
    /// those of the last query: its answer is reused, as the same question would be asked.
    #[serde(default = "yes")]
    pub skip_unchanged_map: bool,
    /// `blocking` (the default, the paper's protocol): the replan waits for the model's
    /// answer, so the decisions do not depend on how fast the server is. `background`: the
    /// replan that asks gets the fallback's goal (the largest frontier) at once, the robot goes
    /// on while the model thinks, and the answer is taken up at the first replan after it
    /// arrived (applied, or recorded as stale).
    #[serde(default)]
    pub mode: AskMode,
    /// `background`: an answer taken up more than this many steps after its question is
    /// stale (the map it was asked on is that old) and is not applied.
    #[serde(default = "default_stale_after_steps")]
    pub stale_after_steps: u64,
}

/// Whether a replan waits for the model (see [`AskPolicy::mode`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum AskMode {
    /// The replan waits for the answer.
    #[default]
    Blocking,
    /// The replan takes the fallback's goal; the answer is applied at a later replan.
    Background,
}

fn default_stale_after_steps() -> u64 {
    200
}

fn yes() -> bool {
    true
}

impl Default for AskPolicy {
    fn default() -> Self {
        Self {
            min_interval_steps: 0,
            skip_unchanged_map: true,
            mode: AskMode::Blocking,
            stale_after_steps: default_stale_after_steps(),
        }
    }
}

/// Per-episode limits on what the model may cost; once reached, decisions fall back (kind
/// `budget`) without a request.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Budget {
    /// Model requests (each HTTP attempt counts).
    #[serde(default)]
    pub max_calls: Option<u64>,
    /// Prompt plus completion tokens, as the server reports them.
    #[serde(default)]
    pub max_tokens: Option<u64>,
}

/// The model service.
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(tag = "kind", rename_all = "snake_case", deny_unknown_fields)]
pub enum ProviderConfig {
    /// OpenAI's Chat Completions at any compatible base URL (OpenAI, vLLM, llama.cpp's server,
    /// LM Studio, Ollama's `/v1`): `POST {base_url}/chat/completions`.
    Openai(HttpProviderConfig),
    /// Ollama's native `POST {base_url}/api/chat` (the release's LLaVA variant).
    Ollama(HttpProviderConfig),
    /// The replies of a recording, served in order: a recorded LLM episode re-runs without
    /// any network and takes the same decisions.
    Recorded {
        /// The `recording.mcap` to read.
        recording: PathBuf,
        /// The node whose `llm` output to serve; `None`: the node being run.
        #[serde(default)]
        node: Option<String>,
    },
}

/// An HTTP provider's settings.
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct HttpProviderConfig {
    /// Base URL: `http(s)://host:port/v1` for `openai`, `http://host:11434` for `ollama`.
    pub base_url: String,
    /// Model name as the server knows it.
    pub model: String,
    /// Name of the environment variable holding the API key, sent as `Authorization: Bearer`.
    /// Required for a non-loopback `openai` URL; loopback URLs need none.
    #[serde(default)]
    pub api_key_env: Option<String>,
    /// Completion token limit (release: 1000 for GPT-4o; `num_predict` for Ollama).
    #[serde(default = "default_max_tokens")]
    pub max_tokens: u32,
    /// Sampling temperature; `None` leaves the server's default (the release sets none).
    #[serde(default)]
    pub temperature: Option<f64>,
    /// Sampling seed, for servers that honour it.
    #[serde(default)]
    pub seed: Option<u64>,
    /// When to ask the server for structured output (OpenAI `response_format` with a JSON
    /// schema of `{target, reason}`, Ollama `format` with the same schema): by default only
    /// on the follow-up turn, since the paper's reply is a free-text plan followed by the
    /// JSON. A 400 or 422 whose body names the field drops it (except with `on`).
    #[serde(default)]
    pub structured_output: StructuredOutput,
    /// Longest `reason` the structured output's schema allows (`maxLength`), in characters; none
    /// by default. A small local model under a grammar can write its reason until the token
    /// limit and never reach `target`; a bound makes the grammar close the string (the schema
    /// orders `reason` before `target`). Not every hosted API takes `maxLength` in a strict
    /// schema: one that refuses it is asked again without the schema.
    #[serde(default)]
    pub reason_max_chars: Option<u32>,
    /// OpenAI `image_url.detail` (`low`, `high`, `auto`); `openai` only.
    #[serde(default)]
    pub detail: Option<String>,
    /// Connect timeout, seconds.
    #[serde(default = "default_connect_timeout")]
    pub connect_timeout_s: f64,
    /// Timeout of one attempt, connection to the last byte of the reply, seconds.
    #[serde(default = "default_timeout")]
    pub timeout_s: f64,
    /// Retries after a connection failure, a timeout, a 429 or a 5xx (other statuses are not
    /// retried).
    #[serde(default = "default_retries")]
    pub max_retries: u32,
    /// First backoff, seconds; doubled per retry up to `backoff_max_s`, with jitter in
    /// [½, 1] of it.
    #[serde(default = "default_backoff")]
    pub backoff_s: f64,
    /// Longest backoff, seconds; a `Retry-After` longer than this gives up (kind
    /// `rate_limited`).
    #[serde(default = "default_backoff_max")]
    pub backoff_max_s: f64,
    /// Longest reply body read, bytes; a longer one fails (kind `too_large`).
    #[serde(default = "default_max_reply_bytes")]
    pub max_reply_bytes: usize,
}

fn default_max_tokens() -> u32 {
    1000
}
fn default_connect_timeout() -> f64 {
    5.0
}
fn default_timeout() -> f64 {
    120.0
}
fn default_retries() -> u32 {
    2
}
fn default_backoff() -> f64 {
    1.0
}
fn default_backoff_max() -> f64 {
    30.0
}
fn default_max_reply_bytes() -> usize {
    1 << 20
}

impl HttpProviderConfig {
    /// A config for `model` at `base_url` with every other field at its default.
    pub fn new(base_url: &str, model: &str) -> Self {
        Self {
            base_url: base_url.into(),
            model: model.into(),
            api_key_env: None,
            max_tokens: default_max_tokens(),
            temperature: None,
            seed: None,
            structured_output: StructuredOutput::default(),
            reason_max_chars: None,
            detail: None,
            connect_timeout_s: default_connect_timeout(),
            timeout_s: default_timeout(),
            max_retries: default_retries(),
            backoff_s: default_backoff(),
            backoff_max_s: default_backoff_max(),
            max_reply_bytes: default_max_reply_bytes(),
        }
    }

    /// Checks the numbers and the URL (`what` names the provider in errors).
    pub fn validate(&self, what: &str) -> Result<(), LlmError> {
        let bad = |field: &str, why: String| LlmError::Config(format!("{what}.{field}: {why}"));
        let url = reqwest::Url::parse(&self.base_url)
            .map_err(|e| bad("base_url", format!("`{}` is not a URL: {e}", self.base_url)))?;
        if !matches!(url.scheme(), "http" | "https") {
            return Err(bad(
                "base_url",
                format!("scheme `{}` is not http(s)", url.scheme()),
            ));
        }
        if self.model.trim().is_empty() {
            return Err(bad("model", "is empty".into()));
        }
        if self.reason_max_chars == Some(0) {
            return Err(bad(
                "reason_max_chars",
                "must be at least 1 (or left out)".into(),
            ));
        }
        for (field, v) in [
            ("connect_timeout_s", self.connect_timeout_s),
            ("timeout_s", self.timeout_s),
            ("backoff_max_s", self.backoff_max_s),
        ] {
            if !(v.is_finite() && v > 0.0) {
                return Err(bad(field, format!("{v} must be finite and > 0")));
            }
        }
        if !(self.backoff_s.is_finite() && self.backoff_s >= 0.0) {
            return Err(bad(
                "backoff_s",
                format!("{} must be finite and ≥ 0", self.backoff_s),
            ));
        }
        if self.max_retries > 10 {
            return Err(bad("max_retries", format!("{} > 10", self.max_retries)));
        }
        if self.max_tokens == 0 {
            return Err(bad("max_tokens", "must be > 0".into()));
        }
        if self.max_reply_bytes < 1024 {
            return Err(bad(
                "max_reply_bytes",
                format!("{} < 1024", self.max_reply_bytes),
            ));
        }
        if let Some(t) = self.temperature
            && !(t.is_finite() && (0.0..=2.0).contains(&t))
        {
            return Err(bad("temperature", format!("{t} outside [0, 2]")));
        }
        if let Some(d) = &self.detail
            && !matches!(d.as_str(), "low" | "high" | "auto")
        {
            return Err(bad("detail", format!("`{d}` is not low, high or auto")));
        }
        if let Some(name) = &self.api_key_env
            && (name.is_empty() || name.contains('='))
        {
            return Err(bad(
                "api_key_env",
                format!("`{name}` is not a variable name"),
            ));
        }
        Ok(())
    }

    /// True when the base URL's host is a loopback address (`localhost`, 127.0.0.0/8, ::1).
    pub fn is_loopback(&self) -> bool {
        reqwest::Url::parse(&self.base_url).is_ok_and(|u| match u.host() {
            Some(url::Host::Domain(d)) => d.eq_ignore_ascii_case("localhost"),
            Some(url::Host::Ipv4(ip)) => ip.is_loopback(),
            Some(url::Host::Ipv6(ip)) => ip.is_loopback(),
            None => false,
        })
    }
}

impl LlmConfig {
    /// Checks every field (the provider's numbers and URL, the BEV size, the budget); the
    /// YAML never holds a key, so an `api_key` field is refused with a pointer to
    /// `api_key_env` when the config is read.
    pub fn validate(&self) -> Result<(), LlmError> {
        self.bev.validate()?;
        match &self.provider {
            None => {}
            Some(ProviderConfig::Openai(c)) => {
                c.validate("provider (openai)")?;
                if !c.is_loopback() && c.api_key_env.is_none() {
                    return Err(LlmError::Config(format!(
                        "provider (openai): `{}` is not a loopback address, so it needs \
                         `api_key_env` (the name of the variable holding the key)",
                        c.base_url
                    )));
                }
            }
            Some(ProviderConfig::Ollama(c)) => {
                c.validate("provider (ollama)")?;
                if c.detail.is_some() {
                    return Err(LlmError::Config(
                        "provider (ollama).detail: `detail` is an OpenAI image option".into(),
                    ));
                }
            }
            Some(ProviderConfig::Recorded { recording, .. })
                if recording.as_os_str().is_empty() =>
            {
                return Err(LlmError::Config(
                    "provider (recorded).recording: empty path".into(),
                ));
            }
            Some(ProviderConfig::Recorded { .. }) => {}
        }
        if self.total_steps == Some(0) {
            return Err(LlmError::Config("total_steps: must be > 0".into()));
        }
        if self.follow_up.max_tokens == 0 {
            return Err(LlmError::Config("follow_up.max_tokens: must be > 0".into()));
        }
        Ok(())
    }

    /// Reads a config from JSON (as the runtime hands a node's `config:` over), naming the
    /// field at fault; an `api_key` anywhere in the provider is refused.
    pub fn from_value(value: &serde_json::Value) -> Result<Self, LlmError> {
        if value
            .get("provider")
            .and_then(|p| p.get("api_key"))
            .is_some()
        {
            return Err(LlmError::Config(
                "provider.api_key: keys are never read from the dataflow file; name the \
                 environment variable that holds it with `api_key_env`"
                    .into(),
            ));
        }
        let config: Self =
            serde_json::from_value(value.clone()).map_err(|e| LlmError::Config(e.to_string()))?;
        config.validate()?;
        Ok(config)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use serde_json::json;

    #[test]
    fn defaults_are_the_offline_paper_planner() {
        let c = LlmConfig::from_value(&json!({})).unwrap();
        assert!(c.provider.is_none());
        assert_eq!(c.prompt, PromptStyle::Image);
        assert_eq!(c.ask, AskPolicy::default());
        assert!(c.ask.skip_unchanged_map);
        let p = LlmConfig::from_value(&json!({"provider": {"kind": "openai",
            "base_url": "http://127.0.0.1:8088/v1", "model": "m"}}))
        .unwrap();
        let Some(ProviderConfig::Openai(h)) = p.provider else {
            panic!("openai")
        };
        assert_eq!(h.max_tokens, 1000);
        assert!(h.is_loopback());
        assert_eq!(h.temperature, None);
        assert_eq!(h.structured_output, StructuredOutput::FollowUp);
        assert_eq!(p.follow_up, FollowUpConfig::default());
    }

    #[test]
    fn prompt_variants_and_structured_output_values() {
        for (name, style, image) in [
            ("image", PromptStyle::Image, true),
            ("json_first", PromptStyle::JsonFirst, true),
            ("text", PromptStyle::Text, false),
            ("text_compact", PromptStyle::TextCompact, false),
        ] {
            let c = LlmConfig::from_value(&json!({ "prompt": name })).unwrap();
            assert_eq!((c.prompt, c.prompt.sends_image()), (style, image), "{name}");
        }
        for (value, mode) in [
            (json!(true), StructuredOutput::On),
            (json!(false), StructuredOutput::Off),
            (json!("off"), StructuredOutput::Off),
            (json!("follow_up"), StructuredOutput::FollowUp),
            (json!("auto"), StructuredOutput::Auto),
            (json!("on"), StructuredOutput::On),
        ] {
            let c = LlmConfig::from_value(&json!({"provider": {"kind": "ollama",
                "base_url": "http://127.0.0.1:11434", "model": "m", "structured_output": value}}))
            .unwrap();
            let Some(ProviderConfig::Ollama(h)) = c.provider else {
                panic!("ollama")
            };
            assert_eq!(h.structured_output, mode);
        }
        assert!(!StructuredOutput::FollowUp.wanted(false));
        assert!(StructuredOutput::FollowUp.wanted(true));
        assert!(StructuredOutput::Auto.wanted(false) && !StructuredOutput::Off.wanted(true));
    }

    #[test]
    fn keys_never_come_from_the_yaml_and_remote_urls_need_a_variable() {
        let e = LlmConfig::from_value(&json!({"provider": {"kind": "openai",
            "base_url": "https://api.openai.com/v1", "model": "gpt-4o", "api_key": "sk-x"}}))
        .unwrap_err()
        .to_string();
        assert!(e.contains("api_key_env") && !e.contains("sk-x"), "{e}");
        let e = LlmConfig::from_value(&json!({"provider": {"kind": "openai",
            "base_url": "https://api.openai.com/v1", "model": "gpt-4o"}}))
        .unwrap_err()
        .to_string();
        assert!(e.contains("loopback") && e.contains("api_key_env"), "{e}");
        assert!(
            LlmConfig::from_value(&json!({"provider": {"kind": "openai",
            "base_url": "https://api.openai.com/v1", "model": "gpt-4o",
            "api_key_env": "OPENAI_API_KEY"}}))
            .is_ok()
        );
    }

    #[test]
    fn bad_fields_are_named() {
        for (v, field) in [
            (
                json!({"provider": {"kind": "openai", "base_url": "nope", "model": "m"}}),
                "base_url",
            ),
            (
                json!({"provider": {"kind": "ollama", "base_url": "http://localhost:11434",
                "model": "m", "timeout_s": 0}}),
                "timeout_s",
            ),
            (
                json!({"provider": {"kind": "ollama", "base_url": "http://localhost:11434",
                "model": "m", "detail": "low"}}),
                "detail",
            ),
            (
                json!({"provider": {"kind": "openai", "base_url": "http://localhost/v1",
                "model": "m", "temperature": 9}}),
                "temperature",
            ),
            (json!({"provider": {"kind": "gemini"}}), "gemini"),
            (json!({"ask": {"every": 3}}), "every"),
            (json!({"total_steps": 0}), "total_steps"),
            (
                json!({"follow_up": {"max_tokens": 0}}),
                "follow_up.max_tokens",
            ),
            (json!({"prompt": "fancy"}), "fancy"),
            (
                json!({"provider": {"kind": "openai", "base_url": "http://localhost/v1",
                "model": "m", "structured_output": "maybe"}}),
                "structured_output",
            ),
        ] {
            let e = LlmConfig::from_value(&v).unwrap_err().to_string();
            assert!(e.contains(field), "{field}: {e}");
        }
    }
}
