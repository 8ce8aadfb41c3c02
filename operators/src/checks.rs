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

use std::path::Path;

use activemap_geometry::RobotModel;
use activemap_runtime::dataflow::NodeImpl;
use activemap_runtime::{Dataflow, Diagnostic, Diagnostics, NodeSpec, catalog::config_from_value};

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
        _ => None,
    }
}

/// The robot model of a node whose operator takes one (`None` for any other node, or a config
/// its own check refuses).
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

/// Every cross-node problem of a validated flow, one diagnostic each, at the consumer node.
pub fn check_flow(flow: &Dataflow) -> Result<(), Diagnostics> {
    let mut diags = Vec::new();
    let robots: Vec<(&NodeSpec, RobotModel)> = flow
        .nodes
        .iter()
        .filter_map(|n| robot(n).map(|r| (n, r)))
        .collect();
    if let Some((first, reference)) = robots.first() {
        for (node, r) in &robots[1..] {
            if r != reference {
                diags.push(Diagnostic {
                    file: flow.file.clone(),
                    loc: node.loc,
                    message: format!(
                        "robot mismatch: node `{}` has robot {r:?} but node `{}` has {reference:?}; every node that takes a `robot` config must describe the same robot (a node without one has the default)",
                        node.id, first.id
                    ),
                });
            }
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

/// Reads and validates a dataflow file against the operator catalog, then [`check_flow`].
pub fn load(path: &Path) -> Result<Dataflow, Diagnostics> {
    let flow = Dataflow::load(path, &crate::catalog())?;
    check_flow(&flow)?;
    Ok(flow)
}

/// As [`load`], for dataflow text (`file` only names it in messages).
pub fn parse(file: &str, source: &str, base_dir: &Path) -> Result<Dataflow, Diagnostics> {
    let flow = Dataflow::parse(file, source, base_dir.to_path_buf(), &crate::catalog())?;
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
