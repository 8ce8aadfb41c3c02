//! The loopback model server shared by the provider tests: wiremock on a runtime of its own,
//! scripted per test to answer like OpenAI's and Ollama's APIs.

use serde_json::{Value, json};
use wiremock::{Mock, MockServer, Request};

use activemap_llm::config::{HttpProviderConfig, LlmConfig, PromptStyle, ProviderConfig};
use activemap_llm::{Candidate, LlmPlanner, Query};
use activemap_splat::Gaussians;

/// A loopback server and the runtime that serves it (the providers are blocking, so the
/// tests run on the plain test thread and the server on the runtime's workers).
pub struct Server {
    runtime: tokio::runtime::Runtime,
    /// The server.
    pub server: MockServer,
}

impl Server {
    /// Starts a server on loopback.
    pub fn start() -> Self {
        let runtime = tokio::runtime::Builder::new_multi_thread()
            .worker_threads(1)
            .enable_all()
            .build()
            .unwrap();
        let server = runtime.block_on(MockServer::start());
        Self { runtime, server }
    }

    /// Mounts `mock`.
    pub fn mount(&self, mock: Mock) {
        self.runtime.block_on(mock.mount(&self.server));
    }

    /// Answers every `POST /api/chat` with Ollama's streamed reply: `chunks` as NDJSON lines.
    pub fn ollama_stream(&self, chunks: &[Value]) {
        let ndjson = chunks
            .iter()
            .map(Value::to_string)
            .collect::<Vec<_>>()
            .join("\n");
        self.mount(
            Mock::given(wiremock::matchers::method("POST"))
                .and(wiremock::matchers::path("/api/chat"))
                .respond_with(
                    wiremock::ResponseTemplate::new(200)
                        .set_body_raw(ndjson, "application/x-ndjson"),
                ),
        );
    }

    /// The requests received so far.
    pub fn requests(&self) -> Vec<Request> {
        self.runtime
            .block_on(self.server.received_requests())
            .unwrap_or_default()
    }

    /// An `openai` config for this server with short timeouts and backoff.
    pub fn openai(&self) -> HttpProviderConfig {
        let mut c = HttpProviderConfig::new(&format!("{}/v1", self.server.uri()), "test-model");
        c.timeout_s = 2.0;
        c.connect_timeout_s = 1.0;
        c.max_retries = 2;
        c.backoff_s = 0.05;
        c.backoff_max_s = 2.0;
        c
    }
}

/// A Chat Completions body answering `content` (finish reason `stop`).
pub fn chat_ok(content: &str) -> Value {
    json!({
        "id": "chatcmpl-1", "object": "chat.completion", "model": "test-model",
        "choices": [{ "index": 0, "message": { "role": "assistant", "content": content },
                      "finish_reason": "stop" }],
        "usage": { "prompt_tokens": 812, "completion_tokens": 40, "total_tokens": 852 }
    })
}

/// `n` candidates, the first the largest.
pub fn candidates(n: usize) -> Vec<Candidate> {
    (0..n)
        .map(|i| Candidate {
            centroid: [i as f64, 1.0],
            label_at: [i as f64, 1.1],
            size_cells: 50 - i as u32,
            area_m2: 0.1,
            path_distance_m: 1.0 + i as f64,
        })
        .collect()
}

/// A planner with `prompt` asking the server's `openai` endpoint.
pub fn planner(s: &Server, prompt: PromptStyle) -> LlmPlanner {
    let config = LlmConfig {
        prompt,
        provider: Some(ProviderConfig::Openai(s.openai())),
        ..LlmConfig::default()
    };
    let provider =
        activemap_llm::provider::from_config(config.provider.as_ref().unwrap(), None, 1).unwrap();
    LlmPlanner::new(config, Some(provider)).unwrap()
}

/// A query at `step` (also the map version) over `candidates`.
pub fn query<'a>(map: &'a Gaussians<f32>, candidates: &'a [Candidate], step: u64) -> Query<'a> {
    Query {
        step,
        total_steps: 2000,
        map,
        map_version: step,
        camera_height_m: 1.0,
        robot: [0.0, 0.0, 0.0],
        path: &[],
        candidates,
    }
}
