//! `planner`: chooses the goal when the follower asks for a replan: a shell around the goal
//! policy of `activemap-policy` ([`activemap_policy::goal`]: FBE, the LLM on FBE's eligible
//! frontiers, refine), which the in-process explorer runs too. The shell joins each replan
//! request with its frame's grid, regions and pose, hands the map snapshots and poses to the
//! policy, and sends the goal on `goal` (its end ends the episode) and each LLM query on `llm`
//! ([`LlmExchange`], into the recording). A `recorded` provider serves a recording's replies
//! back in order ([`recorded_replies`]; what `activemap replay --node planner` uses,
//! [`replay_config`]). With no provider configured the `llm` policy is the paper's fallback
//! (the largest frontier), said once at start.

use std::path::Path;

use activemap_geometry::PlanarPose;
use activemap_geometry::frames::planar_from_camera_pose;
use activemap_llm::provider::RecordedReply;
use activemap_policy::GoalInput;
use activemap_policy::goal::GoalPolicy;
use activemap_runtime::{Context, Event, Flow, Operator, OperatorDescriptor, OperatorImpl};
use activemap_schemas::{
    Frontiers, LlmExchange, MessageKind as K, OccupancyGridView, PoseEstimate, ReplanRequest,
    SmallMessage,
};

pub use activemap_policy::goal::{
    Choice, FbePlanner, GoalConfig as Config, NoFrontier, Policy, REFINE_TARGET, goal_for_request,
};
pub use activemap_policy::llm::{LlmPolicy, exchange_to_wire, recorded_reply};
pub use activemap_policy::wire::regions_from_wire;

use crate::Registered;
use crate::convert::{pose_from_wire, read_grid, with_map_snapshot};
use crate::join::FrameJoin;

fn check_config(value: &serde_json::Value) -> Result<(), String> {
    let config: Config = activemap_runtime::config_from_value(value)?;
    config.validate()
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
    goals: GoalPolicy,
    join: FrameJoin<Slot>,
    requests: Vec<ReplanRequest>,
}

impl Operator for Planner {
    type Config = Config;

    fn new(config: Config, ctx: &mut Context<'_>) -> anyhow::Result<Self> {
        let goals = GoalPolicy::new(&config, ctx.node_id(), ctx.max_steps(), &recorded_replies)?;
        if let Some(about) = goals.describe() {
            eprintln!("planner: {about}");
        }
        Ok(Self {
            goals,
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
                    self.goals.add_pose(&pose);
                    let slot = self.join.slot(e.frame_id);
                    slot.pose = Some(pose);
                    slot.camera_z = Some(t.translation.z);
                }
                inputs::MAP => with_map_snapshot(input.bytes, |map| self.goals.add_map(map))?,
                other => anyhow::bail!("planner: unexpected input `{other}`"),
            },
            Event::InputClosed { port: inputs::POSE } => return self.finish(ctx),
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
            if !self.goals.ready(k) {
                break;
            }
            let (_, grid) = read_grid(grid)?;
            self.requests.remove(0);
            let decision = self.goals.goal(&GoalInput {
                request,
                grid: &grid,
                frontiers,
                pose: *pose,
                camera_z: *camera_z,
            })?;
            if let Some(exchange) = decision.exchange {
                ctx.send(outputs::LLM, &exchange)?;
            }
            match decision.goal {
                Some(goal) => ctx.send(outputs::GOAL, &goal)?,
                None => return self.finish(ctx),
            }
            // Older frames are no longer needed (requests come in frame order).
            self.join.discard_before(k);
        }
        Ok(Flow::Continue)
    }
}

impl Planner {
    /// Ends the node: a `background` LLM question still being asked is waited for and
    /// recorded (never taken up), so nothing asked is lost.
    fn finish(&mut self, ctx: &mut Context<'_>) -> anyhow::Result<Flow> {
        if let Some(exchange) = self.goals.finish()? {
            ctx.send(outputs::LLM, &exchange)?;
        }
        Ok(Flow::Stop)
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
    use activemap_llm::provider::{Completion, Usage};
    use activemap_llm::{Candidate, Choice as LlmChoice, LlmConfig, LlmPlanner, Query};
    use activemap_splat::Gaussians;

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
            background: false,
            answered_frame: None,
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
