//! The replies of the models people run locally, against a real HTTP server on loopback
//! (wiremock): a reply cut by the token limit or without JSON gets one follow-up turn in the
//! same conversation; a server that refuses the JSON schema is asked again without it, and
//! not asked with it again; the reasoning of reasoning models (`<think>` blocks,
//! `reasoning_content`, Ollama's `thinking`) is kept and never parsed; a recorded exchange
//! serves its follow-up on replay.

use activemap_llm::config::{LlmConfig, PromptStyle, ProviderConfig, StructuredOutput};
use activemap_llm::provider::{ChatRequest, RecordedReply};
use activemap_llm::provider::{FailureKind, OllamaProvider, Provider, RecordedProvider};
use activemap_llm::{Choice, LlmPlanner, Source};
use activemap_splat::Gaussians;
use serde_json::{Value, json};
use wiremock::matchers::{method, path};
use wiremock::{Mock, Request, ResponseTemplate};

mod common;
use common::{Server, candidates, chat_ok, query};

/// A Chat Completions body with `content`, `finish_reason` and, if not empty,
/// `reasoning_content`.
fn chat(content: Value, finish: &str, reasoning: &str) -> Value {
    let mut message = json!({ "role": "assistant", "content": content });
    if !reasoning.is_empty() {
        message["reasoning_content"] = json!(reasoning);
    }
    json!({
        "id": "chatcmpl-2", "object": "chat.completion", "model": "test-model",
        "choices": [{ "index": 0, "message": message, "finish_reason": finish }],
        "usage": { "prompt_tokens": 300, "completion_tokens": 200, "total_tokens": 500 }
    })
}

/// The request's JSON body.
fn body(r: &Request) -> Value {
    serde_json::from_slice(&r.body).unwrap()
}

/// True when the request is a follow-up turn (system, user, assistant, user).
fn is_follow_up(r: &Request) -> bool {
    body(r)["messages"].as_array().map_or(0, Vec::len) == 4
}

fn completions() -> wiremock::MockBuilder {
    Mock::given(method("POST")).and(path("/v1/chat/completions"))
}

/// A planner of `config` (its provider set).
fn planner_of(config: LlmConfig) -> LlmPlanner {
    let provider =
        activemap_llm::provider::from_config(config.provider.as_ref().unwrap(), None, 1).unwrap();
    LlmPlanner::new(config, Some(provider)).unwrap()
}

const PLAN: &str = "Exploration Plan:\n1. Look at the corridor.\n2. Then the rooms on the";

/// A reply cut by the token limit (`finish_reason: length`) before its JSON gets one
/// follow-up: the same conversation with the model's own text as the assistant's turn and a
/// short user turn asking only for the JSON, with the follow-up's token limit and the schema.
/// Its answer is the decision; both turns are in the exchange and the totals.
#[test]
fn a_cut_reply_is_recovered_by_the_follow_up() {
    let s = Server::start();
    s.mount(completions().respond_with(|r: &Request| {
        let reply = if is_follow_up(r) {
            chat(json!("{\"target\": 2, \"reason\": \"hall\"}"), "stop", "")
        } else {
            chat(json!(PLAN), "length", "")
        };
        ResponseTemplate::new(200).set_body_json(reply)
    }));
    let mut p = common::planner(&s, PromptStyle::TextCompact);
    let map = Gaussians::new();
    let c = candidates(3);
    let d = p.decide(&query(&map, &c, 10)).unwrap();
    assert_eq!((d.choice, &d.source), (Choice::Frontier(2), &Source::Model));
    let e = d.exchange.unwrap();
    assert_eq!(e.fallback, None);
    assert_eq!(e.answer.as_ref().map(|a| a.reason.as_str()), Some("hall"));
    assert_eq!(e.completion.reply, PLAN);
    assert_eq!(e.completion.finish_reason.as_deref(), Some("length"));
    let f = e.follow_up.as_ref().expect("a follow-up");
    assert_eq!(f.cause.kind, FailureKind::NoJson);
    assert!(
        f.cause.detail.contains("finish reason length"),
        "{}",
        f.cause
    );
    assert_eq!(f.completion.finish_reason.as_deref(), Some("stop"));
    assert!(f.completion.request.contains("\"role\":\"assistant\""));

    let received = s.requests();
    assert_eq!(received.len(), 2);
    let first = body(&received[0]);
    assert_eq!(first["max_tokens"], 1000);
    assert!(
        first.get("response_format").is_none(),
        "the first turn is the prompt's own"
    );
    let second = body(&received[1]);
    assert_eq!(second["messages"][0], first["messages"][0]);
    assert_eq!(second["messages"][1], first["messages"][1]);
    assert_eq!(second["messages"][2]["role"], "assistant");
    assert_eq!(second["messages"][2]["content"], PLAN);
    assert_eq!(second["messages"][3]["role"], "user");
    let ask = second["messages"][3]["content"].as_str().unwrap();
    assert!(ask.contains("only the JSON object") && ask.contains("from 0 to 2"));
    assert_eq!(second["max_tokens"], 256);
    assert_eq!(second["response_format"]["type"], "json_schema");
    assert_eq!(
        second["response_format"]["json_schema"]["schema"]["required"],
        json!(["target", "reason"])
    );
    let stats = p.stats();
    assert_eq!(
        (
            stats.queries,
            stats.calls,
            stats.follow_ups,
            stats.recovered
        ),
        (1, 2, 1, 1)
    );
    assert_eq!(stats.usage.completion_tokens, Some(400));
}

/// A complete reply without JSON gets the follow-up too (here through Ollama's native API,
/// `done_reason` as the finish reason and `format` as the schema); a follow-up that fails
/// again falls back naming both; a reply with JSON that names a bad target gets none, nor does
/// any reply when follow-ups are off.
#[test]
fn a_reply_without_json_is_recovered_and_other_failures_are_not_asked_again() {
    let s = Server::start();
    s.mount(
        Mock::given(method("POST"))
            .and(path("/api/chat"))
            .respond_with(|r: &Request| {
                let b = body(r);
                let content = if b["messages"].as_array().unwrap().len() == 4 {
                    "{\"target\": 1, \"reason\": \"door\"}"
                } else {
                    "I would explore the large room on the left first."
                };
                ResponseTemplate::new(200).set_body_json(json!({
                    "model": "m", "message": { "role": "assistant", "content": content },
                    "done": true, "done_reason": "stop", "prompt_eval_count": 90,
                    "eval_count": 12
                }))
            }),
    );
    let mut http = s.openai();
    http.base_url = s.server.uri();
    let config = LlmConfig {
        prompt: PromptStyle::Text,
        provider: Some(ProviderConfig::Ollama(http)),
        ..LlmConfig::default()
    };
    let mut p = planner_of(config);
    let map = Gaussians::new();
    let c = candidates(3);
    let d = p.decide(&query(&map, &c, 3)).unwrap();
    assert_eq!((d.choice, d.source), (Choice::Frontier(1), Source::Model));
    let e = d.exchange.unwrap();
    assert_eq!(e.completion.finish_reason.as_deref(), Some("stop"));
    let f = e.follow_up.unwrap();
    assert_eq!(f.cause.kind, FailureKind::NoJson);
    assert!(!f.cause.detail.contains("finish reason length"));
    let second = body(&s.requests()[1]);
    assert_eq!(second["messages"][2]["role"], "assistant");
    assert_eq!(second["options"]["num_predict"], 256);
    assert_eq!(second["format"]["type"], "object");
    assert!(body(&s.requests()[0]).get("format").is_none());

    // Rambling twice: the fallback names the follow-up and the first failure.
    let s = Server::start();
    s.mount(completions().respond_with(
        ResponseTemplate::new(200).set_body_json(chat_ok("Let me think about the rooms.")),
    ));
    let mut p = common::planner(&s, PromptStyle::Text);
    let d = p.decide(&query(&map, &c, 4)).unwrap();
    let Source::Fallback(why) = &d.source else {
        panic!("{:?}", d.source)
    };
    assert_eq!(why.kind, FailureKind::NoJson);
    assert!(why.detail.starts_with("follow-up after no_json"), "{why}");
    assert_eq!(d.choice, Choice::Frontier(0));
    assert_eq!((p.stats().follow_ups, p.stats().recovered), (1, 0));
    assert_eq!(s.requests().len(), 2, "one follow-up only");

    // A JSON answer with a bad target is the model's answer: no follow-up.
    let s = Server::start();
    s.mount(completions().respond_with(
        ResponseTemplate::new(200).set_body_json(chat_ok("{\"target\": 7, \"reason\": \"r\"}")),
    ));
    let mut p = common::planner(&s, PromptStyle::Text);
    let d = p.decide(&query(&map, &c, 5)).unwrap();
    assert!(matches!(&d.source, Source::Fallback(f) if f.kind == FailureKind::BadTarget));
    assert!(d.exchange.unwrap().follow_up.is_none());
    assert_eq!(s.requests().len(), 1);

    // Follow-ups off.
    let s = Server::start();
    s.mount(completions().respond_with(ResponseTemplate::new(200).set_body_json(chat_ok("No."))));
    let mut config = LlmConfig {
        prompt: PromptStyle::Text,
        provider: Some(ProviderConfig::Openai(s.openai())),
        ..LlmConfig::default()
    };
    config.follow_up.enabled = false;
    let d = planner_of(config).decide(&query(&map, &c, 6)).unwrap();
    assert!(matches!(&d.source, Source::Fallback(f) if f.kind == FailureKind::NoJson));
    assert_eq!(s.requests().len(), 1);
}

/// A server that does not take `response_format` answers 400 naming it: with
/// `structured_output: auto` the request goes again at once without it (both attempts in the
/// completion, which says the schema was refused) and later requests of the episode leave it
/// out; with `on` the refusal is the query's failure; a 400 about something else is not
/// retried.
#[test]
fn a_server_refusing_response_format_is_asked_again_without_it_and_remembered() {
    let refusing = |r: &Request| {
        if body(r).get("response_format").is_some() {
            ResponseTemplate::new(400).set_body_json(json!({"error": {
                "message": "Unrecognized request argument supplied: response_format",
                "type": "invalid_request_error"}}))
        } else {
            ResponseTemplate::new(200).set_body_json(chat_ok("{\"target\": 1, \"reason\": \"r\"}"))
        }
    };
    let s = Server::start();
    s.mount(completions().respond_with(refusing));
    let mut http = s.openai();
    http.structured_output = StructuredOutput::Auto;
    let config = LlmConfig {
        prompt: PromptStyle::Text,
        provider: Some(ProviderConfig::Openai(http.clone())),
        ..LlmConfig::default()
    };
    let mut p = planner_of(config);
    let map = Gaussians::new();
    let c = candidates(3);
    let d = p.decide(&query(&map, &c, 1)).unwrap();
    assert_eq!((d.choice, d.source), (Choice::Frontier(1), Source::Model));
    let e = d.exchange.unwrap();
    assert!(e.completion.schema_refused);
    assert_eq!(
        (e.completion.attempts, e.completion.http_status),
        (2, Some(200))
    );
    assert!(!e.completion.request.contains("response_format"));
    let d = p.decide(&query(&map, &c, 2)).unwrap();
    let e = d.exchange.unwrap();
    assert!(!e.completion.schema_refused);
    assert_eq!(e.completion.attempts, 1);
    let sent: Vec<bool> = s
        .requests()
        .iter()
        .map(|r| body(r).get("response_format").is_some())
        .collect();
    assert_eq!(sent, [true, false, false], "remembered for the episode");
    assert_eq!(p.stats().calls, 3);

    // `on`: the schema is required.
    let s = Server::start();
    s.mount(completions().respond_with(refusing));
    let mut http = s.openai();
    http.structured_output = StructuredOutput::On;
    let mut provider = activemap_llm::provider::OpenAiProvider::new(&http, 1).unwrap();
    let request = ChatRequest {
        system: "s",
        user: "u",
        image_png: None,
        follow_up: None,
    };
    let out = provider.complete(&request);
    assert_eq!(out.failure.unwrap().kind, FailureKind::HttpStatus);
    assert_eq!((out.attempts, out.schema_refused), (1, false));

    // A 400 that does not name the field is an ordinary client error.
    let s = Server::start();
    s.mount(completions().respond_with(
        ResponseTemplate::new(400).set_body_json(json!({"error": {"message": "bad model"}})),
    ));
    let mut http = s.openai();
    http.structured_output = StructuredOutput::Auto;
    let mut provider = activemap_llm::provider::OpenAiProvider::new(&http, 1).unwrap();
    let out = provider.complete(&request);
    assert_eq!((out.attempts, out.schema_refused), (1, false));
    assert_eq!(s.requests().len(), 1);

    // Ollama refusing `format` on the follow-up turn (the default `follow_up` mode).
    let s = Server::start();
    s.mount(
        Mock::given(method("POST"))
            .and(path("/api/chat"))
            .respond_with(|r: &Request| {
                if body(r).get("format").is_some() {
                    return ResponseTemplate::new(400)
                        .set_body_json(json!({"error": "invalid format: schema not supported"}));
                }
                ResponseTemplate::new(200).set_body_json(json!({
                    "model": "m", "message": { "role": "assistant",
                    "content": "{\"target\": 0, \"reason\": \"r\"}" }, "done": true }))
            }),
    );
    let mut http = s.openai();
    http.base_url = s.server.uri();
    let mut provider = OllamaProvider::new(&http, 1).unwrap();
    let first = provider.complete(&request);
    assert!(!first.schema_refused && first.failure.is_none());
    let turn = ChatRequest {
        follow_up: Some(activemap_llm::provider::FollowUpTurn {
            assistant: "plan",
            user: "only the JSON",
            max_tokens: 64,
        }),
        ..request
    };
    let second = provider.complete(&turn);
    assert!(
        second.schema_refused && second.failure.is_none(),
        "{second:?}"
    );
    assert_eq!(second.attempts, 2);
    assert!(provider.schema_refused());
    let third = provider.complete(&turn);
    assert_eq!((third.attempts, third.schema_refused), (1, false));
    assert_eq!(s.requests().len(), 4);
}

/// Reasoning models: JSON inside `<think>` is never the answer; the block stays in the reply
/// and `reasoning_content` is kept beside it. A reply cut while thinking (no content at all,
/// only `reasoning_content`) gets the follow-up, whose assistant turn is the reasoning.
/// Ollama's `thinking` is kept the same way.
#[test]
fn think_blocks_and_reasoning_content_are_kept_and_never_parsed() {
    let reply = "<think>Maybe {\"target\": 0, \"reason\": \"first\"} but no.</think>\n{\"target\": 2, \"reason\": \"hall\"}";
    let s = Server::start();
    s.mount(
        completions().respond_with(ResponseTemplate::new(200).set_body_json(chat(
            json!(reply),
            "stop",
            "The hall is open.",
        ))),
    );
    let mut p = common::planner(&s, PromptStyle::Text);
    let map = Gaussians::new();
    let c = candidates(3);
    let d = p.decide(&query(&map, &c, 1)).unwrap();
    assert_eq!(d.choice, Choice::Frontier(2));
    let e = d.exchange.unwrap();
    assert_eq!(e.completion.reply, reply, "the think block is kept");
    assert_eq!(e.completion.reasoning, "The hall is open.");
    assert!(e.follow_up.is_none());

    // Only a think block with JSON in it, cut: not taken; the follow-up decides.
    let s = Server::start();
    s.mount(completions().respond_with(|r: &Request| {
        ResponseTemplate::new(200).set_body_json(if is_follow_up(r) {
            chat(json!("{\"target\": 1, \"reason\": \"door\"}"), "stop", "")
        } else {
            chat(
                json!("<think>{\"target\": 0, \"reason\": \"x\"} hmm, the"),
                "length",
                "",
            )
        })
    }));
    let mut p = common::planner(&s, PromptStyle::Text);
    let d = p.decide(&query(&map, &c, 2)).unwrap();
    assert_eq!(d.choice, Choice::Frontier(1));
    let turn = body(&s.requests()[1]);
    assert_eq!(
        turn["messages"][2]["content"],
        "{\"target\": 0, \"reason\": \"x\"} hmm, the"
    );

    // No content, only reasoning_content (cut while reasoning).
    let s = Server::start();
    s.mount(completions().respond_with(|r: &Request| {
        ResponseTemplate::new(200).set_body_json(if is_follow_up(r) {
            chat(
                json!("{\"target\": 2, \"reason\": \"big\"}"),
                "stop",
                "short",
            )
        } else {
            chat(Value::Null, "length", "Candidate 2 is big {\"target\": 0}")
        })
    }));
    let mut p = common::planner(&s, PromptStyle::Text);
    let d = p.decide(&query(&map, &c, 3)).unwrap();
    assert_eq!(d.choice, Choice::Frontier(2));
    let e = d.exchange.unwrap();
    assert_eq!(e.completion.failure, None);
    assert_eq!(e.completion.reply, "");
    assert_eq!(e.completion.reasoning, "Candidate 2 is big {\"target\": 0}");
    let f = e.follow_up.unwrap();
    assert_eq!(f.completion.reasoning, "short");
    assert_eq!(
        body(&s.requests()[1])["messages"][2]["content"],
        "Candidate 2 is big {\"target\": 0}"
    );

    // Ollama's `thinking`, streamed.
    let s = Server::start();
    s.ollama_stream(&[
        json!({"message": {"role": "assistant", "content": "", "thinking": "Room 1 "}, "done": false}),
        json!({"message": {"role": "assistant", "content": "{\"target\": 1, \"reason\": \"r\"}", "thinking": "is open."}, "done": false}),
        json!({"message": {"role": "assistant", "content": ""}, "done": true, "done_reason": "stop"}),
    ]);
    let mut http = s.openai();
    http.base_url = s.server.uri();
    let out = OllamaProvider::new(&http, 1)
        .unwrap()
        .complete(&ChatRequest {
            system: "s",
            user: "u",
            image_png: None,
            follow_up: None,
        });
    assert_eq!(out.reasoning, "Room 1 is open.");
    assert_eq!(out.finish_reason.as_deref(), Some("stop"));
    assert_eq!(out.reply, "{\"target\": 1, \"reason\": \"r\"}");
}

/// Replay: the recorded provider serves an exchange's follow-up to the follow-up turn, so the
/// replayed planner takes the same decision and makes the same exchange; a follow-up the
/// recording lacks is a `replay` failure, not a request.
#[test]
fn replay_serves_the_follow_up_of_the_exchange() {
    let s = Server::start();
    s.mount(completions().respond_with(|r: &Request| {
        ResponseTemplate::new(200).set_body_json(if is_follow_up(r) {
            chat(json!("{\"target\": 1, \"reason\": \"door\"}"), "stop", "")
        } else {
            chat(json!("<think>hmm</think>Plan: 1. the"), "length", "why")
        })
    }));
    let mut live = common::planner(&s, PromptStyle::Text);
    let map = Gaussians::new();
    let c = candidates(3);
    let q = query(&map, &c, 8);
    let d = live.decide(&q).unwrap();
    let e = d.exchange.clone().unwrap();
    let f = e.follow_up.clone().unwrap();
    let replay = |follow_up| {
        let recorded = RecordedProvider::new(vec![RecordedReply {
            system: e.prompt.system.clone(),
            user: e.prompt.user.clone(),
            completion: e.completion.clone(),
            follow_up,
            background: false,
            answered_frame: None,
        }]);
        let mut p = LlmPlanner::new(live.config().clone(), Some(Box::new(recorded))).unwrap();
        p.decide(&q).unwrap()
    };
    let again = replay(Some(f.completion.clone()));
    assert_eq!((again.choice, &again.source), (d.choice, &d.source));
    let mut r = again.exchange.unwrap();
    r.overhead_ms = e.overhead_ms;
    assert_eq!(r, e);

    let missing = replay(None);
    let Source::Fallback(why) = &missing.source else {
        panic!("{:?}", missing.source)
    };
    assert_eq!(why.kind, FailureKind::Replay);
    assert!(why.detail.contains("no follow-up"), "{why}");
    assert_eq!(s.requests().len(), 2, "replay made no request");
}
