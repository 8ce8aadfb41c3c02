//! Render a dataflow as a Mermaid or Graphviz DOT graph (nodes, and one edge per input labelled
//! `output → input : Kind`).

use crate::dataflow::{Dataflow, NodeImpl};

/// Output format of [`render`].
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum GraphFormat {
    /// Mermaid `flowchart LR`.
    Mermaid,
    /// Graphviz DOT.
    Dot,
}

fn label(n: &crate::dataflow::NodeSpec) -> String {
    match &n.implementation {
        NodeImpl::Operator(op) => format!("{}\\n[{op}]", n.id),
        NodeImpl::Path { path, .. } => format!("{}\\n({path})", n.id),
    }
}

/// Render `flow` in `format`.
pub fn render(flow: &Dataflow, format: GraphFormat) -> String {
    let mut out = String::new();
    match format {
        GraphFormat::Mermaid => {
            out.push_str("flowchart LR\n");
            for n in &flow.nodes {
                out.push_str(&format!(
                    "  {}[\"{}\"]\n",
                    n.id,
                    label(n).replace("\\n", "<br/>")
                ));
            }
            for n in &flow.nodes {
                for i in &n.inputs {
                    out.push_str(&format!(
                        "  {} -- \"{} → {} : {}\" --> {}\n",
                        i.source_node,
                        i.source_output,
                        i.name,
                        i.kind.name(),
                        n.id
                    ));
                }
            }
        }
        GraphFormat::Dot => {
            out.push_str("digraph dataflow {\n  rankdir=LR;\n  node [shape=box];\n");
            for n in &flow.nodes {
                out.push_str(&format!("  \"{}\" [label=\"{}\"];\n", n.id, label(n)));
            }
            for n in &flow.nodes {
                for i in &n.inputs {
                    out.push_str(&format!(
                        "  \"{}\" -> \"{}\" [label=\"{} → {} : {}\"];\n",
                        i.source_node,
                        n.id,
                        i.source_output,
                        i.name,
                        i.kind.name()
                    ));
                }
            }
            out.push_str("}\n");
        }
    }
    out
}
