//! `planner`: chooses the frontier to explore when the follower asks for a replan.
//!
//! Policy `fbe` (frontier-based exploration, SPEC §6 baseline): a thin wrapper around
//! [`activemap_planning::fbe::FbePlanner`], the decision the in-process explorer makes too
//! (ranking: `utility` = size / (path + turn cost + offset) by default, or `nearest` / `largest`;
//! strikes: a reached goal one, or two when its region did not shrink, a failed goal (no path,
//! stuck) two; amnesty once per growth of the map). The path distances come with the regions
//! (`FrontierRegion::path_distance_m`), so a replan costs no search here.
//!
//! Policy `llm` (SPEC §7): the multimodal-LLM long-horizon planner of `activemap-llm`. The
//! candidates are the regions FBE's strikes leave eligible (numbered 0..N−1 in the frontier
//! operator's order, largest first); the library renders the annotated BEV of the map snapshot
//! of frame k − 1 − L (L = `map_lag`, the mapper's, so a seeded run stays deterministic), asks
//! the configured provider, parses the reply and falls back to the largest frontier on any
//! failure. Every query goes out on `llm` ([`LlmExchange`]: request without secrets, BEV PNG,
//! raw reply, HTTP status, latency, tokens, decision, fallback reason) and so into the
//! recording; a `recorded` provider serves a recording's replies back in order (what
//! `activemap replay --node planner` uses, [`replay_config`]). With no provider configured the
//! policy is the paper's fallback (the largest frontier), said once at start.
//!
//! With no reachable frontier left, `when_no_frontier` ([`NoFrontier`]) says what happens:
//! `end` (the default, FBE) ends the episode (end of its `goal` stream); `refine` sends a goal
//! with target −1, the scorer's refine mode (SPEC §6: refine what is mapped), and asks again
//! at the next replan, so an episode with Fisher paths runs to its step budget (the simulator
//! ends it at `max_steps`). The model's −1 sends the same refine goal.

use std::collections::BTreeMap;
use std::path::Path;
use std::sync::Arc;

use activemap_geometry::PlanarPose;
use activemap_geometry::frames::planar_from_camera_pose;
use activemap_llm::planner::Source;
use activemap_llm::provider::{Completion, Failure, FailureKind, RecordedReply, Usage};
use activemap_llm::{
    Candidate, Choice as LlmChoice, Exchange, LlmConfig, LlmPlanner, ProviderConfig, Query,
};
use activemap_planning::OccupancyGrid as PlanGrid;
use activemap_planning::fbe::{FbeConfig, FbePolicy, FbeState};
use activemap_planning::frontier::{Approach, FrontierRegion as PlanRegion};
use activemap_planning::grid::Cell;
use activemap_runtime::{Context, Event, Flow, Operator, OperatorDescriptor, OperatorImpl};
use activemap_schemas::{
    Frontiers, GaussianMapView, Goal, LlmExchange, LlmFollowUp, MessageKind as K,
    OccupancyGridView, PoseEstimate, ReplanReason, ReplanRequest, SmallMessage,
};
use activemap_splat::Gaussians;
use nalgebra::Point2;

use crate::Registered;
use crate::convert::{pose_from_wire, read_grid, read_map};
use crate::follower::reason_from_wire;
use crate::join::FrameJoin;
use crate::mapper::required_snapshot;

/// The goal-choice policy, checked once when the config is read.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, serde::Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Policy {
    /// Frontier-based exploration.
    #[default]
    Fbe,
    /// The multimodal-LLM planner (SPEC §7), settings in `llm:`.
    Llm,
}

/// Which frontier FBE picks.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Choice {
    /// Shortest path.
    Nearest,
    /// Most cells.
    Largest,
    /// Size over path-plus-turn cost (the default: doorways before wall pockets).
    Utility,
}

/// What the planner does when no reachable frontier is left (even after forgiving strikes).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, serde::Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum NoFrontier {
    /// End the episode (FBE: nothing left to explore).
    #[default]
    End,
    /// Send a refine goal (target −1) and keep going: the scorer refines what is mapped.
    Refine,
}

/// The goal target that asks the scorer to refine the map instead of exploring a frontier
/// (SPEC §7: the LLM's −1).
pub const REFINE_TARGET: i32 = -1;

/// Config.
#[derive(Debug, Clone, serde::Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Config {
    /// `fbe` (default) or `llm`.
    #[serde(default)]
    pub policy: Policy,
    /// FBE choice (policy `fbe`).
    #[serde(default = "default_choice")]
    pub frontier: Choice,
    /// Struck goals ban approach cells within this many cells.
    #[serde(default = "default_exclusion")]
    pub exclusion_radius_cells: f64,
    /// No reachable frontier left: `end` the episode (default) or send a `refine` goal.
    #[serde(default)]
    pub when_no_frontier: NoFrontier,
    /// Policy `llm`: the planner's settings ([`activemap_llm::LlmConfig`]: prompt, provider,
    /// BEV, when to ask, budget). Absent: the offline default.
    #[serde(default)]
    pub llm: Option<serde_json::Value>,
    /// Policy `llm`: map lag L in frames; the BEV of the decision of frame k shows the map
    /// snapshot of frame k − 1 − L. Must equal the mapper's `map_lag`.
    #[serde(default)]
    pub map_lag: u64,
}

impl Config {
    /// The LLM settings (`llm:`, defaults when absent), checked.
    pub fn llm_config(&self) -> Result<LlmConfig, String> {
        match &self.llm {
            None => Ok(LlmConfig::default()),
            Some(v) => LlmConfig::from_value(v).map_err(|e| format!("llm: {e}")),
        }
    }

    /// True when the LLM policy needs map snapshots (a provider with the image prompt).
    fn needs_map(&self, llm: &LlmConfig) -> bool {
        self.policy == Policy::Llm && llm.provider.is_some() && llm.prompt.sends_image()
    }
}

fn default_choice() -> Choice {
    Choice::Utility
}
fn default_exclusion() -> f64 {
    FbeConfig::default().exclusion_radius_cells
}

fn check_config(value: &serde_json::Value) -> Result<(), String> {
    let config: Config = activemap_runtime::catalog::config_from_value(value)?;
    fbe_config(&config).validate().map_err(|e| e.to_string())?;
    config.llm_config()?;
    if config.policy == Policy::Fbe && config.llm.is_some() {
        return Err("`llm:` settings need `policy: llm`".into());
    }
    Ok(())
}

/// The library settings for an operator config.
fn fbe_config(config: &Config) -> FbeConfig {
    FbeConfig {
        policy: match config.frontier {
            Choice::Nearest => FbePolicy::Nearest,
            Choice::Largest => FbePolicy::Largest,
            Choice::Utility => FbePolicy::Utility,
        },
        exclusion_radius_cells: config.exclusion_radius_cells,
        ..FbeConfig::default()
    }
}

/// Library regions from the wire summaries (the FBE decision reads the size, the centroid and
/// the approach cell with its path distance).
pub fn regions_from_wire(frontiers: &Frontiers) -> Vec<PlanRegion> {
    frontiers
        .regions
        .iter()
        .map(|r| {
            let cell = Cell::new(r.closest_reachable_cell[0], r.closest_reachable_cell[1]);
            PlanRegion {
                cells: vec![cell; r.size_cells as usize],
                centroid: Point2::new(r.centroid[0], r.centroid[1]),
                anchor: cell,
                approach: r.path_distance_m.is_finite().then_some(Approach {
                    cell,
                    path_distance_m: r.path_distance_m,
                }),
            }
        })
        .collect()
}

/// The FBE decision on wire messages (testable without transport): the library's
/// [`activemap_planning::fbe::FbePlanner`] on the regions of the `frontier` operator.
pub struct FbePlanner {
    planner: activemap_planning::fbe::FbePlanner,
}

impl FbePlanner {
    /// A planner with no strikes.
    pub fn new(config: &Config) -> anyhow::Result<Self> {
        Ok(Self {
            planner: activemap_planning::fbe::FbePlanner::new(fbe_config(config))?,
        })
    }

    /// The shared decision state (strikes, amnesties).
    pub fn state(&self) -> &FbeState {
        self.planner.state()
    }

    /// Judges the last goal by the follower's `reason` against the current `frontiers`, then
    /// chooses among the reachable ones for the robot at `robot`: the region id and its
    /// centroid; `None` when no reachable region is left even after forgiving the strikes
    /// (once per growth of the map).
    pub fn choose(
        &mut self,
        reason: ReplanReason,
        grid: &PlanGrid,
        frontiers: &Frontiers,
        robot: &PlanarPose,
    ) -> anyhow::Result<Option<(u32, Point2<f64>)>> {
        let regions = regions_from_wire(frontiers);
        let choice = self
            .planner
            .choose(reason_from_wire(reason), grid, &regions, robot);
        // One line per decision in the node's log: what was on offer and what was banned.
        let offered: Vec<String> = frontiers
            .regions
            .iter()
            .take(8)
            .map(|r| format!("{}:{}c@{:.1}m", r.id, r.size_cells, r.path_distance_m))
            .collect();
        eprintln!(
            "planner: frame {} after {reason:?}: {} of {} regions [{}], {} strikes",
            frontiers.frame_id,
            choice.map_or("none".to_string(), |c| format!(
                "region {}",
                frontiers.regions[c.region].id
            )),
            frontiers.regions.len(),
            offered.join(" "),
            self.state().strikes().len()
        );
        let Some(choice) = choice else {
            return Ok(None);
        };
        Ok(Some((frontiers.regions[choice.region].id, choice.focus)))
    }
}

/// The inputs of one frame (the grid stays encoded until a replan request needs it).
#[derive(Default)]
struct Slot {
    grid: Option<Vec<u8>>,
    regions: Option<Frontiers>,
    pose: Option<PlanarPose>,
    /// Camera height of the estimate (the BEV's ceiling cut).
    camera_z: Option<f64>,
}

/// The goal for one replan request (transport-free): the FBE choice, or with no reachable
/// frontier left a refine goal (target [`REFINE_TARGET`], focused on the robot's position)
/// when `when_no_frontier` is `refine`; `None` ends the episode.
pub fn goal_for_request(
    fbe: &mut FbePlanner,
    when_no_frontier: NoFrontier,
    request: &ReplanRequest,
    grid: &PlanGrid,
    frontiers: &Frontiers,
    pose: &PlanarPose,
) -> anyhow::Result<Option<Goal>> {
    let k = request.frame_id;
    Ok(
        match (
            fbe.choose(request.reason, grid, frontiers, pose)?,
            when_no_frontier,
        ) {
            (Some((target, focus)), _) => Some(Goal {
                frame_id: k,
                target: target as i32,
                focus: [focus.x, focus.y],
            }),
            (None, NoFrontier::End) => {
                eprintln!("planner: no reachable frontier left at frame {k}: episode over");
                None
            }
            (None, NoFrontier::Refine) => {
                eprintln!("planner: no reachable frontier left at frame {k}: refine goal");
                Some(Goal {
                    frame_id: k,
                    target: REFINE_TARGET,
                    focus: [pose.x, pose.y],
                })
            }
        },
    )
}

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

/// The replies a recorded provider serves: the exchanges on `{node}/llm` of the recording
/// at `path`, in order, without those that never reached a provider (budget spent). Parse
/// and model failures are served as they were, so the same fallbacks happen again; a
/// follow-up turn is served with its exchange.
pub fn recorded_replies(path: &Path, node: &str) -> anyhow::Result<Vec<RecordedReply>> {
    let recording = activemap_runtime::record::read_recording(path)?;
    let topic = format!("{node}/llm");
    let mut replies = Vec::new();
    for m in recording
        .messages
        .iter()
        .filter(|m| m.topic == topic && !m.bytes.is_empty())
    {
        let at = format!("{}: message {} of `{topic}`", path.display(), m.seq);
        let e = LlmExchange::decode(&m.bytes).map_err(|e| anyhow::anyhow!("{at}: {e}"))?;
        replies.extend(recorded_reply(e, &at)?);
    }
    if replies.is_empty() {
        eprintln!(
            "planner: {} holds no exchange on `{topic}`: every query will fall back",
            path.display()
        );
    }
    Ok(replies)
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
    lag: u64,
    needs_map: bool,
    total_steps: u64,
    /// Map snapshots by frame; snapshots of the same keyframe share one decoded map.
    maps: BTreeMap<u64, (u64, Arc<Gaussians<f32>>)>,
    /// The estimated positions so far (the green path), one per frame that moved ≥ 1 cm.
    path: Vec<[f64; 2]>,
}

impl LlmPolicy {
    /// The policy of `config` for node `node`; `max_steps` is the run's `--max-steps`.
    pub fn new(config: &Config, node: &str, max_steps: Option<u64>) -> anyhow::Result<Self> {
        let llm = config
            .llm_config()
            .map_err(|e| anyhow::anyhow!("planner: {e}"))?;
        let recorded = match &llm.provider {
            Some(ProviderConfig::Recorded {
                recording,
                node: from,
            }) => Some(recorded_replies(
                recording,
                from.as_deref().unwrap_or(node),
            )?),
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
            lag: config.map_lag,
            total_steps,
            maps: BTreeMap::new(),
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

    /// Stores a wire map snapshot (decoded only when its keyframe is new).
    pub fn add_map(&mut self, bytes: &[u8]) -> anyhow::Result<()> {
        if !self.needs_map {
            return Ok(());
        }
        let header = GaussianMapView::parse(bytes)?.header;
        let version = header.keyframe().unwrap_or(u64::MAX);
        let reuse = self
            .maps
            .values()
            .next_back()
            .filter(|(v, m)| *v == version && m.len() as u64 == header.count)
            .map(|(_, m)| m.clone());
        let map = match reuse {
            Some(m) => m,
            None => Arc::new(read_map(bytes)?.1),
        };
        self.maps.insert(header.frame_id, (version, map));
        Ok(())
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
        !self.needs_map || self.maps.contains_key(&required_snapshot(k, self.lag))
    }

    /// The goal for `request` and the exchange to record, if a query was made; `None` goal:
    /// the episode is over.
    pub fn goal(
        &mut self,
        request: &ReplanRequest,
        grid: &PlanGrid,
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
        let refine = Goal {
            frame_id: k,
            target: REFINE_TARGET,
            focus: [pose.x, pose.y],
        };
        if eligible.is_empty() {
            self.fbe.planner.commit(&regions, None, grid);
            return Ok(match self.when_no_frontier {
                NoFrontier::End => {
                    eprintln!("planner: no reachable frontier left at frame {k}: episode over");
                    (None, None)
                }
                NoFrontier::Refine => {
                    eprintln!("planner: no reachable frontier left at frame {k}: refine goal");
                    (Some(refine), None)
                }
            });
        }
        let cell = grid.geometry.resolution;
        let candidates: Vec<Candidate> = eligible
            .iter()
            .map(|&i| candidate(&frontiers.regions[i], cell))
            .collect();
        let (version, map) = match self.maps.get(&required_snapshot(k, self.lag)) {
            Some((v, m)) => (*v, m.clone()),
            // The text prompt (or no provider) draws no BEV: no map is kept.
            None if !self.needs_map => (u64::MAX, Arc::new(Gaussians::new())),
            None => anyhow::bail!(
                "planner: the decision of frame {k} needs map snapshot {}, which has not arrived",
                required_snapshot(k, self.lag)
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
                refine
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
        eprintln!(
            "planner: frame {k}: target {} of {} candidates: {how}",
            goal.target,
            candidates.len()
        );
        // Older snapshots are no longer needed (requests come in frame order).
        let keep = required_snapshot(k, self.lag);
        self.maps = self.maps.split_off(&keep);
        Ok((
            Some(goal),
            decision.exchange.as_ref().map(|e| exchange_to_wire(k, e)),
        ))
    }
}

/// How a `recorded` provider replaces the node's provider when `activemap replay` re-runs a
/// planner alone: the config of node `node` with its LLM provider set to the recording at
/// `recording` (unchanged for any other policy or an offline planner).
pub fn replay_config(
    config: &serde_json::Value,
    recording: &Path,
    node: &str,
) -> serde_json::Value {
    let mut config = config.clone();
    let llm = config.get("policy").and_then(|p| p.as_str()) == Some("llm");
    if let Some(provider) = config.pointer_mut("/llm/provider")
        && llm
        && !provider.is_null()
    {
        *provider = serde_json::json!({
            "kind": "recorded",
            "recording": recording,
            "node": node,
        });
    }
    config
}

/// The operator.
pub struct Planner {
    fbe: FbePlanner,
    llm: Option<LlmPolicy>,
    when_no_frontier: NoFrontier,
    join: FrameJoin<Slot>,
    requests: Vec<ReplanRequest>,
}

impl Operator for Planner {
    type Config = Config;

    fn new(config: Config, ctx: &mut Context<'_>) -> anyhow::Result<Self> {
        let llm = match config.policy {
            Policy::Fbe => None,
            Policy::Llm => {
                let policy = LlmPolicy::new(&config, ctx.node_id(), ctx.max_steps())?;
                eprintln!("planner: {}", policy.describe());
                Some(policy)
            }
        };
        Ok(Self {
            fbe: FbePlanner::new(&config)?,
            llm,
            when_no_frontier: config.when_no_frontier,
            join: FrameJoin::new(),
            requests: Vec::new(),
        })
    }

    fn on_event(&mut self, event: Event<'_>, ctx: &mut Context<'_>) -> anyhow::Result<Flow> {
        match event {
            Event::Input(input) => match input.port {
                inputs::GRID => {
                    let k = OccupancyGridView::parse(input.bytes)?.header.frame_id;
                    self.join.slot(k).grid = Some(input.bytes.to_vec());
                }
                inputs::REGIONS => {
                    let f: Frontiers = input.decode()?;
                    let frame = f.frame_id;
                    self.join.slot(frame).regions = Some(f);
                }
                inputs::REPLAN => self.requests.push(input.decode()?),
                inputs::POSE => {
                    let e: PoseEstimate = input.decode()?;
                    let t = pose_from_wire(&e.t_world_camera)?;
                    let pose = planar_from_camera_pose(&t);
                    if let Some(llm) = &mut self.llm {
                        llm.add_position(&pose);
                    }
                    let slot = self.join.slot(e.frame_id);
                    slot.pose = Some(pose);
                    slot.camera_z = Some(t.translation.z);
                }
                inputs::MAP => {
                    if let Some(llm) = &mut self.llm {
                        llm.add_map(input.bytes)?;
                    }
                }
                other => anyhow::bail!("planner: unexpected input `{other}`"),
            },
            Event::InputClosed { port: inputs::POSE } => return Ok(Flow::Stop),
            _ => return Ok(Flow::Continue),
        }
        while let Some(request) = self.requests.first().copied() {
            let k = request.frame_id;
            let Some(Slot {
                grid: Some(grid),
                regions: Some(frontiers),
                pose: Some(pose),
                camera_z: Some(camera_z),
            }) = self.join.get(k)
            else {
                break;
            };
            if self.llm.as_ref().is_some_and(|l| !l.ready(k)) {
                break;
            }
            let (_, grid) = read_grid(grid)?;
            self.requests.remove(0);
            let goal = match &mut self.llm {
                None => goal_for_request(
                    &mut self.fbe,
                    self.when_no_frontier,
                    &request,
                    &grid,
                    frontiers,
                    pose,
                )?,
                Some(llm) => {
                    let (goal, exchange) = llm.goal(&request, &grid, frontiers, pose, *camera_z)?;
                    if let Some(exchange) = exchange {
                        ctx.send(outputs::LLM, &exchange)?;
                    }
                    goal
                }
            };
            match goal {
                Some(goal) => ctx.send(outputs::GOAL, &goal)?,
                None => return Ok(Flow::Stop),
            }
            // Older frames are no longer needed (requests come in frame order).
            self.join.discard_before(k);
        }
        Ok(Flow::Continue)
    }
}

/// The operator's input ports, named once for registration and dispatch.
pub mod inputs {
    activemap_runtime::ports! {
        MAP = "map": super::K::GaussianMap,
        REGIONS = "regions": super::K::Frontiers,
        POSE = "pose": super::K::PoseEstimate,
        REPLAN = "replan": super::K::ReplanRequest,
        GRID = "grid": super::K::OccupancyGrid
    }
}

/// The operator's output ports, named once for registration and dispatch.
pub mod outputs {
    activemap_runtime::ports! {
        GOAL = "goal": super::K::Goal,
        LLM = "llm": super::K::LlmExchange
    }
}

/// Registry entry.
pub fn registered() -> Registered {
    Registered {
        descriptor: OperatorDescriptor {
            name: "planner",
            summary: "Goal choice on replan: FBE utility/nearest/largest frontier, or the multimodal LLM on the annotated BEV (refine, -1, when none is left) (SPEC §6, §7)",
            inputs: inputs::ALL,
            outputs: outputs::ALL,
            evaluation: false,
            check_config,
        },
        implementation: Some(OperatorImpl::of::<Planner>()),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use activemap_planning::GridGeometry;
    use activemap_planning::grid::CellState;
    use activemap_schemas::FrontierRegion;

    fn wire(id: u32, size: u32, cell: [i32; 2], distance: f64) -> FrontierRegion {
        FrontierRegion {
            id,
            size_cells: size,
            centroid: [cell[0] as f64 * 0.05, cell[1] as f64 * 0.05 + 0.3],
            closest_reachable_cell: cell,
            path_distance_m: distance,
            anchor: [cell[0] as f64 * 0.05, cell[1] as f64 * 0.05 + 0.1],
        }
    }

    fn frontiers(regions: Vec<FrontierRegion>) -> Frontiers {
        Frontiers {
            frame_id: 0,
            stamp: 0.0,
            regions,
        }
    }

    /// The wrapper keeps the library's rules: with `nearest`, a pocket reached and still there
    /// at full size is banned at once (the doorway comes next), a failed goal is banned too,
    /// and when everything is banned the strikes are forgiven once per growth of the map.
    #[test]
    fn planner_bans_an_unshrunk_pocket_after_one_visit() {
        let geometry = GridGeometry::new(0.0, 0.0, 0.05, 100, 100).unwrap();
        let mut grid = PlanGrid::filled(geometry, CellState::Unknown);
        grid.data[0] = CellState::Free;
        let config = Config {
            policy: Policy::Fbe,
            frontier: Choice::Nearest,
            exclusion_radius_cells: 3.0,
            when_no_frontier: NoFrontier::End,
            llm: None,
            map_lag: 0,
        };
        let mut planner = FbePlanner::new(&config).unwrap();
        let robot = PlanarPose::new(0.5, 0.5, 0.0);
        let f = frontiers(vec![wire(7, 40, [60, 10], 3.0), wire(3, 12, [20, 10], 1.0)]);
        let first = planner
            .choose(ReplanReason::Startup, &grid, &f, &robot)
            .unwrap();
        assert_eq!(first.unwrap().0, 3, "nearest first");
        let second = planner
            .choose(ReplanReason::PathDone, &grid, &f, &robot)
            .unwrap();
        assert_eq!(
            second.unwrap().0,
            7,
            "the unshrunk pocket is banned after one visit"
        );
        assert_eq!(planner.state().unobservable_goals, 1);
        let none = planner
            .choose(ReplanReason::Stuck, &grid, &f, &robot)
            .unwrap();
        assert_eq!(
            none.map(|c| c.0),
            Some(3),
            "amnesty: the map has free cells"
        );
        assert_eq!(planner.state().amnesties, 1);
        let again = planner
            .choose(ReplanReason::NoPath, &grid, &f, &robot)
            .unwrap();
        assert_eq!(again.map(|c| c.0), Some(7));
        let over = planner
            .choose(ReplanReason::NoPath, &grid, &f, &robot)
            .unwrap();
        assert!(
            over.is_none(),
            "no growth since the amnesty: the episode is over"
        );
    }

    /// With no reachable frontier left, `end` (the default) ends the episode and `refine`
    /// sends a refine goal (target −1 at the robot) instead, at every such request; a frontier
    /// that appears again is chosen as before (the FBE decision itself is unchanged).
    #[test]
    fn no_frontier_ends_the_episode_or_asks_to_refine() {
        let config: Config = serde_json::from_value(serde_json::json!({})).unwrap();
        assert_eq!(config.when_no_frontier, NoFrontier::End);
        let refine: Config = serde_json::from_value(
            serde_json::json!({ "frontier": "largest", "when_no_frontier": "refine" }),
        )
        .unwrap();
        assert_eq!(refine.when_no_frontier, NoFrontier::Refine);
        let e = check_config(&serde_json::json!({ "when_no_frontier": "spin" })).unwrap_err();
        assert!(e.contains("spin") && e.contains("refine"), "{e}");

        let geometry = GridGeometry::new(0.0, 0.0, 0.05, 100, 100).unwrap();
        let grid = PlanGrid::filled(geometry, CellState::Free);
        let robot = PlanarPose::new(0.5, 0.75, 1.0);
        let request = |frame_id, reason| ReplanRequest { frame_id, reason };
        let none = Frontiers {
            frame_id: 40,
            ..frontiers(vec![])
        };
        let mut fbe = FbePlanner::new(&config).unwrap();
        let end = goal_for_request(
            &mut fbe,
            config.when_no_frontier,
            &request(40, ReplanReason::Startup),
            &grid,
            &none,
            &robot,
        )
        .unwrap();
        assert_eq!(end, None);

        let mut fbe = FbePlanner::new(&refine).unwrap();
        for (k, reason) in [(40, ReplanReason::Startup), (90, ReplanReason::PathDone)] {
            let goal = goal_for_request(
                &mut fbe,
                refine.when_no_frontier,
                &request(k, reason),
                &grid,
                &none,
                &robot,
            )
            .unwrap();
            assert_eq!(
                goal,
                Some(Goal {
                    frame_id: k,
                    target: REFINE_TARGET,
                    focus: [0.5, 0.75]
                })
            );
        }
        assert!(
            fbe.state().strikes().is_empty(),
            "a refine goal strikes nothing"
        );
        let some = frontiers(vec![wire(4, 30, [60, 10], 3.0)]);
        let goal = goal_for_request(
            &mut fbe,
            refine.when_no_frontier,
            &request(120, ReplanReason::PathDone),
            &grid,
            &some,
            &robot,
        )
        .unwrap()
        .unwrap();
        assert_eq!((goal.frame_id, goal.target), (120, 4));
        assert_eq!(goal.focus, some.regions[0].centroid);
    }

    /// The default ranking is the utility: a large frontier beats a small nearer one.
    #[test]
    fn default_ranking_is_the_utility() {
        let config: Config = serde_json::from_value(serde_json::json!({})).unwrap();
        assert_eq!(config.frontier, Choice::Utility);
        let geometry = GridGeometry::new(0.0, 0.0, 0.05, 100, 100).unwrap();
        let grid = PlanGrid::filled(geometry, CellState::Free);
        let mut planner = FbePlanner::new(&config).unwrap();
        // Robot at (0.5, 0.5) facing +x; both approach cells lie ahead of it (y = 0.5).
        let f = frontiers(vec![wire(1, 6, [14, 10], 0.2), wire(2, 40, [70, 10], 3.0)]);
        let robot = PlanarPose::new(0.5, 0.5, 0.0);
        let c = planner
            .choose(ReplanReason::Startup, &grid, &f, &robot)
            .unwrap();
        assert_eq!(c.unwrap().0, 2);
        assert!(check_config(&serde_json::json!({ "frontier": "utility" })).is_ok());
        assert!(check_config(&serde_json::json!({ "frontier": "widest" })).is_err());
    }

    /// `policy` is checked once, when the config is read: `fbe` (the default) and `llm`;
    /// anything else is refused naming both; `llm:` settings are checked with it (a key in
    /// the YAML is refused) and need `policy: llm`.
    #[test]
    fn policies_and_llm_settings_are_checked_when_read() {
        let config: Config = serde_json::from_value(serde_json::json!({})).unwrap();
        assert_eq!(config.policy, Policy::Fbe);
        assert!(check_config(&serde_json::json!({ "policy": "fbe" })).is_ok());
        assert!(check_config(&serde_json::json!({ "policy": "llm" })).is_ok());
        let other = check_config(&serde_json::json!({ "policy": "random" })).unwrap_err();
        assert!(other.contains("random") && other.contains("llm"), "{other}");
        let key = check_config(&serde_json::json!({ "policy": "llm", "llm": { "provider": {
            "kind": "openai", "base_url": "http://127.0.0.1:1/v1", "model": "m",
            "api_key": "sk-secret" } } }))
        .unwrap_err();
        assert!(
            key.contains("api_key_env") && !key.contains("sk-secret"),
            "{key}"
        );
        let fbe = check_config(&serde_json::json!({ "llm": {} })).unwrap_err();
        assert!(fbe.contains("policy: llm"), "{fbe}");
    }

    /// An exchange whose first reply was cut (with `<think>` and `reasoning_content`) and
    /// whose follow-up answered goes on the wire and back to a recorded provider, which serves
    /// both turns: the replayed planner takes the same decision and records the same exchange.
    /// The evaluator's record keeps the reasoning and the `<think>` text apart.
    #[test]
    fn a_follow_up_exchange_replays_from_its_wire_record() {
        use activemap_llm::PromptStyle;
        use activemap_llm::provider::RecordedProvider;
        let completion = |reply: &str, finish: &str, reasoning: &str| Completion {
            provider: "openai".into(),
            model: "m".into(),
            request: "{\"model\":\"m\"}".into(),
            http_status: Some(200),
            attempts: 1,
            latency_ms: 12.5,
            usage: Usage {
                prompt_tokens: Some(100),
                completion_tokens: Some(50),
            },
            reply: reply.into(),
            finish_reason: Some(finish.into()),
            reasoning: reasoning.into(),
            schema_refused: false,
            failure: None,
        };
        let first = completion(
            "<think>{\"target\": 0, \"reason\": \"no\"}</think>Exploration plan: 1. go",
            "length",
            "thinking aloud",
        );
        let mut second = completion("{\"target\": 2, \"reason\": \"hall\"}", "stop", "");
        second.schema_refused = true;
        let config = LlmConfig {
            prompt: PromptStyle::Text,
            ..LlmConfig::default()
        };
        let candidates: Vec<Candidate> = (0..3)
            .map(|i| Candidate {
                centroid: [i as f64, 1.0],
                label_at: [i as f64, 1.0],
                size_cells: 30 - i,
                area_m2: 0.1,
                path_distance_m: 1.0,
            })
            .collect();
        let map = Gaussians::new();
        let query = Query {
            step: 7,
            total_steps: 100,
            map: &map,
            map_version: 7,
            camera_height_m: 1.0,
            robot: [0.0; 3],
            path: &[],
            candidates: &candidates,
        };
        let run = |reply: RecordedReply| {
            let provider = Box::new(RecordedProvider::new(vec![reply]));
            let mut planner = LlmPlanner::new(config.clone(), Some(provider)).unwrap();
            let d = planner.decide(&query).unwrap();
            assert_eq!(planner.stats().follow_ups, 1);
            assert_eq!(planner.stats().calls, 2);
            (d.choice, exchange_to_wire(7, d.exchange.as_ref().unwrap()))
        };
        let (choice, live) = run(RecordedReply {
            system: String::new(),
            user: String::new(),
            completion: first,
            follow_up: Some(second),
        });
        assert_eq!(choice, LlmChoice::Frontier(2));
        assert_eq!((live.target, live.failure.as_deref()), (Some(2), None));
        assert_eq!(live.finish_reason.as_deref(), Some("length"));
        assert_eq!(live.reasoning, "thinking aloud");
        let f = live.follow_up.as_ref().unwrap();
        assert!(f.cause.contains("no_json") && f.cause.contains("finish reason length"));
        assert!(f.schema_refused && f.prompt.contains("only the JSON object"));
        let wire = LlmExchange::decode(&live.encode()).unwrap();
        let reply = recorded_reply(wire, "test").unwrap().unwrap();
        assert!(reply.follow_up.is_some());
        let (again, replayed) = run(reply);
        assert_eq!((again, &replayed), (choice, &live));
        let record = crate::evaluator::llm_record(&live, None);
        assert_eq!(
            record.thinking.as_deref(),
            Some("{\"target\": 0, \"reason\": \"no\"}")
        );
        assert_eq!(record.reasoning.as_deref(), Some("thinking aloud"));
        assert_eq!(
            record.follow_up.unwrap().finish_reason.as_deref(),
            Some("stop")
        );
    }

    /// Replay swaps an LLM planner's provider for the recording's replies, and leaves other
    /// configs alone.
    #[test]
    fn replay_serves_the_recorded_replies() {
        let live = serde_json::json!({ "policy": "llm", "llm": { "provider": {
            "kind": "ollama", "base_url": "http://127.0.0.1:11434", "model": "llava" } } });
        let r = replay_config(&live, Path::new("/runs/a/recording.mcap"), "planner");
        assert_eq!(r["llm"]["provider"]["kind"], "recorded");
        assert_eq!(r["llm"]["provider"]["recording"], "/runs/a/recording.mcap");
        assert!(check_config(&r).is_ok());
        let fbe = serde_json::json!({ "policy": "fbe" });
        assert_eq!(replay_config(&fbe, Path::new("x"), "planner"), fbe);
        let offline = serde_json::json!({ "policy": "llm" });
        assert_eq!(replay_config(&offline, Path::new("x"), "planner"), offline);
    }
}
