//! Checks across nodes of a dataflow, beyond what each operator's own config check can see.
//! `activemap validate`, `activemap run` and the benchmarks call [`check_flow`] after the
//! runtime's validation ([`load`] does both).
//!
//! - **Map lag.** The mapper publishes one map snapshot per frame and its consumers (tracker,
//!   occupancy) use the snapshot of frame k − 1 − L for frame k, L = `map_lag`. When a
//!   consumer's L differs from its mapper's, it waits for a snapshot that never comes (or uses
//!   the wrong one) and the lockstep loop hangs; so every tracker or occupancy node reading a
//!   mapper node's output must declare the mapper's `map_lag`.
//! - **Robot.** One robot model (`activemap_geometry::RobotModel`: camera height, radius,
//!   step and turn sizes) for the whole flow: every node that takes a `robot` config (sim,
//!   tracker, occupancy, frontier, scorer, follower, evaluator) must end up with the same one
//!   (a node that leaves it out has the default), else e.g. the tracker predicts 5 cm steps
//!   for a robot the simulator moves by 10 cm.
//! - **Camera.** A scorer in `fisher` mode renders the map at the frames' camera but never
//!   sees a frame, so its `camera` (width, height, hfov_deg) must equal the `sim` node's; it
//!   reads the mapper's `map` (its `map_lag` is checked like the tracker's), and a `fisher`
//!   scorer without a `map` input would wait for snapshots forever, so that is refused too.
//! - **Scene.** The evaluator measures the run against its own copy of the scene (the navigable
//!   floor, the ground-truth renders), so its scene keys (`scene`, `max_rooms`, `max_area`,
//!   `up_axis`, `transform`, `floor`) must equal the `sim` node's: `--set sim.scene=house:3`
//!   alone would have the evaluator judge house 3's episode against house 7.
//! - **Depth model.** The mapper fits its map under one depth model (`tuning.depth_model`,
//!   `activemap_splat::DepthModel`); the tracker's renders and the evaluator's must use the
//!   same (`depth_model`; a node that leaves it out has the default), else the tracker
//!   compares frames with depths the map was not fitted to and the evaluator misjudges it.
//! - **LLM planner.** A planner with policy `llm` draws its BEV from the mapper's lagged map
//!   snapshot: its `map_lag` is checked like the tracker's, and it must read the map with
//!   `drop: block`.
//!
//! Two settings are implied rather than checked ([`implied_overrides`], applied by [`load_with`]
//! and [`parse`] after the user's overrides, so the effective flow in the run folder holds them):
//!
//! - **Sensor depth noise.** A tracker weighs each depth residual by σ_d(z) = `depth_sigma` +
//!   `depth_sigma_z2`·z² (`activemap_slam::DenseConfig`). When the simulator feeding its `rgbd`
//!   adds depth noise growing with z² and the tracker leaves `dense.depth_sigma_z2` unset, the
//!   tracker takes the simulator's coefficient (issue 34: unweighted, the realistic sensor's depth
//!   noise drifts long episodes by decimetres). A tracker that sets it (0 included) keeps its own.
//! - **Actuation noise.** A tracker whose prior is the commanded action weighs it by the
//!   per-axis σ of `dense.motion_sigmas`. When the simulator feeding its `rgbd` perturbs the
//!   actions and the tracker leaves `motion_sigmas` unset, the tracker takes σ from the
//!   simulator's actuation noise ([`crate::tracker::motion_sigmas_for`]; issue 34: the
//!   ground-robot default, 1 cm sideways, 5 cm forward and 3° of yaw, let the realistic robot's
//!   estimate drift 2–3 mm sideways per frame where it cannot move). A tracker that sets it
//!   keeps its own.

use std::path::Path;

use activemap_geometry::RobotModel;
use activemap_runtime::dataflow::{NodeImpl, Override};
use activemap_runtime::{
    Dataflow, Diagnostic, Diagnostics, DropPolicy, NodeSpec, config_from_value,
};

/// The `map_lag` of a node of the tracker, mapper or occupancy operator (`None` for any other
/// node, or a config its own check refuses).
fn map_lag(node: &NodeSpec) -> Option<(&'static str, u64)> {
    let NodeImpl::Operator(op) = &node.implementation else {
        return None;
    };
    match op.as_str() {
        "tracker" => config_from_value::<crate::tracker::Config>(&node.config)
            .ok()
            .map(|c| ("tracker", c.map_lag)),
        "mapper" => config_from_value::<crate::mapper::Config>(&node.config)
            .ok()
            .map(|c| ("mapper", c.map_lag)),
        "occupancy" => config_from_value::<crate::occupancy::Config>(&node.config)
            .ok()
            .map(|c| ("occupancy", c.map_lag)),
        // Only the Fisher scorer reads the map (the shortest-path one ignores it).
        "scorer" => fisher_scorer(node).map(|c| ("scorer", c.map_lag)),
        // Only the LLM planner reads the map (its BEV); the FBE one ignores it.
        "planner" => config_from_value::<crate::planner::Config>(&node.config)
            .ok()
            .filter(|c| c.policy == crate::planner::Policy::Llm)
            .map(|c| ("planner", c.map_lag)),
        _ => None,
    }
}

/// The config of a node of the scorer operator in `fisher` mode (`None` otherwise, or for a
/// config its own check refuses).
fn fisher_scorer(node: &NodeSpec) -> Option<crate::scorer::Config> {
    let NodeImpl::Operator(op) = &node.implementation else {
        return None;
    };
    if op != "scorer" {
        return None;
    }
    config_from_value::<crate::scorer::Config>(&node.config)
        .ok()
        .filter(|c| c.mode == crate::scorer::ScorerMode::Fisher)
}

/// The camera (width, height, hfov_deg) of a `sim` node (`None` for any other node, or a
/// config its own check refuses).
fn sim_camera(node: &NodeSpec) -> Option<(u32, u32, f64)> {
    let NodeImpl::Operator(op) = &node.implementation else {
        return None;
    };
    if op != "sim" {
        return None;
    }
    config_from_value::<crate::sim::Config>(&node.config)
        .ok()
        .map(|c| (c.width, c.height, c.hfov_deg))
}

/// The scene of a `sim` or `evaluator` node, with the operator's name (`None` for any other node,
/// or a config its own check refuses).
fn scene(node: &NodeSpec) -> Option<(&'static str, activemap_sim::SceneSpec)> {
    let NodeImpl::Operator(op) = &node.implementation else {
        return None;
    };
    match op.as_str() {
        "sim" => config_from_value::<crate::sim::Config>(&node.config)
            .ok()
            .map(|c| ("sim", c.scene_spec())),
        "evaluator" => config_from_value::<crate::evaluator::Config>(&node.config)
            .ok()
            .map(|c| ("evaluator", c.scene_spec())),
        _ => None,
    }
}

/// A scene's keys as a flow writes them, the ones left at their defaults out:
/// `scene house:3`, `scene room.obj, up_axis -y, floor auto`.
fn describe_scene(spec: &activemap_sim::SceneSpec) -> String {
    let mut out = format!("scene `{}`", spec.scene);
    if let Some(n) = spec.max_rooms {
        out += &format!(", max_rooms {n}");
    }
    if let Some(a) = spec.max_area {
        out += &format!(", max_area {a}");
    }
    if let Some(up) = spec.placement.up_axis {
        out += &format!(", up_axis {up}");
    }
    if let Some(t) = spec.placement.transform {
        out += &format!(", transform {t}");
    }
    if spec.placement.floor != activemap_sim::Floor::default() {
        out += &format!(", floor {}", spec.placement.floor);
    }
    out
}

/// The operators whose config takes a `robot` (the ones [`check_flow`] compares): a tool that
/// changes the robot of a flow (the results benchmark's camera height) sets it on all of them.
pub const ROBOT_OPERATORS: [&str; 7] = [
    "sim",
    "tracker",
    "occupancy",
    "frontier",
    "scorer",
    "follower",
    "evaluator",
];

/// The robot model of a node whose operator takes one (`None` for any other node, or a config
/// its own check refuses). Covers exactly [`ROBOT_OPERATORS`].
fn robot(node: &NodeSpec) -> Option<RobotModel> {
    let NodeImpl::Operator(op) = &node.implementation else {
        return None;
    };
    fn of<C: serde::de::DeserializeOwned>(
        node: &NodeSpec,
        get: impl Fn(C) -> RobotModel,
    ) -> Option<RobotModel> {
        config_from_value::<C>(&node.config).ok().map(get)
    }
    match op.as_str() {
        "sim" => of(node, |c: crate::sim::Config| c.robot),
        "tracker" => of(node, |c: crate::tracker::Config| c.robot),
        "occupancy" => of(node, |c: crate::occupancy::Config| c.robot),
        "frontier" => of(node, |c: crate::frontier::Config| c.robot),
        "scorer" => of(node, |c: crate::scorer::Config| c.robot),
        "follower" => of(node, |c: crate::follower::Config| c.robot),
        "evaluator" => of(node, |c: crate::evaluator::Config| c.robot),
        _ => None,
    }
}

/// The depth model a tracker, mapper or evaluator node renders the map with (`None` for any
/// other node, or a config its own check refuses).
fn depth_model(node: &NodeSpec) -> Option<activemap_splat::DepthModel> {
    let NodeImpl::Operator(op) = &node.implementation else {
        return None;
    };
    let set = match op.as_str() {
        "tracker" => {
            config_from_value::<crate::tracker::Config>(&node.config)
                .ok()?
                .depth_model
        }
        "mapper" => {
            config_from_value::<crate::mapper::Config>(&node.config)
                .ok()?
                .tuning
                .depth_model
        }
        "evaluator" => {
            config_from_value::<crate::evaluator::Config>(&node.config)
                .ok()?
                .depth_model
        }
        _ => return None,
    };
    Some(set.unwrap_or_default())
}

/// One diagnostic per node whose value differs from the first node's, at that node, worded by
/// `message(node, value, first node, first value)`.
fn disagreements<V: PartialEq>(
    flow: &Dataflow,
    values: &[(&NodeSpec, V)],
    diags: &mut Vec<Diagnostic>,
    message: impl Fn(&NodeSpec, &V, &NodeSpec, &V) -> String,
) {
    let Some((first, reference)) = values.first() else {
        return;
    };
    for (node, value) in &values[1..] {
        if value != reference {
            diags.push(Diagnostic {
                file: flow.file.clone(),
                loc: node.loc,
                message: message(node, value, first, reference),
            });
        }
    }
}

/// Every cross-node problem of a validated flow, one diagnostic each, at the consumer node.
pub fn check_flow(flow: &Dataflow) -> Result<(), Diagnostics> {
    let mut diags = Vec::new();
    let robots: Vec<(&NodeSpec, RobotModel)> = flow
        .nodes
        .iter()
        .filter_map(|n| robot(n).map(|r| (n, r)))
        .collect();
    disagreements(flow, &robots, &mut diags, |node, r, first, reference| {
        format!(
            "robot mismatch: node `{}` has robot {r:?} but node `{}` has {reference:?}; every node that takes a `robot` config must describe the same robot (a node without one has the default)",
            node.id, first.id
        )
    });
    let models: Vec<(&NodeSpec, activemap_splat::DepthModel)> = flow
        .nodes
        .iter()
        .filter_map(|n| depth_model(n).map(|m| (n, m)))
        .collect();
    disagreements(flow, &models, &mut diags, |node, m, first, reference| {
        format!(
            "depth model mismatch: node `{}` renders the map with depth_model {m:?} but node `{}` with {reference:?}; the mapper's `tuning.depth_model`, the tracker's and the evaluator's `depth_model` must agree (a node without one has the default, plane)",
            node.id, first.id
        )
    });
    let scenes: Vec<(&NodeSpec, (&str, activemap_sim::SceneSpec))> = flow
        .nodes
        .iter()
        .filter_map(|n| scene(n).map(|s| (n, s)))
        .collect();
    if let Some((first, (first_op, reference))) = scenes.iter().find(|(_, (op, _))| *op == "sim") {
        for (node, (op, spec)) in &scenes {
            if *op == "evaluator" && spec != reference {
                diags.push(Diagnostic {
                    file: flow.file.clone(),
                    loc: node.loc,
                    message: format!(
                        "scene mismatch: node `{}` (evaluator) has {} but node `{}` ({first_op}) runs {}; the evaluator must be given the simulator's scene keys (e.g. `--set sim.scene=X --set {}.scene=X`)",
                        node.id,
                        describe_scene(spec),
                        first.id,
                        describe_scene(reference),
                        node.id
                    ),
                });
            }
        }
    }
    let sims: Vec<(&NodeSpec, (u32, u32, f64))> = flow
        .nodes
        .iter()
        .filter_map(|n| sim_camera(n).map(|c| (n, c)))
        .collect();
    for node in &flow.nodes {
        let Some(scorer) = fisher_scorer(node) else {
            continue;
        };
        let c = scorer.camera;
        for (sim, (w, h, fov)) in &sims {
            if (c.width, c.height, c.hfov_deg) != (*w, *h, *fov) {
                diags.push(Diagnostic {
                    file: flow.file.clone(),
                    loc: node.loc,
                    message: format!(
                        "camera mismatch: node `{}` (scorer, fisher mode) has camera {}×{} at {}° but node `{}` (sim) renders {w}×{h} at {fov}°; set the scorer's `camera: {{ width, height, hfov_deg }}` to the simulator's (the scorer never sees a frame)",
                        node.id, c.width, c.height, c.hfov_deg, sim.id
                    ),
                });
            }
        }
        match node.inputs.iter().find(|i| i.name == "map") {
            None => diags.push(Diagnostic {
                file: flow.file.clone(),
                loc: node.loc,
                message: format!(
                    "node `{}` (scorer) is in fisher mode but has no `map` input; wire it to the mapper's map (e.g. `map: {{ source: mapper/map, queue_size: 4, drop: block }}`)",
                    node.id
                ),
            }),
            Some(map) if map.drop != DropPolicy::Block => diags.push(Diagnostic {
                file: flow.file.clone(),
                loc: map.loc,
                message: format!(
                    "node `{}` (scorer, fisher mode): its `map` input must be `drop: block`; a dropped snapshot is one a goal waits for forever",
                    node.id
                ),
            }),
            Some(_) => {}
        }
    }
    // The LLM planner draws its BEV from the lagged map snapshot and waits for it.
    for node in flow
        .nodes
        .iter()
        .filter(|n| matches!(map_lag(n), Some(("planner", _))))
    {
        let message = match node.inputs.iter().find(|i| i.name == "map") {
            None => Some((
                node.loc,
                format!(
                    "node `{}` (planner) has policy llm but no `map` input; wire it to the mapper's map (e.g. `map: {{ source: mapper/map, queue_size: 4, drop: block }}`): its bird's-eye view is drawn from it",
                    node.id
                ),
            )),
            Some(map) if map.drop != DropPolicy::Block => Some((
                map.loc,
                format!(
                    "node `{}` (planner, policy llm): its `map` input must be `drop: block`; a dropped snapshot is one a decision waits for forever",
                    node.id
                ),
            )),
            Some(_) => None,
        };
        if let Some((loc, message)) = message {
            diags.push(Diagnostic {
                file: flow.file.clone(),
                loc,
                message,
            });
        }
    }
    for consumer in &flow.nodes {
        let Some((consumer_op, consumer_lag)) = map_lag(consumer) else {
            continue;
        };
        if consumer_op == "mapper" {
            continue;
        }
        let mut mappers: Vec<&str> = consumer
            .inputs
            .iter()
            .map(|i| i.source_node.as_str())
            .collect();
        mappers.dedup();
        for source in mappers {
            let Some(mapper) = flow.node(source) else {
                continue;
            };
            let Some(("mapper", mapper_lag)) = map_lag(mapper) else {
                continue;
            };
            if mapper_lag != consumer_lag {
                diags.push(Diagnostic {
                    file: flow.file.clone(),
                    loc: consumer.loc,
                    message: format!(
                        "map_lag mismatch: node `{}` ({consumer_op}) has map_lag {consumer_lag} but node `{}` (mapper), whose map it reads, has map_lag {mapper_lag}; set the same map_lag on the mapper and every node reading its map, else the loop waits for snapshots that never come",
                        consumer.id, mapper.id
                    ),
                });
            }
        }
    }
    if diags.is_empty() {
        Ok(())
    } else {
        Err(Diagnostics(diags))
    }
}

/// The `--set` overrides one node's config implies for another's (see the module doc), for each
/// tracker that reads its `rgbd` from a `sim` node: `TRACKER.dense.depth_sigma_z2=C` when it
/// leaves that unset and the simulator's depth noise grows as C·z², C > 0; and
/// `TRACKER.dense.motion_sigmas={...}` ([`crate::tracker::motion_sigmas_for`]) when it leaves
/// that unset, takes the commanded action as its prior and the simulator's actions are noisy.
/// Empty when nothing is implied.
pub fn implied_overrides(flow: &Dataflow) -> Vec<Override> {
    let sim_config = |id: &str| {
        let node = flow.node(id)?;
        let NodeImpl::Operator(op) = &node.implementation else {
            return None;
        };
        (op == "sim")
            .then(|| config_from_value::<crate::sim::Config>(&node.config).ok())
            .flatten()
    };
    let mut implied = Vec::new();
    for node in &flow.nodes {
        let NodeImpl::Operator(op) = &node.implementation else {
            continue;
        };
        if op != "tracker" {
            continue;
        }
        let Ok(tracker) = config_from_value::<crate::tracker::Config>(&node.config) else {
            continue;
        };
        let Some(sim) = node
            .inputs
            .iter()
            .find(|i| i.name == "rgbd")
            .and_then(|i| sim_config(&i.source_node))
        else {
            continue;
        };
        let z2 = sim.noise.depth.sigma_z2;
        if tracker.dense.depth_sigma_z2.is_none() && z2 > 0.0 {
            let text = format!("{}.dense.depth_sigma_z2={z2}", node.id);
            implied.push(Override::parse(&text).expect("a node id, keys and a number"));
        }
        if tracker.dense.motion_sigmas.is_none()
            && tracker.motion_prior == crate::tracker::Prior::Action
            && let Some(sigmas) =
                crate::tracker::motion_sigmas_for(&sim.noise.actuation, &sim.robot)
        {
            let text = format!("{}.dense.motion_sigmas={}", node.id, sigmas.to_yaml());
            implied.push(Override::parse(&text).expect("a node id, keys and a YAML mapping"));
        }
    }
    implied
}

/// Reads and validates a dataflow file against the operator catalog, then [`check_flow`].
pub fn load(path: &Path) -> Result<Dataflow, Diagnostics> {
    load_with(path, &[])
}

/// As [`load`], with `--set` overrides of node configs applied first (see [`Override`]), then
/// the [`implied_overrides`]; a cross-node problem then says which overrides were in force.
pub fn load_with(path: &Path, overrides: &[Override]) -> Result<Dataflow, Diagnostics> {
    let catalog = crate::catalog();
    let mut flow = Dataflow::load_with(path, &catalog, overrides)?;
    let implied = implied_overrides(&flow);
    if !implied.is_empty() {
        flow = Dataflow::load_with(path, &catalog, &[overrides, &implied].concat())?;
    }
    let overrides = [overrides, &implied].concat();
    check_flow(&flow).map_err(|Diagnostics(mut diags)| {
        if !overrides.is_empty() {
            let labels: Vec<String> = overrides.iter().map(Override::label).collect();
            for d in &mut diags {
                d.message.push_str(&format!(" (with {})", labels.join(" ")));
            }
        }
        Diagnostics(diags)
    })?;
    Ok(flow)
}

/// As [`load`], for dataflow text (`file` only names it in messages).
pub fn parse(file: &str, source: &str, base_dir: &Path) -> Result<Dataflow, Diagnostics> {
    let catalog = crate::catalog();
    let mut flow = Dataflow::parse(file, source, base_dir.to_path_buf(), &catalog)?;
    let implied = implied_overrides(&flow);
    if !implied.is_empty() {
        flow = Dataflow::parse_with(file, source, base_dir.to_path_buf(), &catalog, &implied)?;
    }
    check_flow(&flow)?;
    Ok(flow)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn reference() -> String {
        let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("..");
        std::fs::read_to_string(root.join("dataflow.yaml")).unwrap()
    }

    /// The tracker's depth σ(z) growth follows the simulator's depth noise when it leaves it
    /// unset, through `--set` as through the file; its own value (0 too) is kept, and a
    /// noise-free simulator implies nothing.
    #[test]
    fn the_tracker_takes_the_simulators_depth_noise_unless_it_sets_its_own() {
        let z2 = |flow: &Dataflow| {
            crate::single_node_config::<crate::tracker::Config>(flow, "tracker")
                .unwrap()
                .dense
                .depth_sigma_z2
        };
        let realistic = activemap_sim::NoisePreset::Realistic
            .config()
            .depth
            .sigma_z2;
        assert!(realistic > 0.0);
        let flow = parse("plain.yaml", &reference(), Path::new(".")).unwrap();
        assert!(implied_overrides(&flow).is_empty());
        assert_eq!(z2(&flow), None);
        // In the file.
        let noisy = reference().replace("lockstep: true,", "lockstep: true, noise: realistic,");
        assert_ne!(noisy, reference());
        let flow = parse("noisy.yaml", &noisy, Path::new(".")).unwrap();
        assert_eq!(z2(&flow), Some(realistic));
        // The effective text (run folder, recording) holds it and reads back the same.
        assert!(
            flow.source.contains("--set tracker.dense.depth_sigma_z2="),
            "{}",
            flow.source
        );
        let again = parse("again.yaml", &flow.source, Path::new(".")).unwrap();
        assert_eq!(z2(&again), Some(realistic));
        assert!(implied_overrides(&again).is_empty());
        // Through `--set`, as `activemap run --set sim.noise=realistic` gives it.
        let dir = tempfile::tempdir().unwrap();
        let file = dir.path().join("flow.yaml");
        std::fs::write(&file, reference()).unwrap();
        let set = |text: &str| Override::parse(text).unwrap();
        let flow = load_with(&file, &[set("sim.noise=realistic")]).unwrap();
        assert_eq!(z2(&flow), Some(realistic));
        // A custom coefficient is followed; the tracker's own value, 0 included, is kept.
        let flow = load_with(&file, &[set("sim.noise={ depth: { sigma_z2: 0.002 } }")]).unwrap();
        assert_eq!(z2(&flow), Some(0.002));
        for own in ["0", "0.001"] {
            let flow = load_with(
                &file,
                &[
                    set("sim.noise=realistic"),
                    set(&format!("tracker.dense.depth_sigma_z2={own}")),
                ],
            )
            .unwrap();
            assert_eq!(z2(&flow), Some(own.parse().unwrap()));
        }
        // Noise without depth growth (actuation only) implies nothing.
        let flow = load_with(&file, &[set("sim.noise={ actuation: realistic }")]).unwrap();
        assert_eq!(z2(&flow), None);
    }

    /// The tracker's motion prior follows the simulator's actuation noise when it leaves
    /// `dense.motion_sigmas` unset and its prior is the action: the realistic preset gives 2 mm
    /// sideways, 2 × 2.8 mm forward and 2 × 0.66° of yaw, read back the same from the effective
    /// text; exact actions, the tracker's own σ or another prior imply nothing.
    #[test]
    fn the_tracker_takes_the_simulators_actuation_noise_unless_it_sets_its_own() {
        let sigmas = |flow: &Dataflow| {
            let c = crate::single_node_config::<crate::tracker::Config>(flow, "tracker").unwrap();
            let s = c.tracking_config().unwrap().tracker.dense.prior_axis_sigmas;
            (c.dense.motion_sigmas, s)
        };
        let close = |a: f64, b: f64| (a - b).abs() < 1e-12;
        let dir = tempfile::tempdir().unwrap();
        let file = dir.path().join("flow.yaml");
        std::fs::write(&file, reference()).unwrap();
        let set = |text: &str| Override::parse(text).unwrap();
        let (none, default) = sigmas(&load_with(&file, &[]).unwrap());
        assert_eq!(none, None);
        let flow = load_with(&file, &[set("sim.noise=realistic")]).unwrap();
        let (given, axes) = sigmas(&flow);
        assert!(given.is_some());
        assert!(close(axes[0], 0.002), "{axes:?}");
        assert!(close(axes[1], default[1]));
        assert!(close(axes[2], 2.0 * 0.056 * 0.05), "{axes:?}");
        assert!(close(axes[3], default[3]) && close(axes[5], default[5]));
        assert!(close(axes[4], (2.0 * 0.66f64).to_radians()), "{axes:?}");
        let again = parse("again.yaml", &flow.source, Path::new(".")).unwrap();
        assert_eq!(sigmas(&again), (given, axes));
        assert!(implied_overrides(&again).is_empty());
        // Actuation noise alone implies the prior (and not the depth model); depth noise alone
        // does not.
        let flow = load_with(&file, &[set("sim.noise={ actuation: realistic }")]).unwrap();
        assert_eq!(sigmas(&flow).0, given);
        let flow = load_with(&file, &[set("sim.noise={ depth: realistic }")]).unwrap();
        assert_eq!(sigmas(&flow).0, None);
        // The tracker's own σ is kept; a prior other than the action implies nothing.
        let own = load_with(
            &file,
            &[
                set("sim.noise=realistic"),
                set("tracker.dense.motion_sigmas={ lateral_m: 0.004 }"),
            ],
        )
        .unwrap();
        let (own, axes) = sigmas(&own);
        assert_eq!(own.and_then(|o| o.forward_m), None);
        assert!(close(axes[0], 0.004) && close(axes[2], default[2]));
        let velocity = load_with(
            &file,
            &[
                set("sim.noise=realistic"),
                set("tracker.motion_prior=constant_velocity"),
            ],
        )
        .unwrap();
        assert_eq!(sigmas(&velocity).0, None);
    }

    /// A robot override on one node only is refused, naming that node and the first one.
    #[test]
    fn a_robot_that_differs_between_nodes_is_refused() {
        let text = reference().replace(
            "config: { mode: shortest }",
            "config: { mode: shortest, robot: { radius_m: 0.2 } }",
        );
        assert_ne!(text, reference());
        let e = parse("robot.yaml", &text, Path::new(".")).unwrap_err();
        let msg = e.to_string();
        assert!(
            msg.contains("robot mismatch") && msg.contains("`scorer`") && msg.contains("`sim`"),
            "{msg}"
        );
        // The same override on every robot node is accepted.
        let all = reference()
            .replace("lockstep: true,", "lockstep: true, robot: { radius_m: 0.2 },")
            .replace("config: { mode: shortest }", "config: { mode: shortest, robot: { radius_m: 0.2 } }")
            .replace("config: { motion_prior: action,", "config: { robot: { radius_m: 0.2 }, motion_prior: action,")
            .replace("config: { cell_size: 0.05,", "config: { robot: { radius_m: 0.2 }, cell_size: 0.05,")
            .replace("config: { scene: \"house:7\" }", "config: { scene: \"house:7\", robot: { radius_m: 0.2 } }")
            .replace("  - id: frontier\n    operator: frontier\n", "  - id: frontier\n    operator: frontier\n    config: { robot: { radius_m: 0.2 } }\n")
            .replace("  - id: follower\n    operator: follower\n", "  - id: follower\n    operator: follower\n    config: { robot: { radius_m: 0.2 } }\n");
        parse("robots.yaml", &all, Path::new(".")).unwrap();
    }

    /// A tracker that renders the map under another depth model than the mapper fitted it
    /// with is refused; the same model on the mapper, tracker and evaluator is accepted.
    #[test]
    fn a_depth_model_that_differs_between_nodes_is_refused() {
        let tracker = reference().replace(
            "config: { motion_prior: action,",
            "config: { depth_model: centre, motion_prior: action,",
        );
        assert_ne!(tracker, reference());
        let msg = parse("depth.yaml", &tracker, Path::new("."))
            .unwrap_err()
            .to_string();
        assert!(
            msg.contains("depth model mismatch")
                && msg.contains("`tracker`")
                && msg.contains("`mapper`"),
            "{msg}"
        );
        let all = tracker
            .replace(
                "config: { map_lag: 10, keyframe_min_interval: 5 }",
                "config: { map_lag: 10, keyframe_min_interval: 5, tuning: { depth_model: centre } }",
            )
            .replace(
                "config: { scene: \"house:7\" }",
                "config: { scene: \"house:7\", depth_model: centre }",
            );
        parse("depths.yaml", &all, Path::new(".")).unwrap();
    }

    /// `--set sim.scene=…` without the evaluator's is refused, naming both nodes and the fix.
    #[test]
    fn an_evaluator_scene_other_than_the_simulators_is_refused() {
        let text = reference().replace(
            "config: { scene: \"house:7\" }",
            "config: { scene: \"house:3\" }",
        );
        assert_ne!(text, reference());
        let e = parse("scene.yaml", &text, Path::new(".")).unwrap_err();
        let msg = e.to_string();
        assert!(
            msg.contains("scene mismatch")
                && msg.contains("`evaluator`")
                && msg.contains("`sim`")
                && msg.contains("house:3")
                && msg.contains("evaluator.scene=X"),
            "{msg}"
        );
    }

    fn fisher_flow() -> String {
        let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("..");
        std::fs::read_to_string(root.join("flows/fisher.yaml")).unwrap()
    }

    /// An LLM planner must read the mapper's map, blocking, at the mapper's lag.
    #[test]
    fn the_llm_planner_must_read_the_lagged_map() {
        let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("..");
        let flow = std::fs::read_to_string(root.join("flows/llm.yaml")).unwrap();
        parse("llm.yaml", &flow, Path::new(".")).unwrap();
        let input = "      map: { source: mapper/map, queue_size: 4, drop: block }\n      grid: { source: occupancy/grid, queue_size: 4, drop: block }\n      regions: { source: frontier/regions, drop: block }\n      pose: { source: tracker/pose, drop: block }\n      replan";
        assert!(flow.contains(input), "the planner's inputs moved");
        let no_map = flow.replacen(
            "      map: { source: mapper/map, queue_size: 4, drop: block }\n      grid: { source: occupancy/grid, queue_size: 4, drop: block }\n      regions: { source: frontier/regions, drop: block }\n      pose: { source: tracker/pose, drop: block }\n      replan",
            "      grid: { source: occupancy/grid, queue_size: 4, drop: block }\n      regions: { source: frontier/regions, drop: block }\n      pose: { source: tracker/pose, drop: block }\n      replan",
            1,
        );
        let msg = parse("nomap.yaml", &no_map, Path::new("."))
            .unwrap_err()
            .to_string();
        assert!(
            msg.contains("`planner`") && msg.contains("no `map` input"),
            "{msg}"
        );
        let lag = flow.replacen(
            "      map_lag: 10\n      llm:",
            "      map_lag: 3\n      llm:",
            1,
        );
        assert_ne!(lag, flow);
        let msg = parse("lag.yaml", &lag, Path::new("."))
            .unwrap_err()
            .to_string();
        assert!(
            msg.contains("map_lag mismatch") && msg.contains("`planner`"),
            "{msg}"
        );
    }

    /// The named Fisher flows pass; a Fisher scorer whose camera is not the simulator's, whose
    /// map lag is not the mapper's, whose map input may drop snapshots or that reads no map
    /// is refused, naming the scorer (and the other node).
    #[test]
    fn the_fisher_scorer_must_match_the_sim_camera_and_read_the_lagged_map() {
        let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("..");
        for name in [
            "flows/fisher.yaml",
            "flows/fisher_eig_only.yaml",
            "flows/llm.yaml",
        ] {
            let text = std::fs::read_to_string(root.join(name)).unwrap();
            parse(name, &text, Path::new(".")).unwrap();
        }
        let camera = fisher_flow().replace(
            "camera: { width: 160, height: 160, hfov_deg: 90 }",
            "camera: { width: 64, height: 64, hfov_deg: 90 }",
        );
        assert_ne!(camera, fisher_flow());
        let msg = parse("camera.yaml", &camera, Path::new("."))
            .unwrap_err()
            .to_string();
        assert!(
            msg.contains("camera mismatch")
                && msg.contains("`scorer`")
                && msg.contains("64×64")
                && msg.contains("`sim`")
                && msg.contains("160×160"),
            "{msg}"
        );
        // In shortest mode the camera is not used, so it is not checked.
        let shortest = camera.replace("mode: fisher", "mode: shortest");
        parse("shortest.yaml", &shortest, Path::new(".")).unwrap();

        let lag = fisher_flow().replace(
            "mode: fisher\n      map_lag: 10",
            "mode: fisher\n      map_lag: 3",
        );
        assert_ne!(lag, fisher_flow());
        let msg = parse("lag.yaml", &lag, Path::new("."))
            .unwrap_err()
            .to_string();
        assert!(
            msg.contains("map_lag mismatch")
                && msg.contains("node `scorer` (scorer) has map_lag 3"),
            "{msg}"
        );

        let map_input = "      map: { source: mapper/map, queue_size: 4, drop: block }\n      grid: { source: occupancy/grid, queue_size: 4, drop: block }\n      pose: { source: tracker/pose, drop: block }\n      regions";
        assert!(fisher_flow().contains(map_input));
        let dropping = fisher_flow().replace(
            map_input,
            &map_input.replace(
                "queue_size: 4, drop: block }\n      grid",
                "queue_size: 4 }\n      grid",
            ),
        );
        let msg = parse("drop.yaml", &dropping, Path::new("."))
            .unwrap_err()
            .to_string();
        assert!(msg.contains("`map` input must be `drop: block`"), "{msg}");
        let no_map = fisher_flow().replace(
            map_input,
            map_input.trim_start_matches(
                "      map: { source: mapper/map, queue_size: 4, drop: block }\n",
            ),
        );
        let msg = parse("nomap.yaml", &no_map, Path::new("."))
            .unwrap_err()
            .to_string();
        assert!(
            msg.contains("node `scorer` (scorer) is in fisher mode but has no `map` input"),
            "{msg}"
        );
    }

    #[test]
    fn the_reference_flow_passes() {
        parse("dataflow.yaml", &reference(), Path::new(".")).unwrap();
    }

    /// A tracker whose lag differs from the mapper's is refused, naming both nodes and both
    /// values; so is an occupancy node left at the default lag.
    #[test]
    fn mismatching_map_lags_are_refused_naming_both_nodes() {
        let text = reference()
            .replace(
                "config: { motion_prior: action, map_lag: 10 }",
                "config: { motion_prior: action, map_lag: 3 }",
            )
            .replace(
                "config: { cell_size: 0.05, map_lag: 10 }",
                "config: { cell_size: 0.05 }",
            );
        assert_ne!(text, reference());
        let e = parse("lags.yaml", &text, Path::new(".")).unwrap_err();
        assert_eq!(e.0.len(), 2, "{e}");
        let tracker = e.0[0].to_string();
        for part in [
            "lags.yaml:",
            "node `tracker`",
            "map_lag 3",
            "node `mapper`",
            "map_lag 10",
        ] {
            assert!(tracker.contains(part), "{part} in {tracker}");
        }
        let occupancy = e.0[1].to_string();
        assert!(
            occupancy.contains("node `occupancy`")
                && occupancy.contains("map_lag 0")
                && occupancy.contains("map_lag 10"),
            "{occupancy}"
        );
        // The location is the consumer's declaration.
        assert!(e.0[0].loc < e.0[1].loc);
    }
}
