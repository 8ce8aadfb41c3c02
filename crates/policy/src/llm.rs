//! The `llm` goal policy (SPEC §7): the multimodal-LLM long-horizon planner of
//! `activemap-llm`. The candidates are the regions FBE's strikes leave eligible (numbered
//! 0..N−1 in the frontier operator's order, largest first); the library renders the annotated
//! BEV of the map snapshot of frame k − 1 − L (L = `map_lag`, the mapper's, so a seeded run
//! stays deterministic), asks the configured provider, parses the reply and falls back to the
//! largest frontier on any failure. Every query gives an [`LlmExchange`] (request without
//! secrets, BEV PNG, raw reply, HTTP status, latency, tokens, decision, fallback reason) for
//! the recording; a `recorded` provider serves a recording's replies back in order
//! ([`recorded_reply`]). With no provider configured the policy is the paper's fallback (the
//! largest frontier).
//!
//! `ask.mode: background` asks on a thread of its own: the replan that asks, and those that
//! follow until the answer has come, take the largest frontier; the answer is taken up at the
//! first replan after it came, applied or recorded as stale ([`LlmPolicy::goal`]). A replay
//! takes each recorded answer up at the recorded frame, so its goals are the run's.

use std::collections::VecDeque;
use std::sync::{Arc, Mutex, MutexGuard};
use std::thread::JoinHandle;

use activemap_geometry::PlanarPose;
use activemap_geometry::snapshots::LaggedSnapshots;
use activemap_llm::planner::{HOLD_RADIUS_M, Source, Stats, largest, nearest};
use activemap_llm::provider::{Completion, Failure, FailureKind, RecordedReply, Usage};
use activemap_llm::{
    AskMode, Candidate, Choice as LlmChoice, Decision, Exchange, LlmPlanner, ProviderConfig, Query,
};
use activemap_planning::OccupancyGrid;
use activemap_planning::fbe::FbeState;
use activemap_schemas::{Frontiers, Goal, LlmExchange, LlmFollowUp, ReplanRequest};
use activemap_splat::Gaussians;

use crate::goal::{
    FbePlanner, GoalConfig, NoFrontier, REFINE_TARGET, RecordedLoader, no_frontier_goal,
};
use crate::wire::{reason_from_wire, regions_from_wire};
use crate::{Log, MapSnapshot};

/// The library's candidate of a wire region (its number is its index among the candidates).
fn candidate(region: &activemap_schemas::FrontierRegion, cell_size_m: f64) -> Candidate {
    Candidate {
        centroid: region.centroid,
        label_at: region.anchor,
        size_cells: region.size_cells,
        area_m2: region.size_cells as f64 * cell_size_m * cell_size_m,
        path_distance_m: region.path_distance_m,
    }
}

/// The wire record of an exchange made at frame `frame_id`.
pub fn exchange_to_wire(frame_id: u64, e: &Exchange) -> LlmExchange {
    let c = &e.completion;
    LlmExchange {
        frame_id,
        system: e.prompt.system.clone(),
        prompt: e.prompt.user.clone(),
        bev_png: e.bev_png.clone(),
        provider: c.provider.clone(),
        model: c.model.clone(),
        request: c.request.clone(),
        candidates: e.candidates,
        http_status: c.http_status,
        attempts: c.attempts,
        latency_ms: c.latency_ms,
        prompt_tokens: c.usage.prompt_tokens,
        completion_tokens: c.usage.completion_tokens,
        reply: c.reply.clone(),
        target: e.answer.as_ref().map(|a| a.target as i32),
        reason: e.answer.as_ref().map(|a| a.reason.clone()),
        decision: e.decision as i32,
        fallback_target: e.fallback_target as i32,
        failure: e.fallback.as_ref().map(|f| f.kind.name().to_string()),
        failure_detail: e.fallback.as_ref().map(|f| f.detail.clone()),
        finish_reason: c.finish_reason.clone(),
        reasoning: c.reasoning.clone(),
        schema_refused: c.schema_refused,
        follow_up: e.follow_up.as_ref().map(|f| {
            let c = &f.completion;
            LlmFollowUp {
                cause: f.cause.to_string(),
                prompt: f.user.clone(),
                request: c.request.clone(),
                http_status: c.http_status,
                attempts: c.attempts,
                latency_ms: c.latency_ms,
                prompt_tokens: c.usage.prompt_tokens,
                completion_tokens: c.usage.completion_tokens,
                reply: c.reply.clone(),
                finish_reason: c.finish_reason.clone(),
                reasoning: c.reasoning.clone(),
                schema_refused: c.schema_refused,
                failure: c.failure.as_ref().map(|f| f.kind.name().to_string()),
                failure_detail: c.failure.as_ref().map(|f| f.detail.clone()),
            }
        }),
        answered_frame: Some(frame_id),
        stale: None,
    }
}

/// The failure kind named `name`; `at` names the message in errors.
fn recorded_kind(at: &str, name: Option<&str>) -> anyhow::Result<Option<FailureKind>> {
    name.map(|k| {
        FailureKind::from_name(k).ok_or_else(|| anyhow::anyhow!("{at}: unknown failure `{k}`"))
    })
    .transpose()
}

/// What a recorded provider serves for the recorded exchange `e` (`at` names it in errors);
/// `None` when it never reached a provider (budget spent).
pub fn recorded_reply(e: LlmExchange, at: &str) -> anyhow::Result<Option<RecordedReply>> {
    let kind = recorded_kind(at, e.failure.as_deref())?;
    if kind == Some(FailureKind::Budget) {
        return Ok(None);
    }
    // Parse failures are the planner's, not the provider's: the provider served a reply.
    // With a follow-up the first reply came back (the failure is the follow-up's).
    let provider_failure = kind.filter(|k| {
        e.follow_up.is_none()
            && !matches!(
                k,
                FailureKind::NoJson | FailureKind::BadJson | FailureKind::BadTarget
            )
    });
    let follow_up = match e.follow_up {
        None => None,
        Some(f) => {
            let kind = recorded_kind(&format!("{at}, follow-up"), f.failure.as_deref())?;
            Some(Completion {
                provider: e.provider.clone(),
                model: e.model.clone(),
                request: f.request,
                http_status: f.http_status,
                attempts: f.attempts,
                latency_ms: f.latency_ms,
                usage: Usage {
                    prompt_tokens: f.prompt_tokens,
                    completion_tokens: f.completion_tokens,
                },
                reply: f.reply,
                finish_reason: f.finish_reason,
                reasoning: f.reasoning,
                schema_refused: f.schema_refused,
                failure: kind.map(|k| Failure::new(k, f.failure_detail.unwrap_or_default())),
            })
        }
    };
    Ok(Some(RecordedReply {
        system: e.system,
        user: e.prompt,
        completion: Completion {
            provider: e.provider,
            model: e.model,
            request: e.request,
            http_status: e.http_status,
            attempts: e.attempts,
            latency_ms: e.latency_ms,
            usage: Usage {
                prompt_tokens: e.prompt_tokens,
                completion_tokens: e.completion_tokens,
            },
            reply: e.reply,
            finish_reason: e.finish_reason,
            reasoning: e.reasoning,
            schema_refused: e.schema_refused,
            failure: provider_failure
                .map(|k| Failure::new(k, e.failure_detail.unwrap_or_default())),
        },
        follow_up,
        background: e.answered_frame != Some(e.frame_id),
        answered_frame: e.answered_frame,
    }))
}

/// The `llm` policy without transport: FBE's strikes pick the eligible regions, the library
/// planner decides among them on the lagged map snapshot.
pub struct LlmPolicy {
    fbe: FbePlanner,
    /// The library planner; a `background` question holds it on its own thread until it is
    /// answered.
    planner: Arc<Mutex<LlmPlanner>>,
    /// `ask.mode` and `ask.stale_after_steps`.
    mode: AskMode,
    stale_after_steps: u64,
    /// The `background` question being answered, if any.
    pending: Option<Pending>,
    /// Replaying a recording (`recorded` provider): the frames at which its `background`
    /// answers were taken up, in order, so the replay takes them up at the same replans.
    recorded_answers: Option<VecDeque<Option<u64>>>,
    when_no_frontier: NoFrontier,
    needs_map: bool,
    total_steps: u64,
    /// Map snapshots by frame; snapshots of the same keyframe share one decoded map.
    maps: LaggedSnapshots<(u64, Arc<Gaussians<f32>>)>,
    /// The estimated positions so far (the green path), one per frame that moved ≥ 1 cm.
    path: Vec<[f64; 2]>,
}

impl LlmPolicy {
    /// The policy of `config` for node `node`; `max_steps` is the run's `--max-steps`;
    /// `recorded` reads the replies of a `recorded` provider.
    pub fn new(
        config: &GoalConfig,
        node: &str,
        max_steps: Option<u64>,
        recorded: RecordedLoader<'_>,
    ) -> anyhow::Result<Self> {
        let llm = config
            .llm_config()
            .map_err(|e| anyhow::anyhow!("planner: {e}"))?;
        let recorded = match &llm.provider {
            Some(ProviderConfig::Recorded {
                recording,
                node: from,
            }) => Some(recorded(recording, from.as_deref().unwrap_or(node))?),
            _ => None,
        };
        let recorded_answers = recorded.as_ref().map(|replies| {
            replies
                .iter()
                .filter(|r| r.background)
                .map(|r| r.answered_frame)
                .collect()
        });
        let seed = match &llm.provider {
            Some(ProviderConfig::Openai(h) | ProviderConfig::Ollama(h)) => h.seed.unwrap_or(0),
            _ => 0,
        };
        let provider = llm
            .provider
            .as_ref()
            .map(|p| activemap_llm::provider::from_config(p, recorded, seed))
            .transpose()?;
        let total_steps = llm.total_steps.or(max_steps).unwrap_or(2000);
        Ok(Self {
            fbe: FbePlanner::new(config)?,
            needs_map: config.needs_map(&llm),
            mode: llm.ask.mode,
            stale_after_steps: llm.ask.stale_after_steps,
            pending: None,
            recorded_answers,
            planner: Arc::new(Mutex::new(LlmPlanner::new(llm, provider)?)),
            when_no_frontier: config.when_no_frontier,
            total_steps,
            maps: LaggedSnapshots::new(config.map_lag),
            path: Vec::new(),
        })
    }

    /// The line the node logs at start.
    pub fn describe(&self) -> String {
        let line = self.lock().map_or_else(|e| e.to_string(), |p| p.describe());
        match self.mode {
            AskMode::Blocking => line,
            AskMode::Background => format!("{line}; asked in the background"),
        }
    }

    /// The library planner's totals (waits for a `background` question still being asked).
    pub fn stats(&self) -> Stats {
        self.lock().map(|p| p.stats().clone()).unwrap_or_default()
    }

    /// The library planner.
    fn lock(&self) -> anyhow::Result<MutexGuard<'_, LlmPlanner>> {
        self.planner
            .lock()
            .map_err(|_| anyhow::anyhow!("planner: the LLM planner's thread panicked"))
    }

    /// True while a `background` question is being answered and not yet taken up.
    pub fn asking(&self) -> bool {
        self.pending.is_some()
    }

    /// True once the `background` question's answer has come (it is taken up at the next
    /// replan); false with no question.
    pub fn answer_arrived(&self) -> bool {
        self.pending
            .as_ref()
            .is_some_and(|p| p.worker.is_finished())
    }

    /// Ends the episode: a `background` question still being asked is waited for (the
    /// provider's timeouts bound the wait) and returned for the recording, with no
    /// `answered_frame` (never taken up).
    pub fn finish(&mut self) -> anyhow::Result<Option<LlmExchange>> {
        let Some(pending) = self.pending.take() else {
            return Ok(None);
        };
        let asked = pending.asked;
        let decision = join(pending.worker)?;
        (self.fbe.log)(&format!(
            "planner: the question asked at frame {asked} was not taken up before the end"
        ));
        Ok(decision.exchange.as_ref().map(|e| {
            let mut wire = exchange_to_wire(asked, e);
            wire.answered_frame = None;
            wire.stale = Some("the episode ended before the answer was taken up".into());
            wire
        }))
    }

    /// The same policy writing its decisions to `log`.
    pub fn with_log(self, log: Log) -> Self {
        Self {
            fbe: self.fbe.with_log(log),
            ..self
        }
    }

    /// The FBE eligibility state (strikes, amnesties).
    pub fn fbe_state(&self) -> &FbeState {
        self.fbe.state()
    }

    /// Stores a map snapshot (decoded only when its keyframe is new).
    pub fn add_map(&mut self, snapshot: &MapSnapshot<'_>) -> anyhow::Result<()> {
        if !self.needs_map {
            return Ok(());
        }
        let version = snapshot.keyframe.unwrap_or(u64::MAX);
        self.maps.insert_reusing(
            snapshot.frame_id,
            |(v, m)| *v == version && m.len() as u64 == snapshot.count,
            || Ok::<_, anyhow::Error>((version, Arc::new((snapshot.decode)()?.0))),
        )
    }

    /// Notes the estimated position of a frame (frames come in order).
    pub fn add_position(&mut self, pose: &PlanarPose) {
        let p = [pose.x, pose.y];
        if self
            .path
            .last()
            .is_none_or(|q| (q[0] - p[0]).hypot(q[1] - p[1]) >= 0.01)
        {
            self.path.push(p);
        }
    }

    /// True once what the decision of frame `k` needs has arrived.
    pub fn ready(&self, k: u64) -> bool {
        !self.needs_map || self.maps.for_frame(k).is_some()
    }

    /// The goal for `request` and the exchange to record, if a query was made or a
    /// `background` answer taken up (at most one per replan); `None` goal: the episode is over.
    pub fn goal(
        &mut self,
        request: &ReplanRequest,
        grid: &OccupancyGrid,
        frontiers: &Frontiers,
        pose: &PlanarPose,
        camera_z: f64,
    ) -> anyhow::Result<(Option<Goal>, Option<LlmExchange>)> {
        let k = request.frame_id;
        let regions = regions_from_wire(frontiers);
        let eligible = self
            .fbe
            .planner
            .eligible(reason_from_wire(request.reason), grid, &regions);
        let cell = grid.geometry.resolution;
        let candidates: Vec<Candidate> = eligible
            .iter()
            .map(|&i| candidate(&frontiers.regions[i], cell))
            .collect();
        let at = Replan {
            k,
            grid,
            frontiers,
            regions: &regions,
            eligible: &eligible,
            candidates: &candidates,
            pose,
        };
        if self.pending.is_some() && self.answer_due(k) {
            return self.take_up(&at);
        }
        if eligible.is_empty() {
            self.fbe.planner.commit(&regions, None, grid);
            let goal = no_frontier_goal(self.when_no_frontier, k, pose, self.fbe.log);
            return Ok((goal, None));
        }
        if let Some(p) = &self.pending {
            let asked = p.asked;
            let goal =
                self.fallback_goal(&at, &format!("the model is still asked (frame {asked})"));
            // The question holds its own map.
            self.maps.retain_needed_from(k);
            return Ok((Some(goal), None));
        }
        let (version, map) = match self.maps.for_frame(k) {
            Some((v, m)) => (*v, m.clone()),
            // The text prompt (or no provider) draws no BEV: no map is kept.
            None if !self.needs_map => (u64::MAX, Arc::new(Gaussians::new())),
            None => anyhow::bail!(
                "planner: the decision of frame {k} needs map snapshot {}, which has not arrived",
                self.maps.needed(k)
            ),
        };
        let question = Question {
            step: k,
            total_steps: self.total_steps,
            map,
            map_version: version,
            camera_height_m: camera_z,
            robot: [pose.x, pose.y, pose.yaw],
            path: self.path.clone(),
            candidates: candidates.clone(),
        };
        if self.mode == AskMode::Background && self.lock()?.will_query(&question.query()) {
            let planner = self.planner.clone();
            let worker = std::thread::Builder::new()
                .name("llm-question".into())
                .spawn(move || -> anyhow::Result<Decision> {
                    let mut planner = planner
                        .lock()
                        .map_err(|_| anyhow::anyhow!("the LLM planner's lock is poisoned"))?;
                    Ok(planner.decide(&question.query())?)
                })?;
            let answered_frame = self
                .recorded_answers
                .as_mut()
                .map(|frames| frames.pop_front().flatten());
            self.pending = Some(Pending {
                asked: k,
                candidates: candidates.clone(),
                worker,
                answered_frame,
            });
            let goal = self.fallback_goal(&at, "asked the model in the background");
            return Ok((Some(goal), None));
        }
        let decision = self.lock()?.decide(&question.query())?;
        let goal = self.apply(&at, decision.choice);
        let how = match &decision.source {
            Source::Model => "the model's choice".to_string(),
            Source::Reused => "the last answer (map unchanged)".to_string(),
            Source::Held => "the last target (too soon to ask)".to_string(),
            Source::Fallback(f) if f.kind == FailureKind::NoProvider => {
                "largest frontier".to_string()
            }
            Source::Fallback(f) => format!("largest frontier, fallback after {f}"),
        };
        self.log_goal(k, &goal, candidates.len(), &how);
        // Older snapshots are no longer needed (requests come in frame order).
        self.maps.retain_needed_from(k);
        Ok((
            Some(goal),
            decision.exchange.as_ref().map(|e| exchange_to_wire(k, e)),
        ))
    }

    /// Whether the `background` answer is taken up at the replan of frame `k`: when it has
    /// come; in a replay, at the frame the recording took it up.
    fn answer_due(&self, k: u64) -> bool {
        match &self.pending {
            None => false,
            Some(p) => match p.answered_frame {
                Some(frame) => frame == Some(k),
                None => p.worker.is_finished(),
            },
        }
    }

    /// Takes up the `background` answer at the replan `at`: applied when the question is not
    /// older than `stale_after_steps` and its frontier is still offered (the eligible
    /// frontier whose label lies within [`HOLD_RADIUS_M`] of the chosen one's), else recorded
    /// as stale and the largest frontier taken.
    fn take_up(&mut self, at: &Replan<'_>) -> anyhow::Result<(Option<Goal>, Option<LlmExchange>)> {
        let Pending {
            asked,
            candidates: asked_candidates,
            worker,
            ..
        } = self.pending.take().expect("checked by the caller");
        let decision = join(worker)?;
        let k = at.k;
        let age = k.saturating_sub(asked);
        let now = match decision.choice {
            _ if age > self.stale_after_steps => Err(format!(
                "asked at frame {asked}, {age} steps ago (stale_after_steps {})",
                self.stale_after_steps
            )),
            LlmChoice::Refine => Ok(LlmChoice::Refine),
            LlmChoice::Frontier(i) => {
                let label = asked_candidates[i].label_at;
                nearest(at.candidates, label)
                    .filter(|&(_, d)| d <= HOLD_RADIUS_M)
                    .map(|(j, _)| LlmChoice::Frontier(j))
                    .ok_or_else(|| {
                        format!(
                            "frontier {i} of frame {asked} is gone (no eligible frontier within \
                             {HOLD_RADIUS_M} m of it at frame {k})"
                        )
                    })
            }
        };
        let (goal, stale) = match (now, at.eligible.is_empty()) {
            (Ok(LlmChoice::Refine), _) => {
                let goal = self.apply(at, LlmChoice::Refine);
                self.log_goal(
                    k,
                    &goal,
                    at.candidates.len(),
                    &format!("the model's answer to frame {asked}"),
                );
                (Some(goal), None)
            }
            (Ok(choice), false) => {
                let how = match &decision.source {
                    Source::Model => format!("the model's answer to frame {asked}"),
                    _ => format!("the largest frontier (the question of frame {asked} fell back)"),
                };
                let goal = self.apply(at, choice);
                self.log_goal(k, &goal, at.candidates.len(), &how);
                (Some(goal), None)
            }
            (_, true) => {
                self.fbe.planner.commit(at.regions, None, at.grid);
                let goal = no_frontier_goal(self.when_no_frontier, k, at.pose, self.fbe.log);
                (
                    goal,
                    Some(format!("no eligible frontier left at frame {k}")),
                )
            }
            (Err(why), false) => {
                let goal = self.fallback_goal(at, &format!("stale answer: {why}"));
                (Some(goal), Some(why))
            }
        };
        self.maps.retain_needed_from(k);
        let exchange = decision.exchange.as_ref().map(|e| {
            let mut wire = exchange_to_wire(asked, e);
            wire.answered_frame = Some(k);
            wire.stale = stale.filter(|_| decision.source == Source::Model);
            wire
        });
        Ok((goal, exchange))
    }

    /// The goal of `choice` among the replan's candidates (FBE's strikes told).
    fn apply(&mut self, at: &Replan<'_>, choice: LlmChoice) -> Goal {
        match choice {
            LlmChoice::Frontier(i) => {
                let region = at.eligible[i];
                self.fbe.planner.commit(at.regions, Some(region), at.grid);
                let r = &at.frontiers.regions[region];
                Goal {
                    frame_id: at.k,
                    target: r.id as i32,
                    focus: r.centroid,
                }
            }
            LlmChoice::Refine => {
                self.fbe.planner.commit(at.regions, None, at.grid);
                Goal {
                    frame_id: at.k,
                    target: REFINE_TARGET,
                    focus: [at.pose.x, at.pose.y],
                }
            }
        }
    }

    /// The largest eligible frontier's goal (the paper's fallback), logged with `why`.
    fn fallback_goal(&mut self, at: &Replan<'_>, why: &str) -> Goal {
        let i = largest(at.candidates).expect("called with eligible frontiers");
        let goal = self.apply(at, LlmChoice::Frontier(i));
        self.log_goal(
            at.k,
            &goal,
            at.candidates.len(),
            &format!("largest frontier: {why}"),
        );
        goal
    }

    fn log_goal(&self, k: u64, goal: &Goal, candidates: usize, how: &str) {
        (self.fbe.log)(&format!(
            "planner: frame {k}: target {} of {candidates} candidates: {how}",
            goal.target
        ));
    }
}

/// What one replan offers, for the goal helpers.
struct Replan<'a> {
    k: u64,
    grid: &'a OccupancyGrid,
    frontiers: &'a Frontiers,
    regions: &'a [activemap_planning::frontier::FrontierRegion],
    /// Indices into `regions` of the eligible ones; `candidates[i]` is `eligible[i]`'s.
    eligible: &'a [usize],
    candidates: &'a [Candidate],
    pose: &'a PlanarPose,
}

/// A question to the model with everything it needs owned, so it can be asked on another
/// thread.
struct Question {
    step: u64,
    total_steps: u64,
    map: Arc<Gaussians<f32>>,
    map_version: u64,
    camera_height_m: f64,
    robot: [f64; 3],
    path: Vec<[f64; 2]>,
    candidates: Vec<Candidate>,
}

impl Question {
    fn query(&self) -> Query<'_> {
        Query {
            step: self.step,
            total_steps: self.total_steps,
            map: &self.map,
            map_version: self.map_version,
            camera_height_m: self.camera_height_m,
            robot: self.robot,
            path: &self.path,
            candidates: &self.candidates,
        }
    }
}

/// A `background` question being answered.
struct Pending {
    /// The frame whose replan asked it.
    asked: u64,
    /// The candidates it was asked about.
    candidates: Vec<Candidate>,
    worker: JoinHandle<anyhow::Result<Decision>>,
    /// Replaying: the frame at which the recording took the answer up (`None` inside: never);
    /// `None`: live, taken up once it has come.
    answered_frame: Option<Option<u64>>,
}

/// The decision of a `background` question (waits for it).
fn join(worker: JoinHandle<anyhow::Result<Decision>>) -> anyhow::Result<Decision> {
    worker
        .join()
        .map_err(|_| anyhow::anyhow!("planner: the LLM question's thread panicked"))?
}

#[cfg(test)]
mod tests {
    use super::*;
    use activemap_planning::GridGeometry;
    use activemap_planning::grid::CellState;
    use activemap_schemas::{FrontierRegion, ReplanReason};
    use std::io::{BufRead, BufReader, Read, Write};
    use std::net::TcpListener;
    use std::sync::mpsc;

    /// A loopback OpenAI-compatible server that answers every request with `target` 1, the
    /// first one only once `gate` is opened (so a test knows the question is still being
    /// asked, without timing).
    fn gated_server(gate: mpsc::Receiver<()>) -> String {
        let listener = TcpListener::bind("127.0.0.1:0").unwrap();
        let url = format!("http://{}/v1", listener.local_addr().unwrap());
        std::thread::spawn(move || {
            for (n, stream) in listener.incoming().enumerate() {
                let Ok(mut stream) = stream else { return };
                let mut reader = BufReader::new(stream.try_clone().unwrap());
                let mut length = 0;
                loop {
                    let mut line = String::new();
                    if reader.read_line(&mut line).unwrap_or(0) == 0 || line == "\r\n" {
                        break;
                    }
                    if let Some(v) = line.to_ascii_lowercase().strip_prefix("content-length:") {
                        length = v.trim().parse().unwrap();
                    }
                }
                let mut body = vec![0; length];
                reader.read_exact(&mut body).unwrap();
                if n == 0 {
                    gate.recv().unwrap();
                }
                let reply = serde_json::json!({
                    "id": "c", "object": "chat.completion", "model": "m",
                    "choices": [{ "index": 0, "finish_reason": "stop", "message": {
                        "role": "assistant", "content": "{\"target\": 1, \"reason\": \"r\"}" } }],
                    "usage": { "prompt_tokens": 10, "completion_tokens": 5 }
                })
                .to_string();
                let _ = write!(
                    stream,
                    "HTTP/1.1 200 OK\r\nContent-Type: application/json\r\nContent-Length: {}\r\nConnection: close\r\n\r\n{reply}",
                    reply.len()
                );
            }
        });
        url
    }

    fn region(id: u32, size: u32, x: f64) -> FrontierRegion {
        FrontierRegion {
            id,
            size_cells: size,
            centroid: [x, 1.0],
            closest_reachable_cell: [(x / 0.05) as i32, 10],
            path_distance_m: x,
            anchor: [x, 0.9],
        }
    }

    fn frontiers(regions: Vec<FrontierRegion>) -> Frontiers {
        Frontiers {
            frame_id: 0,
            stamp: 0.0,
            regions,
        }
    }

    fn config(url: &str, recorded: bool) -> GoalConfig {
        let provider = if recorded {
            serde_json::json!({ "kind": "recorded", "recording": "r.mcap" })
        } else {
            serde_json::json!({ "kind": "openai", "base_url": url, "model": "m",
                                "timeout_s": 10.0 })
        };
        serde_json::from_value(serde_json::json!({
            "policy": "llm",
            "llm": { "prompt": "text", "provider": provider, "ask": { "mode": "background" } }
        }))
        .unwrap()
    }

    /// One episode's replans: (frame, frontiers offered).
    fn episode() -> Vec<(u64, Frontiers)> {
        let all = || vec![region(7, 40, 0.5), region(3, 12, 2.0), region(5, 20, 4.0)];
        let without_3 = vec![region(7, 40, 0.5), region(5, 20, 4.0)];
        let without_3_and_5 = vec![region(7, 40, 0.5)];
        vec![
            (10, frontiers(all())),
            (11, frontiers(all())),
            (12, frontiers(all())),
            (13, frontiers(without_3)),
            (14, frontiers(without_3_and_5.clone())),
            (15, frontiers(vec![region(7, 40, 0.5), region(9, 30, 3.0)])),
        ]
    }

    /// Runs the replans of [`episode`]; `between(k)` runs before the replan of frame k.
    fn run(
        policy: &mut LlmPolicy,
        mut between: impl FnMut(&LlmPolicy, u64),
    ) -> Vec<(i32, Option<LlmExchange>)> {
        let geometry = GridGeometry::new(0.0, 0.0, 0.05, 100, 100).unwrap();
        let mut grid = OccupancyGrid::filled(geometry, CellState::Unknown);
        grid.data[0] = CellState::Free;
        let pose = PlanarPose::new(0.2, 0.2, 0.0);
        let mut out = Vec::new();
        for (k, f) in episode() {
            between(policy, k);
            let request = ReplanRequest {
                frame_id: k,
                reason: ReplanReason::ObstacleAhead,
            };
            let (goal, exchange) = policy.goal(&request, &grid, &f, &pose, 0.9).unwrap();
            out.push((goal.unwrap().target, exchange));
        }
        out
    }

    fn wait_for_answer(policy: &LlmPolicy) {
        for _ in 0..1000 {
            if policy.answer_arrived() {
                return;
            }
            std::thread::sleep(std::time::Duration::from_millis(10));
        }
        panic!("no answer in 10 s");
    }

    /// `ask.mode: background`: the replan that asks gets the largest frontier (id 7) at once,
    /// and so does the next one while the model has not answered; the answer (candidate 1,
    /// region 3) is applied at the first replan after it came, recorded as asked at frame 10
    /// and taken up at 12. The question of frame 13 (region 3 gone, so the candidates
    /// changed) chooses candidate 1 = region 5, which is gone by frame 14: recorded as stale,
    /// the largest taken. At frame 15 (new candidates) a question is asked and never taken
    /// up: the end of the episode records it as such. A replay with a recorded provider
    /// serving these exchanges takes the same goals at the same frames and records the same
    /// exchanges.
    #[test]
    fn a_background_answer_is_applied_at_a_later_replan_or_recorded_stale_and_replays() {
        let (open, gate) = mpsc::channel();
        let url = gated_server(gate);
        let mut live = LlmPolicy::new(&config(&url, false), "planner", None, &|_, _| {
            anyhow::bail!("no recording")
        })
        .unwrap();
        let mut outcome = run(&mut live, |policy, k| match k {
            11 => assert!(policy.asking() && !policy.answer_arrived()),
            12 => {
                open.send(()).unwrap();
                wait_for_answer(policy);
            }
            14 => wait_for_answer(policy),
            _ => {}
        });
        assert!(live.asking());
        let last = live.finish().unwrap();
        assert!(!live.asking());
        let targets: Vec<i32> = outcome.iter().map(|(t, _)| *t).collect();
        assert_eq!(targets, [7, 7, 3, 7, 7, 7]);
        let asked: Vec<Option<(u64, Option<u64>)>> = outcome
            .iter()
            .map(|(_, e)| e.as_ref().map(|e| (e.frame_id, e.answered_frame)))
            .collect();
        assert_eq!(
            asked,
            [
                None,
                None,
                Some((10, Some(12))),
                None,
                Some((13, Some(14))),
                None
            ]
        );
        let applied = outcome[2].1.clone().unwrap();
        assert_eq!(
            (applied.target, applied.decision, applied.fallback_target),
            (Some(1), 1, 0)
        );
        assert_eq!(applied.stale, None);
        let stale = outcome[4].1.clone().unwrap();
        assert_eq!(stale.target, Some(1));
        assert!(
            stale
                .stale
                .as_deref()
                .unwrap()
                .contains("frontier 1 of frame 13 is gone"),
            "{:?}",
            stale.stale
        );
        let last = last.unwrap();
        assert_eq!((last.frame_id, last.answered_frame), (15, None));
        assert!(last.stale.as_deref().unwrap().contains("episode ended"));
        assert_eq!(live.stats().queries, 3);

        // The replay: the recorded exchanges, served back in recording order.
        outcome.push((0, Some(last)));
        let recorded: Vec<LlmExchange> = outcome.iter().filter_map(|(_, e)| e.clone()).collect();
        let replies = recorded.clone();
        let loader = move |_: &std::path::Path, _: &str| {
            replies
                .iter()
                .map(|e| recorded_reply(e.clone(), "test").map(Option::unwrap))
                .collect()
        };
        let mut replay = LlmPolicy::new(&config(&url, true), "planner", None, &loader).unwrap();
        let again = run(&mut replay, |_, _| {});
        let end = replay.finish().unwrap();
        assert_eq!(
            again.iter().map(|(t, _)| *t).collect::<Vec<_>>(),
            targets,
            "the replay's goals"
        );
        let replayed: Vec<LlmExchange> = again
            .into_iter()
            .filter_map(|(_, e)| e)
            .chain(end)
            .collect();
        assert_eq!(replayed.len(), recorded.len());
        for (r, e) in replayed.iter().zip(&recorded) {
            assert_eq!(
                (r.frame_id, r.answered_frame, &r.stale, r.target, &r.reply),
                (e.frame_id, e.answered_frame, &e.stale, e.target, &e.reply)
            );
        }
    }
}
