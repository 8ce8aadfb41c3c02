//! `openai`: Chat Completions (`POST {base_url}/chat/completions`) at any OpenAI-compatible
//! base URL. The image goes as a `data:image/png;base64,…` `image_url` part of the user
//! message (with `detail` if set); `max_tokens`, `temperature`, `seed` and, when
//! `structured_output` asks for it, a `response_format` JSON schema of `{target, reason}`
//! (dropped for the episode if the server answers 400 naming `response_format`). A follow-up
//! turn resends the conversation: system, user (with the image), the model's reply as the
//! assistant's message, and the follow-up user message. The reply's `finish_reason` and the
//! reasoning of reasoning models (`reasoning_content`, or `reasoning`) are kept.

use base64::Engine;
use serde_json::{Value, json};

use super::http::HttpClient;
use super::{ChatRequest, Completion, Failure, FailureKind, Provider, Reply, Usage};
use crate::config::{HttpProviderConfig, StructuredOutput};
use crate::error::LlmError;

/// The JSON schema of the answer, for providers' structured output; `reason_max_chars` bounds
/// the reason (`maxLength`). The keys are serialised in sorted order, so a grammar built from it
/// writes `reason` before `target`.
pub fn answer_schema(reason_max_chars: Option<u32>) -> Value {
    let mut reason = json!({ "type": "string" });
    if let Some(n) = reason_max_chars {
        reason["maxLength"] = json!(n);
    }
    json!({
        "type": "object",
        "properties": {
            "target": { "type": "integer" },
            "reason": reason
        },
        "required": ["target", "reason"],
        "additionalProperties": false
    })
}

/// The OpenAI-compatible provider.
pub struct OpenAiProvider {
    config: HttpProviderConfig,
    url: String,
    http: HttpClient,
    /// The server refused `response_format` once this episode: it is not sent again.
    schema_refused: bool,
}

impl OpenAiProvider {
    /// The provider of `config` (its key read from `api_key_env` now); `seed` seeds the jitter.
    pub fn new(config: &HttpProviderConfig, seed: u64) -> Result<Self, LlmError> {
        config.validate("provider (openai)")?;
        let key = super::api_key(config)?;
        Ok(Self {
            url: format!("{}/chat/completions", config.base_url.trim_end_matches('/')),
            http: HttpClient::new(config, key, seed)?,
            config: config.clone(),
            schema_refused: false,
        })
    }

    /// True once the server refused `response_format` this episode.
    pub fn schema_refused(&self) -> bool {
        self.schema_refused
    }

    /// The request body, with `image_url` as the image's URL and the JSON schema if `schema`.
    pub fn body(&self, request: &ChatRequest<'_>, image_url: Option<&str>, schema: bool) -> Value {
        body(&self.config, request, image_url, schema)
    }
}

/// The request body of `c` for `request`, with `image_url` as the image's URL and the JSON
/// schema if `schema`.
fn body(
    c: &HttpProviderConfig,
    request: &ChatRequest<'_>,
    image_url: Option<&str>,
    schema: bool,
) -> Value {
    let user = match image_url {
        None => json!(request.user),
        Some(url) => {
            let mut image = json!({ "url": url });
            if let Some(detail) = &c.detail {
                image["detail"] = json!(detail);
            }
            json!([
                { "type": "text", "text": request.user },
                { "type": "image_url", "image_url": image }
            ])
        }
    };
    let mut messages = vec![
        json!({ "role": "system", "content": request.system }),
        json!({ "role": "user", "content": user }),
    ];
    let mut max_tokens = c.max_tokens;
    if let Some(turn) = &request.follow_up {
        messages.push(json!({ "role": "assistant", "content": turn.assistant }));
        messages.push(json!({ "role": "user", "content": turn.user }));
        max_tokens = turn.max_tokens;
    }
    let mut body = json!({
        "model": c.model,
        "messages": messages,
        "max_tokens": max_tokens,
        "stream": false,
    });
    if let Some(t) = c.temperature {
        body["temperature"] = json!(t);
    }
    if let Some(s) = c.seed {
        body["seed"] = json!(s);
    }
    if schema {
        body["response_format"] = json!({
            "type": "json_schema",
            "json_schema": { "name": "exploration_target", "strict": true, "schema": answer_schema(c.reason_max_chars) }
        });
    }
    body
}

/// The reply text, usage, finish reason and reasoning of a Chat Completions body.
pub fn read_reply(body: &[u8]) -> Result<Reply, Failure> {
    let value: Value = serde_json::from_slice(body)
        .map_err(|e| Failure::new(FailureKind::BadBody, format!("the body is not JSON: {e}")))?;
    let usage = Usage {
        prompt_tokens: value
            .pointer("/usage/prompt_tokens")
            .and_then(Value::as_u64),
        completion_tokens: value
            .pointer("/usage/completion_tokens")
            .and_then(Value::as_u64),
    };
    let message = value.pointer("/choices/0/message");
    let reasoning = ["reasoning_content", "reasoning"]
        .iter()
        .find_map(|k| message.and_then(|m| m.get(*k)).and_then(Value::as_str))
        .unwrap_or_default()
        .to_string();
    let finish_reason = value
        .pointer("/choices/0/finish_reason")
        .and_then(Value::as_str)
        .map(str::to_string);
    let text = match message.and_then(|m| m.get("content")) {
        Some(Value::String(text)) => Some(text.clone()),
        Some(Value::Array(parts)) => Some(
            parts
                .iter()
                .filter_map(|p| p.get("text").and_then(Value::as_str))
                .collect::<Vec<_>>()
                .join(""),
        ),
        // A reasoning model cut while thinking: no content, only its reasoning.
        Some(Value::Null) | None if !reasoning.is_empty() => Some(String::new()),
        _ => None,
    };
    match text {
        Some(text) => Ok(Reply {
            text,
            usage,
            finish_reason,
            reasoning,
        }),
        None => {
            let why = value
                .pointer("/error/message")
                .and_then(Value::as_str)
                .map_or("no choices[0].message.content".to_string(), |m| {
                    format!("error: {m}")
                });
            Err(Failure::new(FailureKind::BadBody, why))
        }
    }
}

impl Provider for OpenAiProvider {
    fn complete(&mut self, request: &ChatRequest<'_>) -> Completion {
        let data_url = request.image_png.map(|png| {
            format!(
                "data:image/png;base64,{}",
                base64::engine::general_purpose::STANDARD.encode(png)
            )
        });
        let placeholder = request.image_png.map(super::image_placeholder);
        let mode = self.config.structured_output;
        let follow_up = request.follow_up.is_some();
        let config = &self.config;
        let build = |schema: bool| {
            (
                serde_json::to_vec(&body(config, request, data_url.as_deref(), schema))
                    .unwrap_or_default(),
                body(config, request, placeholder.as_deref(), schema).to_string(),
            )
        };
        let (out, recorded, dropped) = super::post_with_schema(
            &mut self.http,
            &self.url,
            "response_format",
            mode.wanted(follow_up),
            mode == StructuredOutput::On,
            &mut self.schema_refused,
            build,
        );
        let mut c = Completion::from_http("openai", &self.config.model, recorded, out, read_reply);
        c.schema_refused = dropped;
        c
    }

    fn describe(&self) -> String {
        format!(
            "openai-compatible chat completions at {} (model `{}`{})",
            self.url,
            self.config.model,
            if self.config.api_key_env.is_some() {
                ", key from the environment"
            } else {
                ", no key"
            }
        )
    }
}
