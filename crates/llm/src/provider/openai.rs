//! `openai`: Chat Completions (`POST {base_url}/chat/completions`) at any OpenAI-compatible
//! base URL. The image goes as a `data:image/png;base64,…` `image_url` part of the user
//! message (with `detail` if set); `max_tokens`, `temperature`, `seed` and, with
//! `structured_output`, a `response_format` JSON schema of `{target, reason}`.

use base64::Engine;
use serde_json::{Value, json};

use super::http::HttpClient;
use super::{ChatRequest, Completion, Failure, FailureKind, Provider, Usage};
use crate::config::HttpProviderConfig;
use crate::error::LlmError;

/// The JSON schema of the answer, for providers' structured output.
pub fn answer_schema() -> Value {
    json!({
        "type": "object",
        "properties": {
            "target": { "type": "integer" },
            "reason": { "type": "string" }
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
        })
    }

    /// The request body, with `image_url` as the image's URL.
    pub fn body(&self, request: &ChatRequest<'_>, image_url: Option<&str>) -> Value {
        let c = &self.config;
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
        let mut body = json!({
            "model": c.model,
            "messages": [
                { "role": "system", "content": request.system },
                { "role": "user", "content": user }
            ],
            "max_tokens": c.max_tokens,
            "stream": false,
        });
        if let Some(t) = c.temperature {
            body["temperature"] = json!(t);
        }
        if let Some(s) = c.seed {
            body["seed"] = json!(s);
        }
        if c.structured_output {
            body["response_format"] = json!({
                "type": "json_schema",
                "json_schema": { "name": "exploration_target", "strict": true, "schema": answer_schema() }
            });
        }
        body
    }
}

/// The reply text and usage of a Chat Completions body.
pub fn read_reply(body: &[u8]) -> Result<(String, Usage), Failure> {
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
    match value.pointer("/choices/0/message/content") {
        Some(Value::String(text)) => Ok((text.clone(), usage)),
        Some(Value::Array(parts)) => Ok((
            parts
                .iter()
                .filter_map(|p| p.get("text").and_then(Value::as_str))
                .collect::<Vec<_>>()
                .join(""),
            usage,
        )),
        _ => {
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
        let sent = serde_json::to_vec(&self.body(request, data_url.as_deref())).unwrap_or_default();
        let placeholder = request.image_png.map(super::image_placeholder);
        let recorded = self.body(request, placeholder.as_deref()).to_string();
        let out = self.http.post_json(&self.url, &sent);
        Completion::from_http("openai", &self.config.model, recorded, out, read_reply)
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
