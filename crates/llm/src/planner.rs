//! The long-horizon decision (SPEC §7): at a replan with candidate frontiers, render the
//! annotated BEV, build the prompt, ask the provider, parse the reply; on any failure fall
//! back to the largest frontier, with the reason recorded. Stages: [`LlmPlanner::decide`] →
//! ask policy → budget → [`crate::bev::render_bev`] → [`crate::prompt::build`] →
//! [`crate::provider::Provider::complete`] → [`crate::parse::parse_reply`].
//!
//! When it asks ([`crate::config::AskPolicy`]): at each decision, unless the last query was
//! fewer than `min_interval_steps` steps ago (the last chosen frontier is kept if one of the
//! candidates lies within [`HOLD_RADIUS_M`] of it, else the largest is taken), or the map
//! version and the candidates are those of the last query (`skip_unchanged_map`: its answer is
//! reused, as the same question would be asked again).
//!
//! A reply that was cut (finish reason `length`) or holds no JSON answer gets one follow-up
//! turn in the same conversation ([`crate::config::FollowUpConfig`]): the model's own text
//! as the assistant's message, then [`crate::prompt::follow_up_turn`] asking only for the
//! JSON, with a small token limit. Its outcome is part of the same [`Exchange`].

use std::collections::BTreeMap;
use std::time::Instant;

use activemap_splat::Gaussians;

use crate::bev::{Annotations, render_bev};
use crate::config::LlmConfig;
use crate::error::LlmError;
use crate::parse::{Answer, ParseError, parse_reply, split_thinking};
use crate::prompt::{Candidate, Prompt, PromptFacts, build, follow_up_turn};
use crate::provider::{
    ChatRequest, Completion, Failure, FailureKind, FollowUpTurn, Provider, Usage,
};

/// A held target is the candidate nearest the last choice, if within this distance (m).
pub const HOLD_RADIUS_M: f64 = 1.0;

/// What the planner knows at a decision.
#[derive(Debug, Clone, Copy)]
pub struct Query<'a> {
    /// Current step (`<STEP_ID>`).
    pub step: u64,
    /// Steps of the episode (`<TOTAL_STEPS>`).
    pub total_steps: u64,
    /// The current map.
    pub map: &'a Gaussians<f32>,
    /// Its version (the keyframe that made it): equal versions hold equal maps.
    pub map_version: u64,
    /// The camera height, metres (the BEV's ceiling cut).
    pub camera_height_m: f64,
    /// The robot's estimated pose (x, y metres, yaw radians).
    pub robot: [f64; 3],
    /// The visited path (estimated positions).
    pub path: &'a [[f64; 2]],
    /// The candidate frontiers; index = the number shown.
    pub candidates: &'a [Candidate],
}

/// The decision.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Choice {
    /// Explore candidate `i`.
    Frontier(usize),
    /// Refine what is mapped (the model's −1).
    Refine,
}

impl Choice {
    /// The target as the model names it: the index, or −1.
    pub fn target(self) -> i64 {
        match self {
            Self::Frontier(i) => i as i64,
            Self::Refine => -1,
        }
    }
}

/// Where a decision came from.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Source {
    /// The model's valid answer to a query made now.
    Model,
    /// The last query's answer, reused (same map and candidates).
    Reused,
    /// The last choice, kept (too soon to ask again).
    Held,
    /// The largest frontier, because of this failure.
    Fallback(Failure),
}

/// One query to the model and what came of it (what goes on `planner/llm`).
#[derive(Debug, Clone, PartialEq)]
pub struct Exchange {
    /// Step of the decision.
    pub step: u64,
    /// Number of candidates offered.
    pub candidates: u32,
    /// The prompt.
    pub prompt: Prompt,
    /// The annotated BEV, PNG (empty for the text prompt).
    pub bev_png: Vec<u8>,
    /// What the provider made of it.
    pub completion: Completion,
    /// The follow-up turn, if the first reply was cut or held no JSON answer.
    pub follow_up: Option<FollowUp>,
    /// The parsed answer (of the follow-up, if one was asked), if valid.
    pub answer: Option<Answer>,
    /// The decision taken: the candidate index, or −1.
    pub decision: i64,
    /// The largest candidate's index: what the paper's fallback would have decided without
    /// the model, so a report can tell where the model's choice made a difference.
    pub fallback_target: u32,
    /// Why it fell back to the largest frontier, if it did.
    pub fallback: Option<Failure>,
    /// The planner's own time (BEV, PNG, prompt, request, parsing), without the model's.
    pub overhead_ms: f64,
}

/// The follow-up turn of an exchange.
#[derive(Debug, Clone, PartialEq)]
pub struct FollowUp {
    /// Why it was asked: the first reply's parse failure (its detail names the finish
    /// reason when the reply was cut).
    pub cause: Failure,
    /// The user turn sent.
    pub user: String,
    /// What the provider made of it.
    pub completion: Completion,
}

/// A decision and, when a query was made, its exchange.
#[derive(Debug, Clone, PartialEq)]
pub struct Decision {
    /// What to do.
    pub choice: Choice,
    /// Why.
    pub source: Source,
    /// The query made for it, if any.
    pub exchange: Option<Exchange>,
}

/// Totals over an episode (also recomputable from the recorded exchanges).
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Stats {
    /// Decisions made.
    pub decisions: u64,
    /// Queries sent to the provider.
    pub queries: u64,
    /// HTTP attempts.
    pub calls: u64,
    /// Fallbacks to the largest frontier, by kind.
    pub fallbacks: BTreeMap<FailureKind, u64>,
    /// Tokens used.
    pub usage: Usage,
    /// Model latency summed, milliseconds.
    pub latency_ms: f64,
    /// Follow-up turns asked.
    pub follow_ups: u64,
    /// Follow-up turns whose reply held a valid answer.
    pub recovered: u64,
}

/// The last query, to reuse its answer.
#[derive(Debug, Clone, PartialEq)]
struct LastQuery {
    step: u64,
    map_version: u64,
    candidates: Vec<Candidate>,
    choice: Choice,
}

/// The LLM policy's decision state.
pub struct LlmPlanner {
    config: LlmConfig,
    provider: Option<Box<dyn Provider>>,
    last_query: Option<LastQuery>,
    /// The last chosen frontier's label position (the yellow diamond).
    last_choice: Option<[f64; 2]>,
    stats: Stats,
}

/// Why a decision needs no request ([`LlmPlanner::will_query`]).
enum Shortcut {
    /// No provider: the paper's fallback.
    NoProvider,
    /// Same map and candidates as the last query: its choice.
    Reused(Choice),
    /// Too soon after the last query: its target held.
    Held,
}

/// The largest candidate (ties: the nearer by path, then the lower index): the paper's
/// fallback.
pub fn largest(candidates: &[Candidate]) -> Option<usize> {
    (0..candidates.len()).min_by(|&a, &b| {
        let (ca, cb) = (&candidates[a], &candidates[b]);
        cb.size_cells
            .cmp(&ca.size_cells)
            .then(ca.path_distance_m.total_cmp(&cb.path_distance_m))
            .then(a.cmp(&b))
    })
}

impl LlmPlanner {
    /// A planner of `config` asking `provider` (`None`: the offline default, the largest
    /// frontier at every decision).
    pub fn new(config: LlmConfig, provider: Option<Box<dyn Provider>>) -> Result<Self, LlmError> {
        config.validate()?;
        Ok(Self {
            config,
            provider,
            last_query: None,
            last_choice: None,
            stats: Stats::default(),
        })
    }

    /// The totals so far.
    pub fn stats(&self) -> &Stats {
        &self.stats
    }

    /// The settings.
    pub fn config(&self) -> &LlmConfig {
        &self.config
    }

    /// One line for the node's log at start: which provider, or that the offline default
    /// (the largest frontier) decides.
    pub fn describe(&self) -> String {
        match &self.provider {
            Some(p) => format!("llm policy: {}", p.describe()),
            None => "llm policy: no provider configured: every decision takes the largest \
                     frontier (the paper's fallback, SPEC §7)"
                .into(),
        }
    }

    /// True when deciding `query` would send a request to the model: a provider is set, the
    /// last answer is not reused, the last target is not held and the budget is not spent.
    /// Otherwise [`LlmPlanner::decide`] returns at once (what `background` asking relies on:
    /// only real requests go to the background).
    pub fn will_query(&self, query: &Query<'_>) -> bool {
        self.shortcut(query).is_none() && self.budget_spent().is_none()
    }

    /// Why `query` is decided without asking (no provider, the last answer reused, the last
    /// target held), if it is.
    fn shortcut(&self, query: &Query<'_>) -> Option<Shortcut> {
        if self.provider.is_none() {
            return Some(Shortcut::NoProvider);
        }
        let last = self.last_query.as_ref()?;
        if self.config.ask.skip_unchanged_map
            && last.map_version == query.map_version
            && last.candidates == query.candidates
        {
            return Some(Shortcut::Reused(last.choice));
        }
        (query.step < last.step + self.config.ask.min_interval_steps).then_some(Shortcut::Held)
    }

    /// Which per-episode budget is spent, if one is (`call budget of N spent`, …).
    fn budget_spent(&self) -> Option<String> {
        let budget = self.config.budget;
        if let Some(m) = budget.max_calls.filter(|&m| self.stats.calls >= m) {
            return Some(format!("call budget of {m} spent"));
        }
        let m = budget
            .max_tokens
            .filter(|&m| self.stats.usage.total() >= m)?;
        Some(format!("token budget of {m} spent"))
    }

    /// Decides among `query.candidates` (at least one).
    pub fn decide(&mut self, query: &Query<'_>) -> Result<Decision, LlmError> {
        let n = query.candidates.len();
        let Some(fallback) = largest(query.candidates) else {
            return Err(LlmError::Input(format!(
                "step {}: a decision needs at least one candidate",
                query.step
            )));
        };
        if !query.robot.iter().all(|v| v.is_finite()) {
            return Err(LlmError::Input(format!(
                "step {}: non-finite robot pose {:?}",
                query.step, query.robot
            )));
        }
        self.stats.decisions += 1;
        let decision = self.decide_inner(query, n, fallback)?;
        if let Choice::Frontier(i) = decision.choice {
            self.last_choice = Some(query.candidates[i].label_at);
        }
        if let Source::Fallback(f) = &decision.source {
            *self.stats.fallbacks.entry(f.kind).or_default() += 1;
        }
        Ok(decision)
    }

    fn decide_inner(
        &mut self,
        query: &Query<'_>,
        n: usize,
        fallback: usize,
    ) -> Result<Decision, LlmError> {
        match self.shortcut(query) {
            None => {}
            Some(Shortcut::NoProvider) => {
                return Ok(Decision {
                    choice: Choice::Frontier(fallback),
                    source: Source::Fallback(Failure::new(
                        FailureKind::NoProvider,
                        "no provider configured",
                    )),
                    exchange: None,
                });
            }
            Some(Shortcut::Reused(choice)) => {
                return Ok(Decision {
                    choice,
                    source: Source::Reused,
                    exchange: None,
                });
            }
            Some(Shortcut::Held) => {
                let held = self.last_choice.and_then(|p| {
                    nearest(query.candidates, p).filter(|&(_, d)| d <= HOLD_RADIUS_M)
                });
                return Ok(Decision {
                    choice: Choice::Frontier(held.map_or(fallback, |(i, _)| i)),
                    source: Source::Held,
                    exchange: None,
                });
            }
        }
        let started = Instant::now();
        let facts = PromptFacts {
            total_steps: query.total_steps,
            step: query.step,
            candidates: query.candidates,
            has_last_choice: self.last_choice.is_some(),
            robot: query.robot,
            last_choice: self.last_choice,
        };
        let prompt = build(self.config.prompt, &facts);
        let spent = self.budget_spent();
        let bev_png = if self.config.prompt.sends_image() && spent.is_none() {
            let annotations = Annotations {
                robot: query.robot,
                path: query.path.to_vec(),
                last_frontier: self.last_choice,
                candidates: query.candidates.iter().map(|c| c.label_at).collect(),
            };
            render_bev(
                query.map,
                query.camera_height_m,
                &annotations,
                &self.config.bev,
            )
            .map_err(|e| LlmError::Bev(e.to_string()))?
            .png()
        } else {
            Vec::new()
        };
        let completion = if let Some(what) = spent {
            Completion::failed("", FailureKind::Budget, what)
        } else {
            let request = ChatRequest {
                system: &prompt.system,
                user: &prompt.user,
                image_png: (!bev_png.is_empty()).then_some(bev_png.as_slice()),
                follow_up: None,
            };
            match self.provider.as_mut() {
                Some(p) => p.complete(&request),
                None => unreachable!("checked above"),
            }
        };
        self.stats.queries += u64::from(completion.attempts > 0);
        self.count(&completion);
        let mut parsed = parse(&completion, n);
        let mut follow_up = None;
        if let Err((first, Some(e))) = &parsed
            && self.follow_up_due(&completion, e)
        {
            let cause = match completion.finish_reason.as_deref() {
                Some(r) => {
                    Failure::new(first.kind, format!("{} (finish reason {r})", first.detail))
                }
                None => first.clone(),
            };
            let (turn, outcome) = self.ask_follow_up(&completion, cause, &prompt, &bev_png, n);
            parsed = outcome;
            follow_up = Some(turn);
        }
        let parsed = parsed.map_err(|(f, _)| f);
        let (choice, source, answer, fallback_reason) = match parsed {
            Ok(answer) => {
                let choice = match answer.target {
                    -1 => Choice::Refine,
                    i => Choice::Frontier(i as usize),
                };
                (choice, Source::Model, Some(answer), None)
            }
            Err(f) => (
                Choice::Frontier(fallback),
                Source::Fallback(f.clone()),
                None,
                Some(f),
            ),
        };
        let model_ms =
            completion.latency_ms + follow_up.as_ref().map_or(0.0, |f| f.completion.latency_ms);
        let overhead_ms = (started.elapsed().as_secs_f64() * 1e3 - model_ms).max(0.0);
        self.last_query = Some(LastQuery {
            step: query.step,
            map_version: query.map_version,
            candidates: query.candidates.to_vec(),
            choice,
        });
        Ok(Decision {
            choice,
            source,
            exchange: Some(Exchange {
                step: query.step,
                candidates: n as u32,
                prompt,
                bev_png,
                completion,
                follow_up,
                answer,
                decision: choice.target(),
                fallback_target: fallback as u32,
                fallback: fallback_reason,
                overhead_ms,
            }),
        })
    }
}

impl LlmPlanner {
    /// Adds a completion's calls, latency and tokens to the totals.
    fn count(&mut self, c: &Completion) {
        self.stats.calls += u64::from(c.attempts);
        self.stats.latency_ms += c.latency_ms;
        let u = &mut self.stats.usage;
        u.prompt_tokens = Some(u.prompt_tokens.unwrap_or(0) + c.usage.prompt_tokens.unwrap_or(0));
        u.completion_tokens =
            Some(u.completion_tokens.unwrap_or(0) + c.usage.completion_tokens.unwrap_or(0));
    }

    /// Asks the follow-up turn after the reply `first` (which failed for `cause`) to the
    /// query of `prompt` and `bev_png` among `n` candidates; returns the turn and the answer
    /// it gave, or the failure (its detail naming the follow-up and the first failure).
    fn ask_follow_up(
        &mut self,
        first: &Completion,
        cause: Failure,
        prompt: &Prompt,
        bev_png: &[u8],
        n: usize,
    ) -> (FollowUp, Parsed) {
        // The model's visible text; its reasoning when that is all it wrote.
        let split = split_thinking(&first.reply);
        let mut assistant = split.answer.trim().to_string();
        if assistant.is_empty() {
            assistant = if first.reasoning.trim().is_empty() {
                split.thinking.join("\n")
            } else {
                first.reasoning.trim().to_string()
            };
        }
        let user = follow_up_turn(n);
        let request = ChatRequest {
            system: &prompt.system,
            user: &prompt.user,
            image_png: (!bev_png.is_empty()).then_some(bev_png),
            follow_up: Some(FollowUpTurn {
                assistant: &assistant,
                user: &user,
                max_tokens: self.config.follow_up.max_tokens,
            }),
        };
        let second = match self.provider.as_mut() {
            Some(p) => p.complete(&request),
            None => Completion::failed("", FailureKind::NoProvider, "no provider configured"),
        };
        self.count(&second);
        self.stats.follow_ups += 1;
        let parsed = parse(&second, n).map_err(|(f, e)| {
            let detail = format!("follow-up after {}: {}", cause.kind.name(), f.detail);
            (Failure::new(f.kind, detail), e)
        });
        self.stats.recovered += u64::from(parsed.is_ok());
        let turn = FollowUp {
            cause,
            user,
            completion: second,
        };
        (turn, parsed)
    }

    /// Whether a reply that came back but failed to parse with `error` gets the follow-up:
    /// it was cut (finish reason `length`) or holds no JSON answer, follow-ups are on, and
    /// the budget is not spent.
    fn follow_up_due(&self, c: &Completion, error: &ParseError) -> bool {
        let cut = c.finish_reason.as_deref() == Some("length");
        let no_answer = matches!(
            error,
            ParseError::NoJson | ParseError::Truncated(_) | ParseError::MissingTarget
        );
        self.config.follow_up.enabled && (cut || no_answer) && self.budget_spent().is_none()
    }
}

/// A completion's answer, or its failure and, when the reply came back but did not parse,
/// the parse error.
type Parsed = Result<Answer, (Failure, Option<ParseError>)>;

/// The answer of a completion among `n` candidates ([`Parsed`]).
fn parse(c: &Completion, n: usize) -> Parsed {
    match &c.failure {
        Some(f) => Err((f.clone(), None)),
        None => {
            parse_reply(&c.reply, n).map_err(|e| (Failure::new(e.kind(), e.to_string()), Some(e)))
        }
    }
}

/// The candidate whose label lies nearest `p`, and the distance.
pub fn nearest(candidates: &[Candidate], p: [f64; 2]) -> Option<(usize, f64)> {
    candidates
        .iter()
        .enumerate()
        .map(|(i, c)| (i, (c.label_at[0] - p[0]).hypot(c.label_at[1] - p[1])))
        .min_by(|a, b| a.1.total_cmp(&b.1).then(a.0.cmp(&b.0)))
}
