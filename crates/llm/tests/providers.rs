//! The providers against a real HTTP server on loopback (wiremock) that answers like OpenAI's
//! and Ollama's APIs, and fails like them: every fault ends in a recorded failure (and a
//! fallback decision) or a parsed answer, never a crash or a hang; every test is bounded in
//! time by short timeouts and few retries.

use std::time::{Duration, Instant};

use activemap_llm::config::{
    HttpProviderConfig, LlmConfig, PromptStyle, ProviderConfig, StructuredOutput,
};
use activemap_llm::provider::{ChatRequest, FailureKind, OllamaProvider, OpenAiProvider, Provider};
use activemap_llm::{Choice, LlmPlanner, Source};
use activemap_splat::Gaussians;
use base64::Engine;
use serde_json::{Value, json};
use wiremock::matchers::{method, path};
use wiremock::{Mock, ResponseTemplate};

mod common;
use common::{Server, candidates, chat_ok, planner, query};

const PNG: &[u8] = b"\x89PNG\r\n\x1a\n-not-really-but-bytes";

fn request(image: bool) -> ChatRequest<'static> {
    ChatRequest {
        system: "system text",
        user: "user text",
        image_png: image.then_some(PNG),
        follow_up: None,
    }
}

fn completions() -> wiremock::MockBuilder {
    Mock::given(method("POST")).and(path("/v1/chat/completions"))
}

/// Model, messages, the image as a data URL that decodes to the PNG sent, the headers; the
/// key goes only in the `Authorization` header: never in the body or the recorded request.
#[test]
fn the_openai_request_is_right_and_the_key_stays_in_its_header() {
    let s = Server::start();
    s.mount(
        completions().respond_with(
            ResponseTemplate::new(200)
                .set_body_json(chat_ok("Plan: go.\n{\"target\": 1, \"reason\": \"door\"}")),
        ),
    );
    let mut config = s.openai();
    config.api_key_env = Some("ACTIVEMAP_TEST_OPENAI_KEY".into());
    config.detail = Some("high".into());
    config.seed = Some(7);
    config.temperature = Some(0.0);
    config.structured_output = StructuredOutput::On;
    config.reason_max_chars = Some(160);
    // SAFETY: set before any thread of this test reads the environment.
    unsafe { std::env::set_var("ACTIVEMAP_TEST_OPENAI_KEY", "sk-test-4242") };
    let mut p = OpenAiProvider::new(&config, 1).unwrap();
    let c = p.complete(&request(true));
    assert_eq!(c.failure, None, "{c:?}");
    assert_eq!(c.reply, "Plan: go.\n{\"target\": 1, \"reason\": \"door\"}");
    assert_eq!((c.http_status, c.attempts), (Some(200), 1));
    assert_eq!(c.usage.prompt_tokens, Some(812));
    assert_eq!(c.usage.completion_tokens, Some(40));

    let received = s.requests();
    assert_eq!(received.len(), 1);
    let r = &received[0];
    assert_eq!(
        r.headers.get("authorization").unwrap().to_str().unwrap(),
        "Bearer sk-test-4242"
    );
    assert!(
        r.headers
            .get("content-type")
            .unwrap()
            .to_str()
            .unwrap()
            .starts_with("application/json")
    );
    let body: Value = serde_json::from_slice(&r.body).unwrap();
    assert_eq!(body["model"], "test-model");
    assert_eq!(body["max_tokens"], 1000);
    assert_eq!(body["seed"], 7);
    assert_eq!(body["temperature"], 0.0);
    assert_eq!(body["response_format"]["type"], "json_schema");
    let schema = &body["response_format"]["json_schema"]["schema"];
    assert_eq!(schema["properties"]["reason"]["maxLength"], 160);
    // Sorted keys: a grammar made from the schema writes the bounded reason, then the target.
    let text = serde_json::to_string(schema).unwrap();
    assert!(text.find("\"reason\"").unwrap() < text.find("\"target\"").unwrap());
    assert_eq!(body["messages"][0]["role"], "system");
    assert_eq!(body["messages"][0]["content"], "system text");
    assert_eq!(body["messages"][1]["content"][0]["text"], "user text");
    let image = &body["messages"][1]["content"][1]["image_url"];
    assert_eq!(image["detail"], "high");
    let url = image["url"].as_str().unwrap();
    let b64 = url.strip_prefix("data:image/png;base64,").unwrap();
    assert_eq!(
        base64::engine::general_purpose::STANDARD
            .decode(b64)
            .unwrap(),
        PNG
    );
    let raw = String::from_utf8_lossy(&r.body);
    assert!(!raw.contains("sk-test"), "the key is not in the body");
    assert!(!c.request.contains("sk-test") && !c.reply.contains("sk-test"));
    assert!(
        c.request
            .contains(&format!("<bev.png: {} bytes>", PNG.len()))
    );
    assert!(!p.describe().contains("sk-test"));
    assert!(!format!("{config:?}").contains("sk-test"));
}

#[test]
fn connection_refused_is_a_connect_failure() {
    let port = {
        let l = std::net::TcpListener::bind("127.0.0.1:0").unwrap();
        l.local_addr().unwrap().port()
    };
    let mut config = HttpProviderConfig::new(&format!("http://127.0.0.1:{port}/v1"), "m");
    config.max_retries = 1;
    config.backoff_s = 0.01;
    let mut p = OpenAiProvider::new(&config, 1).unwrap();
    let c = p.complete(&request(false));
    let f = c.failure.unwrap();
    assert_eq!(f.kind, FailureKind::Connect, "{f}");
    assert_eq!((c.attempts, c.http_status), (2, None));
}

#[test]
fn a_server_that_never_answers_times_out() {
    let s = Server::start();
    s.mount(
        completions().respond_with(
            ResponseTemplate::new(200)
                .set_body_json(chat_ok("{}"))
                .set_delay(Duration::from_secs(30)),
        ),
    );
    let mut config = s.openai();
    config.timeout_s = 0.4;
    config.max_retries = 1;
    let mut p = OpenAiProvider::new(&config, 1).unwrap();
    let t = Instant::now();
    let c = p.complete(&request(false));
    assert!(t.elapsed() < Duration::from_secs(5), "{:?}", t.elapsed());
    assert_eq!(c.failure.unwrap().kind, FailureKind::Timeout);
    assert_eq!(c.attempts, 2);
}

#[test]
fn rate_limited_with_retry_after_then_success() {
    let s = Server::start();
    s.mount(
        completions()
            .respond_with(ResponseTemplate::new(429).insert_header("Retry-After", "1"))
            .up_to_n_times(1),
    );
    s.mount(completions().respond_with(
        ResponseTemplate::new(200).set_body_json(chat_ok("{\"target\": 0, \"reason\": \"r\"}")),
    ));
    let mut p = OpenAiProvider::new(&s.openai(), 1).unwrap();
    let t = Instant::now();
    let c = p.complete(&request(false));
    assert!(
        t.elapsed() >= Duration::from_millis(950),
        "Retry-After honoured"
    );
    assert_eq!(c.failure, None);
    assert_eq!((c.attempts, c.http_status), (2, Some(200)));
    assert!(c.latency_ms >= 950.0);
}

#[test]
fn a_retry_after_longer_than_allowed_gives_up_at_once() {
    let s = Server::start();
    s.mount(
        completions().respond_with(ResponseTemplate::new(503).insert_header("Retry-After", "3600")),
    );
    let mut p = OpenAiProvider::new(&s.openai(), 1).unwrap();
    let c = p.complete(&request(false));
    let f = c.failure.unwrap();
    assert_eq!(f.kind, FailureKind::RateLimited);
    assert!(f.detail.contains("3600"), "{f}");
    assert_eq!(c.attempts, 1);
}

#[test]
fn server_error_then_success_and_server_error_forever() {
    let s = Server::start();
    s.mount(
        completions()
            .respond_with(ResponseTemplate::new(500))
            .up_to_n_times(1),
    );
    s.mount(completions().respond_with(
        ResponseTemplate::new(200).set_body_json(chat_ok("{\"target\": 0, \"reason\": \"r\"}")),
    ));
    let mut p = OpenAiProvider::new(&s.openai(), 1).unwrap();
    let c = p.complete(&request(false));
    assert_eq!((c.failure, c.attempts), (None, 2));

    let s = Server::start();
    s.mount(completions().respond_with(ResponseTemplate::new(500).set_body_string("boom")));
    let mut p = OpenAiProvider::new(&s.openai(), 1).unwrap();
    let c = p.complete(&request(false));
    let f = c.failure.unwrap();
    assert_eq!(f.kind, FailureKind::HttpStatus);
    assert!(f.detail.contains("500") && f.detail.contains("boom"), "{f}");
    assert_eq!((c.attempts, c.http_status), (3, Some(500)));
    assert_eq!(s.requests().len(), 3, "bounded retries");
}

#[test]
fn a_client_error_is_not_retried() {
    let s = Server::start();
    s.mount(completions().respond_with(
        ResponseTemplate::new(401).set_body_json(json!({"error": {"message": "bad key"}})),
    ));
    let mut p = OpenAiProvider::new(&s.openai(), 1).unwrap();
    let c = p.complete(&request(false));
    assert_eq!(c.failure.unwrap().kind, FailureKind::HttpStatus);
    assert_eq!(c.attempts, 1);
    assert!(c.reply.contains("bad key"), "the body excerpt is kept");
}

#[test]
fn a_body_that_is_not_json_or_too_large() {
    let s = Server::start();
    s.mount(completions().respond_with(ResponseTemplate::new(200).set_body_string("<html>oops")));
    let mut p = OpenAiProvider::new(&s.openai(), 1).unwrap();
    let c = p.complete(&request(false));
    assert_eq!(c.failure.unwrap().kind, FailureKind::BadBody);
    assert_eq!(c.reply, "<html>oops");

    let s = Server::start();
    let huge = "x".repeat(10 << 20);
    s.mount(completions().respond_with(ResponseTemplate::new(200).set_body_json(chat_ok(&huge))));
    let mut p = OpenAiProvider::new(&s.openai(), 1).unwrap();
    let c = p.complete(&request(false));
    assert_eq!(c.failure.unwrap().kind, FailureKind::TooLarge);
    assert_eq!(c.attempts, 1);
    assert!(c.reply.len() <= 64 * 1024, "only an excerpt is kept");
}

/// Ollama's native API: images in the user message, `stream: false`, `options`; and a
/// server that streams NDJSON anyway.
#[test]
fn ollama_request_and_streamed_ndjson() {
    let s = Server::start();
    s.ollama_stream(&[
        json!({"model": "llava", "message": {"role": "assistant", "content": "Plan. {\"target\": "}, "done": false}),
        json!({"model": "llava", "message": {"role": "assistant", "content": "2, \"reason\": \"hall\"}"}, "done": false}),
        json!({"model": "llava", "message": {"role": "assistant", "content": ""}, "done": true,
               "prompt_eval_count": 600, "eval_count": 25}),
    ]);
    let mut config = s.openai();
    config.base_url = s.server.uri();
    config.seed = Some(3);
    config.max_tokens = 300;
    let mut p = OllamaProvider::new(&config, 1).unwrap();
    let c = p.complete(&request(true));
    assert_eq!(c.failure, None, "{c:?}");
    assert_eq!(c.reply, "Plan. {\"target\": 2, \"reason\": \"hall\"}");
    assert_eq!(c.usage.prompt_tokens, Some(600));
    assert_eq!(c.usage.completion_tokens, Some(25));
    let body: Value = serde_json::from_slice(&s.requests()[0].body).unwrap();
    assert_eq!(body["stream"], false);
    assert_eq!(body["options"]["seed"], 3);
    assert_eq!(body["options"]["num_predict"], 300);
    assert_eq!(body["messages"][1]["content"], "user text");
    let image = body["messages"][1]["images"][0].as_str().unwrap();
    assert_eq!(
        base64::engine::general_purpose::STANDARD
            .decode(image)
            .unwrap(),
        PNG
    );
    assert!(c.request.contains("<bev.png:"));
}

/// Replies the planner cannot use fall back to the largest frontier (candidate 0 here) with
/// the reason recorded; valid ones are taken, −1 included.
#[test]
fn bad_replies_fall_back_to_the_largest_frontier_with_their_reason() {
    let cases: &[(&str, Option<FailureKind>, Choice)] = &[
        (
            "I think the kitchen.",
            Some(FailureKind::NoJson),
            Choice::Frontier(0),
        ),
        (
            "{\"target\": 2, \"reason\": \"The ta",
            Some(FailureKind::BadJson),
            Choice::Frontier(0),
        ),
        (
            "{\"target\": 3, \"reason\": \"r\"}",
            Some(FailureKind::BadTarget),
            Choice::Frontier(0),
        ),
        (
            "{\"target\": -2, \"reason\": \"r\"}",
            Some(FailureKind::BadTarget),
            Choice::Frontier(0),
        ),
        (
            "{\"target\": \"2\", \"reason\": \"r\"}",
            Some(FailureKind::BadTarget),
            Choice::Frontier(0),
        ),
        (
            "{\"target\": 1.5, \"reason\": \"r\"}",
            Some(FailureKind::BadTarget),
            Choice::Frontier(0),
        ),
        (
            "{\"target\": 2}",
            Some(FailureKind::BadTarget),
            Choice::Frontier(0),
        ),
        (
            "plan\n```json\n{\"target\": 2, \"reason\": \"hall\"}\n```",
            None,
            Choice::Frontier(2),
        ),
        (
            "{\"target\": -1, \"reason\": \"refine\"}",
            None,
            Choice::Refine,
        ),
    ];
    let map = Gaussians::new();
    let c = candidates(3);
    for (step, (reply, kind, choice)) in cases.iter().enumerate() {
        let s = Server::start();
        s.mount(
            completions().respond_with(ResponseTemplate::new(200).set_body_json(chat_ok(reply))),
        );
        let mut p = planner(&s, PromptStyle::Text);
        let d = p.decide(&query(&map, &c, step as u64)).unwrap();
        assert_eq!(d.choice, *choice, "{reply}");
        let e = d.exchange.unwrap();
        assert_eq!(e.fallback.as_ref().map(|f| f.kind), *kind, "{reply}");
        assert_eq!(e.completion.reply, *reply);
        assert_eq!(e.decision, choice.target());
        // The largest of the three candidates is the first: the fallback's choice.
        assert_eq!(e.fallback_target, 0);
        match kind {
            Some(k) => {
                assert!(matches!(&d.source, Source::Fallback(f) if f.kind == *k));
                assert_eq!(p.stats().fallbacks.get(k), Some(&1));
            }
            None => assert_eq!(d.source, Source::Model),
        }
    }
}

/// The same question is not asked twice (same map version and candidates), a minimum
/// interval holds the last target, and the call budget ends the queries.
#[test]
fn asking_rules_and_the_budget() {
    let s = Server::start();
    s.mount(completions().respond_with(
        ResponseTemplate::new(200).set_body_json(chat_ok("{\"target\": 1, \"reason\": \"r\"}")),
    ));
    let mut config = LlmConfig {
        prompt: PromptStyle::Text,
        provider: Some(ProviderConfig::Openai(s.openai())),
        ..LlmConfig::default()
    };
    config.ask.min_interval_steps = 10;
    config.budget.max_calls = Some(2);
    let provider =
        activemap_llm::provider::from_config(config.provider.as_ref().unwrap(), None, 1).unwrap();
    let mut p = LlmPlanner::new(config, Some(provider)).unwrap();
    let map = Gaussians::new();
    let c = candidates(3);
    let mut q = query(&map, &c, 100);
    assert_eq!(p.decide(&q).unwrap().source, Source::Model);
    q.step = 103;
    let again = p.decide(&q).unwrap();
    assert_eq!(
        (again.source, again.choice),
        (Source::Reused, Choice::Frontier(1))
    );
    q.map_version = 101;
    q.step = 105;
    let held = p.decide(&q).unwrap();
    assert_eq!(
        (held.source, held.choice),
        (Source::Held, Choice::Frontier(1))
    );
    q.step = 140;
    assert_eq!(p.decide(&q).unwrap().source, Source::Model);
    q.map_version = 150;
    q.step = 150;
    let spent = p.decide(&q).unwrap();
    assert!(matches!(&spent.source, Source::Fallback(f) if f.kind == FailureKind::Budget));
    assert_eq!(spent.choice, Choice::Frontier(0));
    assert_eq!(s.requests().len(), 2);
    assert_eq!(p.stats().calls, 2);
    assert_eq!(p.stats().usage.prompt_tokens, Some(2 * 812));
}

/// With no provider, every decision is the largest frontier and nothing is sent.
#[test]
fn the_offline_default_takes_the_largest_frontier() {
    let mut p = LlmPlanner::new(LlmConfig::default(), None).unwrap();
    assert!(p.describe().contains("largest frontier"));
    let map = Gaussians::new();
    let mut c = candidates(3);
    c[2].size_cells = 99;
    let d = p.decide(&query(&map, &c, 5)).unwrap();
    assert_eq!(d.choice, Choice::Frontier(2));
    assert!(d.exchange.is_none());
    assert!(matches!(d.source, Source::Fallback(f) if f.kind == FailureKind::NoProvider));
}

/// The image prompt: the PNG in the request is the BEV the planner rendered and recorded.
#[test]
fn the_image_sent_is_the_bev_recorded() {
    let s = Server::start();
    s.mount(completions().respond_with(
        ResponseTemplate::new(200).set_body_json(chat_ok("{\"target\": 0, \"reason\": \"r\"}")),
    ));
    let mut p = planner(&s, PromptStyle::Image);
    let mut map = Gaussians::new();
    for i in 0..50 {
        map.push(
            [i as f64 * 0.1, 0.5, 0.2],
            [0.5, 0.0, 0.0],
            [1.0, 0.0, 0.0, 0.0],
            2.0,
            [-3.0; 3],
        );
    }
    let c = candidates(2);
    let d = p.decide(&query(&map, &c, 9)).unwrap();
    let e = d.exchange.unwrap();
    assert!(e.bev_png.starts_with(b"\x89PNG"));
    let body: Value = serde_json::from_slice(&s.requests()[0].body).unwrap();
    let url = body["messages"][1]["content"][1]["image_url"]["url"]
        .as_str()
        .unwrap();
    let sent = base64::engine::general_purpose::STANDARD
        .decode(url.strip_prefix("data:image/png;base64,").unwrap())
        .unwrap();
    assert_eq!(sent, e.bev_png);
    let decoded = image::load_from_memory(&sent).unwrap();
    assert_eq!(decoded.width().max(decoded.height()), 800);
    assert!(e.prompt.system.contains("there are 2 candidate points"));
}
