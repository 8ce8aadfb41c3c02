//! `ollama`: the native `POST {base_url}/api/chat` (the release's LLaVA variant) with the
//! image in the user message's `images` (base64), `stream: false`, `format` (the answer's
//! JSON schema, when `structured_output` asks for it; dropped for the episode if the server
//! answers 400 naming `format`) and `options` (`seed`, `temperature`, `num_predict`). A
//! follow-up turn resends the conversation with the model's reply as the assistant's message
//! and the follow-up user message. A server that streams anyway answers with NDJSON, one
//! object per line: the pieces of `message.content` (and of `message.thinking`, a thinking
//! model's reasoning) are joined, and the counts and `done_reason` read from the last line.

use base64::Engine;
use serde_json::{Value, json};

use super::http::HttpClient;
use super::{ChatRequest, Completion, Failure, FailureKind, Provider, Reply};
use crate::config::{HttpProviderConfig, StructuredOutput};
use crate::error::LlmError;

/// The Ollama provider.
pub struct OllamaProvider {
    config: HttpProviderConfig,
    url: String,
    http: HttpClient,
    /// The server refused `format` once this episode: it is not sent again.
    schema_refused: bool,
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
            schema_refused: false,
        })
    }

    /// True once the server refused `format` this episode.
    pub fn schema_refused(&self) -> bool {
        self.schema_refused
    }

    /// The request body, with `image` as the image's base64 text and the JSON schema if
    /// `schema`.
    pub fn body(&self, request: &ChatRequest<'_>, image: Option<&str>, schema: bool) -> Value {
        body(&self.config, request, image, schema)
    }
}

/// The request body of `c` for `request`, with `image` as the image's base64 text and the
/// JSON schema if `schema`.
fn body(
    c: &HttpProviderConfig,
    request: &ChatRequest<'_>,
    image: Option<&str>,
    schema: bool,
) -> Value {
    let mut user = json!({ "role": "user", "content": request.user });
    if let Some(image) = image {
        user["images"] = json!([image]);
    }
    let mut messages = vec![json!({ "role": "system", "content": request.system }), user];
    let mut max_tokens = c.max_tokens;
    if let Some(turn) = &request.follow_up {
        messages.push(json!({ "role": "assistant", "content": turn.assistant }));
        messages.push(json!({ "role": "user", "content": turn.user }));
        max_tokens = turn.max_tokens;
    }
    let mut options = json!({ "num_predict": max_tokens });
    if let Some(s) = c.seed {
        options["seed"] = json!(s);
    }
    if let Some(t) = c.temperature {
        options["temperature"] = json!(t);
    }
    let mut body = json!({
        "model": c.model,
        "messages": messages,
        "stream": false,
        "options": options,
    });
    if schema {
        body["format"] = super::openai::answer_schema(c.reason_max_chars);
    }
    body
}

/// The reply text, usage, finish reason (`done_reason`) and thinking of an `/api/chat` body:
/// one JSON object, or NDJSON lines.
pub fn read_reply(body: &[u8]) -> Result<Reply, Failure> {
    let text = std::str::from_utf8(body)
        .map_err(|e| Failure::new(FailureKind::BadBody, format!("the body is not UTF-8: {e}")))?;
    let lines: Vec<&str> = text.lines().filter(|l| !l.trim().is_empty()).collect();
    if lines.is_empty() {
        return Err(Failure::new(FailureKind::BadBody, "empty body"));
    }
    let mut reply = Reply::default();
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
            Some(Value::String(piece)) => reply.text += piece,
            _ => {
                return Err(Failure::new(
                    FailureKind::BadBody,
                    format!("line {} has no message.content", i + 1),
                ));
            }
        }
        if let Some(Value::String(piece)) = value.pointer("/message/thinking") {
            reply.reasoning += piece;
        }
        if value.get("done").and_then(Value::as_bool) == Some(true) {
            done = true;
            reply.usage.prompt_tokens = value.get("prompt_eval_count").and_then(Value::as_u64);
            reply.usage.completion_tokens = value.get("eval_count").and_then(Value::as_u64);
            reply.finish_reason = value
                .get("done_reason")
                .and_then(Value::as_str)
                .map(str::to_string);
        }
    }
    if !done && lines.len() > 1 {
        return Err(Failure::new(
            FailureKind::BadBody,
            "the streamed reply ended before its `done` line",
        ));
    }
    Ok(reply)
}

impl Provider for OllamaProvider {
    fn complete(&mut self, request: &ChatRequest<'_>) -> Completion {
        let image = request
            .image_png
            .map(|png| base64::engine::general_purpose::STANDARD.encode(png));
        let placeholder = request.image_png.map(super::image_placeholder);
        let mode = self.config.structured_output;
        let config = &self.config;
        let build = |schema: bool| {
            (
                serde_json::to_vec(&body(config, request, image.as_deref(), schema))
                    .unwrap_or_default(),
                body(config, request, placeholder.as_deref(), schema).to_string(),
            )
        };
        let (out, recorded, dropped) = super::post_with_schema(
            &mut self.http,
            &self.url,
            "format",
            mode.wanted(request.follow_up.is_some()),
            mode == StructuredOutput::On,
            &mut self.schema_refused,
            build,
        );
        let mut c = Completion::from_http("ollama", &self.config.model, recorded, out, read_reply);
        c.schema_refused = dropped;
        c
    }

    fn describe(&self) -> String {
        format!(
            "ollama chat at {} (model `{}`)",
            self.url, self.config.model
        )
    }
}
