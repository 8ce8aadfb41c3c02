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

use std::sync::Arc;

use activemap_geometry::PlanarPose;
use activemap_geometry::snapshots::LaggedSnapshots;
use activemap_llm::planner::Source;
use activemap_llm::provider::{Completion, Failure, FailureKind, RecordedReply, Usage};
use activemap_llm::{Candidate, Choice as LlmChoice, Exchange, LlmPlanner, ProviderConfig, Query};
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
    }))
}

/// The `llm` policy without transport: FBE's strikes pick the eligible regions, the library
/// planner decides among them on the lagged map snapshot.
pub struct LlmPolicy {
    fbe: FbePlanner,
    planner: LlmPlanner,
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
            planner: LlmPlanner::new(llm, provider)?,
            when_no_frontier: config.when_no_frontier,
            total_steps,
            maps: LaggedSnapshots::new(config.map_lag),
            path: Vec::new(),
        })
    }

    /// The line the node logs at start.
    pub fn describe(&self) -> String {
        self.planner.describe()
    }

    /// The library planner (its totals).
    pub fn planner(&self) -> &LlmPlanner {
        &self.planner
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

    /// The goal for `request` and the exchange to record, if a query was made; `None` goal:
    /// the episode is over.
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
        if eligible.is_empty() {
            self.fbe.planner.commit(&regions, None, grid);
            let goal = no_frontier_goal(self.when_no_frontier, k, pose, self.fbe.log);
            return Ok((goal, None));
        }
        let cell = grid.geometry.resolution;
        let candidates: Vec<Candidate> = eligible
            .iter()
            .map(|&i| candidate(&frontiers.regions[i], cell))
            .collect();
        let (version, map) = match self.maps.for_frame(k) {
            Some((v, m)) => (*v, m.clone()),
            // The text prompt (or no provider) draws no BEV: no map is kept.
            None if !self.needs_map => (u64::MAX, Arc::new(Gaussians::new())),
            None => anyhow::bail!(
                "planner: the decision of frame {k} needs map snapshot {}, which has not arrived",
                self.maps.needed(k)
            ),
        };
        let decision = self.planner.decide(&Query {
            step: k,
            total_steps: self.total_steps,
            map: &map,
            map_version: version,
            camera_height_m: camera_z,
            robot: [pose.x, pose.y, pose.yaw],
            path: &self.path,
            candidates: &candidates,
        })?;
        let goal = match decision.choice {
            LlmChoice::Frontier(i) => {
                let region = eligible[i];
                self.fbe.planner.commit(&regions, Some(region), grid);
                let r = &frontiers.regions[region];
                Goal {
                    frame_id: k,
                    target: r.id as i32,
                    focus: r.centroid,
                }
            }
            LlmChoice::Refine => {
                self.fbe.planner.commit(&regions, None, grid);
                Goal {
                    frame_id: k,
                    target: REFINE_TARGET,
                    focus: [pose.x, pose.y],
                }
            }
        };
        let how = match &decision.source {
            Source::Model => "the model's choice".to_string(),
            Source::Reused => "the last answer (map unchanged)".to_string(),
            Source::Held => "the last target (too soon to ask)".to_string(),
            Source::Fallback(f) if f.kind == FailureKind::NoProvider => {
                "largest frontier".to_string()
            }
            Source::Fallback(f) => format!("largest frontier, fallback after {f}"),
        };
        (self.fbe.log)(&format!(
            "planner: frame {k}: target {} of {} candidates: {how}",
            goal.target,
            candidates.len()
        ));
        // Older snapshots are no longer needed (requests come in frame order).
        self.maps.retain_needed_from(k);
        Ok((
            Some(goal),
            decision.exchange.as_ref().map(|e| exchange_to_wire(k, e)),
        ))
    }
}
