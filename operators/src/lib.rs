//! The built-in dataflow operators and their registry.
//!
//! Every operator has a descriptor (ports, types, config check: what `activemap validate` needs)
//! and, once built, an implementation ([`OperatorImpl`]). Operators of the pipeline that are not
//! built yet are registered with their descriptor only ([`planned`]), so the reference
//! `dataflow.yaml` validates; `activemap run` refuses to launch them with a clear message.
//!
//! Checks that span several nodes (the mapper's `map_lag` against its consumers') are in
//! [`checks`]; [`checks::load`] validates a file with both.
//!
//! Adding an operator: write a module with a type implementing
//! [`activemap_runtime::Operator`], its ports declared once with [`activemap_runtime::ports!`]
//! (modules `inputs` and `outputs`, used by both the descriptor and the dispatch) and a
//! `pub fn registered() -> Registered`, then add one line to [`registry`] (and drop its entry
//! from [`planned`]).
//!
//! What the recorder does with this crate's messages it learns from here: the Gaussian maps'
//! column-wise codec ([`register_recording_codecs`], which a program calls before it records or
//! reads a recording).

use activemap_runtime::{OperatorDescriptor, OperatorImpl};

pub use map_columns::register_recording_codecs;

pub mod checks;
pub mod convert;
pub mod evaluator;
pub mod follower;
pub mod frontier;
pub mod join;
pub mod map_columns;
pub mod mapper;
pub mod occupancy;
pub mod planned;
pub mod planner;
pub mod scorer;
pub mod sim;
pub mod testing;
pub mod tracker;

/// A registry entry: what the validator knows, and how to run it (None while not built).
#[derive(Clone, Copy)]
pub struct Registered {
    /// Ports, types and config check.
    pub descriptor: OperatorDescriptor,
    /// Entry points, or None for a planned operator.
    pub implementation: Option<OperatorImpl>,
}

/// Every operator known to this build.
pub fn registry() -> Vec<Registered> {
    let mut all = vec![
        testing::counter_source::registered(),
        testing::doubler::registered(),
        testing::frame_source::registered(),
        testing::frame_checker::registered(),
        sim::registered(),
        tracker::registered(),
        mapper::registered(),
        occupancy::registered(),
        frontier::registered(),
        planner::registered(),
        scorer::registered(),
        follower::registered(),
        evaluator::registered(),
    ];
    all.extend(planned::registered());
    all
}

/// The descriptors, for validation.
pub fn catalog() -> Vec<OperatorDescriptor> {
    registry().into_iter().map(|r| r.descriptor).collect()
}

/// The config a node of operator `operator` runs with when `activemap replay` re-runs it
/// alone from `recording`: nodes that talk to the outside world serve the recorded answers
/// instead (the LLM planner's `recorded` provider, [`planner::replay_config`]); any other
/// config is returned as it is.
pub fn replay_config(
    operator: &str,
    config: &serde_json::Value,
    recording: &std::path::Path,
    node: &str,
) -> serde_json::Value {
    match operator {
        "planner" => planner::replay_config(config, recording, node),
        _ => config.clone(),
    }
}

/// The config of a dataflow's single node of operator `operator` (an error names a missing,
/// doubled or refused one): what the benchmarks that run one part of a flow in process read.
pub fn single_node_config<C: serde::de::DeserializeOwned>(
    flow: &activemap_runtime::Dataflow,
    operator: &str,
) -> anyhow::Result<C> {
    let mut nodes = flow.nodes.iter().filter(
        |n| matches!(&n.implementation, activemap_runtime::dataflow::NodeImpl::Operator(o) if o == operator),
    );
    match (nodes.next(), nodes.next()) {
        (Some(node), None) => activemap_runtime::config_from_value(&node.config)
            .map_err(|e| anyhow::anyhow!("node `{}` ({operator}): {e}", node.id)),
        (None, _) => anyhow::bail!("the dataflow has no `{operator}` node"),
        (Some(a), Some(b)) => anyhow::bail!(
            "the dataflow has two `{operator}` nodes (`{}` and `{}`)",
            a.id,
            b.id
        ),
    }
}

/// The registry entry of operator `name`.
pub fn find(name: &str) -> Option<Registered> {
    registry().into_iter().find(|r| r.descriptor.name == name)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn operator_names_are_unique() {
        let mut names: Vec<_> = super::catalog().iter().map(|d| d.name).collect();
        let n = names.len();
        names.sort();
        names.dedup();
        assert_eq!(names.len(), n);
    }

    /// Every registered operator declares each port once (its `inputs`/`outputs` modules), so
    /// dispatch by name is unambiguous; a duplicate would fail here naming the operator.
    #[test]
    fn every_operator_declares_each_port_once() {
        for r in registry() {
            r.descriptor.check_ports().unwrap();
        }
        const TWICE: &[activemap_runtime::PortSpec] =
            &[mapper::inputs::ALL[0], mapper::inputs::ALL[0]];
        let twice = OperatorDescriptor {
            inputs: TWICE,
            ..mapper::registered().descriptor
        };
        let e = twice.check_ports().unwrap_err();
        assert!(
            e.contains("`mapper`") && e.contains("`rgbd`") && e.contains("twice"),
            "{e}"
        );
    }
}
