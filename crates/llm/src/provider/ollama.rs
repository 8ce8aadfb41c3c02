//! `ollama`: the native `POST {base_url}/api/chat` (the release's LLaVA variant) with the
//! image in the user message's `images` (base64), `stream: false`, `format` (the answer's
//! JSON schema, with `structured_output`) and `options` (`seed`, `temperature`,
//! `num_predict`). A server that streams anyway answers with NDJSON, one object per line:
//! the pieces of `message.content` are joined, and the counts read from the last line.

use base64::Engine;
use serde_json::{Value, json};

use super::http::HttpClient;
use super::{ChatRequest, Completion, Failure, FailureKind, Provider, Usage};
use crate::config::HttpProviderConfig;
use crate::error::LlmError;

/// The Ollama provider.
pub struct OllamaProvider {
    config: HttpProviderConfig,
    url: String,
    http: HttpClient,
}

impl OllamaProvider {
    /// The provider of `config` (a key, if `api_key_env` names one, goes as a bearer token,
    /// for servers behind a proxy); `seed` seeds the jitter.
    pub fn new(config: &HttpProviderConfig, seed: u64) -> Result<Self, LlmError> {
        config.validate("provider (ollama)")?;
        let key = super::api_key(config)?;
        Ok(Self {
            url: format!("{}/api/chat", config.base_url.trim_end_matches('/')),
            http: HttpClient::new(config, key, seed)?,
            config: config.clone(),
        })
    }

    /// The request body, with `image` as the image's base64 text.
    pub fn body(&self, request: &ChatRequest<'_>, image: Option<&str>) -> Value {
        let c = &self.config;
        let mut user = json!({ "role": "user", "content": request.user });
        if let Some(image) = image {
            user["images"] = json!([image]);
        }
        let mut options = json!({ "num_predict": c.max_tokens });
        if let Some(s) = c.seed {
            options["seed"] = json!(s);
        }
        if let Some(t) = c.temperature {
            options["temperature"] = json!(t);
        }
        let mut body = json!({
            "model": c.model,
            "messages": [ { "role": "system", "content": request.system }, user ],
            "stream": false,
            "options": options,
        });
        if c.structured_output {
            body["format"] = super::openai::answer_schema();
        }
        body
    }
}

/// The reply text and usage of an `/api/chat` body: one JSON object, or NDJSON lines.
pub fn read_reply(body: &[u8]) -> Result<(String, Usage), Failure> {
    let text = std::str::from_utf8(body)
        .map_err(|e| Failure::new(FailureKind::BadBody, format!("the body is not UTF-8: {e}")))?;
    let lines: Vec<&str> = text.lines().filter(|l| !l.trim().is_empty()).collect();
    if lines.is_empty() {
        return Err(Failure::new(FailureKind::BadBody, "empty body"));
    }
    let mut content = String::new();
    let mut usage = Usage::default();
    let mut done = false;
    for (i, line) in lines.iter().enumerate() {
        let value: Value = serde_json::from_str(line).map_err(|e| {
            Failure::new(
                FailureKind::BadBody,
                format!("line {} of the body is not JSON: {e}", i + 1),
            )
        })?;
        if let Some(m) = value.get("error").and_then(Value::as_str) {
            return Err(Failure::new(FailureKind::BadBody, format!("error: {m}")));
        }
        match value.pointer("/message/content") {
            Some(Value::String(piece)) => content += piece,
            _ => {
                return Err(Failure::new(
                    FailureKind::BadBody,
                    format!("line {} has no message.content", i + 1),
                ));
            }
        }
        if value.get("done").and_then(Value::as_bool) == Some(true) {
            done = true;
            usage.prompt_tokens = value.get("prompt_eval_count").and_then(Value::as_u64);
            usage.completion_tokens = value.get("eval_count").and_then(Value::as_u64);
        }
    }
    if !done && lines.len() > 1 {
        return Err(Failure::new(
            FailureKind::BadBody,
            "the streamed reply ended before its `done` line",
        ));
    }
    Ok((content, usage))
}

impl Provider for OllamaProvider {
    fn complete(&mut self, request: &ChatRequest<'_>) -> Completion {
        let image = request
            .image_png
            .map(|png| base64::engine::general_purpose::STANDARD.encode(png));
        let sent = serde_json::to_vec(&self.body(request, image.as_deref())).unwrap_or_default();
        let placeholder = request.image_png.map(super::image_placeholder);
        let recorded = self.body(request, placeholder.as_deref()).to_string();
        let out = self.http.post_json(&self.url, &sent);
        Completion::from_http("ollama", &self.config.model, recorded, out, read_reply)
    }

    fn describe(&self) -> String {
        format!(
            "ollama chat at {} (model `{}`)",
            self.url, self.config.model
        )
    }
}
