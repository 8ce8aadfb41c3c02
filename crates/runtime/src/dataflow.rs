//! The dataflow file: model, parsing and validation (every error with `file:line:column`).
//!
//! ```yaml
//! machines:                       # optional; default: one machine `local` on loopback
//!   - id: a
//!     listen: [tcp/127.0.0.2:7447] # this machine's Zenoh router endpoints
//!     connect: [tcp/127.0.0.3:7447]
//!     tls: { root_ca_certificate: ca.pem }   # passed through to Zenoh's transport/link/tls
//! nodes:
//!   - id: source
//!     operator: counter_source    # a built-in operator, or `path: ./my_exe` for an external one
//!     outputs: [count]            # built-ins: optional (all declared ports); external: `{id, type}`
//!     config: { count: 10 }
//!     timers: { tick: 10ms }      # timer events, period in ms or s
//!     deploy: { machine: a }
//!     restart: never              # never | on-failure | { on-failure: 3 }
//!   - id: doubler
//!     operator: doubler
//!     inputs:
//!       value: source/count       # short form, or { source: source/count, queue_size: 4, drop: block }
//! ```
//! Cycles are legal (the pipeline is a loop).

use std::collections::{BTreeMap, HashMap};
use std::fmt;
use std::path::{Path, PathBuf};
use std::time::Duration;

use activemap_schemas::MessageKind;

use crate::OperatorDescriptor;
use crate::yaml::{self, Loc, Node};

mod overrides;
pub use overrides::Override;

/// Name of the implicit machine when a file declares none.
pub const DEFAULT_MACHINE: &str = "local";

/// One validation problem with its location.
#[derive(Debug, Clone, PartialEq)]
pub struct Diagnostic {
    /// File the problem is in.
    pub file: String,
    /// Where.
    pub loc: Loc,
    /// What.
    pub message: String,
}

impl fmt::Display for Diagnostic {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        // Line 0: a problem of the whole file, or of a `--set` override (named in `file`).
        if self.loc.line == 0 {
            write!(f, "{}: error: {}", self.file, self.message)
        } else {
            write!(f, "{}:{}: error: {}", self.file, self.loc, self.message)
        }
    }
}

/// All problems found in a dataflow file.
#[derive(Debug, Clone, PartialEq)]
pub struct Diagnostics(pub Vec<Diagnostic>);

impl std::error::Error for Diagnostics {}

impl fmt::Display for Diagnostics {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        for (i, d) in self.0.iter().enumerate() {
            if i > 0 {
                writeln!(f)?;
            }
            write!(f, "{d}")?;
        }
        Ok(())
    }
}

/// What happens to a full input queue.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
pub enum DropPolicy {
    /// The newest message replaces the oldest (latency first; default).
    DropOldest,
    /// The producer waits until the consumer has room (back-pressure; nothing lost).
    Block,
}

/// What the launcher does when a node's process fails.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
pub enum RestartPolicy {
    /// Stop the whole flow (default).
    Never,
    /// Restart the node, at most this many times, then stop the flow.
    OnFailure(u32),
}

/// How a node is implemented.
#[derive(Debug, Clone, PartialEq)]
pub enum NodeImpl {
    /// A built-in operator, run as an `activemap node` subprocess.
    Operator(String),
    /// An external executable and its arguments.
    Path {
        /// Executable, relative to the dataflow file's folder.
        path: String,
        /// Arguments.
        args: Vec<String>,
    },
}

/// One input of a node: where it comes from and how it is queued.
#[derive(Debug, Clone, PartialEq)]
pub struct InputSpec {
    /// Input port name.
    pub name: String,
    /// Producing node id.
    pub source_node: String,
    /// Producing output name.
    pub source_output: String,
    /// Message kind (resolved from the producer).
    pub kind: MessageKind,
    /// Queue depth (≥ 1).
    pub queue_size: usize,
    /// Full-queue policy.
    pub drop: DropPolicy,
    /// Where it is declared.
    pub loc: Loc,
}

impl InputSpec {
    /// The topic it reads, `node/output` (a recording's channel name).
    pub fn source_topic(&self) -> String {
        format!("{}/{}", self.source_node, self.source_output)
    }
}

/// One output of a node.
#[derive(Debug, Clone, PartialEq)]
pub struct OutputSpec {
    /// Output name.
    pub name: String,
    /// Message kind.
    pub kind: MessageKind,
}

/// A periodic timer of a node.
#[derive(Debug, Clone, PartialEq)]
pub struct TimerSpec {
    /// Timer name, delivered with each tick.
    pub name: String,
    /// Period.
    pub period: Duration,
}

/// A validated node.
#[derive(Debug, Clone, PartialEq)]
pub struct NodeSpec {
    /// Unique id.
    pub id: String,
    /// Implementation.
    pub implementation: NodeImpl,
    /// Inputs.
    pub inputs: Vec<InputSpec>,
    /// Outputs.
    pub outputs: Vec<OutputSpec>,
    /// Operator config (JSON form of the YAML `config:` value; null when absent).
    pub config: serde_json::Value,
    /// Timers.
    pub timers: Vec<TimerSpec>,
    /// Machine the node runs on.
    pub machine: String,
    /// Restart policy.
    pub restart: RestartPolicy,
    /// True for evaluation nodes (may read ground truth).
    pub evaluation: bool,
    /// Where the node is declared.
    pub loc: Loc,
}

impl NodeSpec {
    /// Output named `name`.
    pub fn output(&self, name: &str) -> Option<&OutputSpec> {
        self.outputs.iter().find(|o| o.name == name)
    }
}

/// A machine of a distributed run and its Zenoh endpoints.
#[derive(Debug, Clone, PartialEq)]
pub struct MachineSpec {
    /// Machine id, used by `deploy.machine`.
    pub id: String,
    /// Endpoints the machine's router listens on (default `tcp/127.0.0.1:0`, loopback only).
    pub listen: Vec<String>,
    /// Endpoints of other machines to connect to.
    pub connect: Vec<String>,
    /// Zenoh `transport/link/tls` settings, passed through verbatim.
    pub tls: Option<serde_json::Value>,
}

/// A validated dataflow.
#[derive(Debug, Clone, PartialEq)]
pub struct Dataflow {
    /// File it was read from (for messages).
    pub file: String,
    /// Folder external `path:` executables are relative to.
    pub base_dir: PathBuf,
    /// Text of the dataflow, copied to run folders and embedded in recordings: the file as
    /// written, or with `--set` overrides the effective document (see [`Override`]).
    pub source: String,
    /// Machines; at least one.
    pub machines: Vec<MachineSpec>,
    /// Nodes, in file order.
    pub nodes: Vec<NodeSpec>,
}

impl Dataflow {
    /// Read and validate a dataflow file against the operator catalogue.
    pub fn load(path: &Path, catalog: &[OperatorDescriptor]) -> Result<Self, Diagnostics> {
        Self::load_with(path, catalog, &[])
    }

    /// As [`Dataflow::load`], with `--set` overrides of node configs applied first.
    pub fn load_with(
        path: &Path,
        catalog: &[OperatorDescriptor],
        overrides: &[Override],
    ) -> Result<Self, Diagnostics> {
        let file = path.display().to_string();
        let source = std::fs::read_to_string(path).map_err(|e| {
            Diagnostics(vec![Diagnostic {
                file: file.clone(),
                loc: Loc::default(),
                message: format!("cannot read the file: {e}"),
            }])
        })?;
        let base_dir = path.parent().map(Path::to_path_buf).unwrap_or_default();
        Self::parse_with(&file, &source, base_dir, catalog, overrides)
    }

    /// Validate dataflow text; `file` only names it in messages.
    pub fn parse(
        file: &str,
        source: &str,
        base_dir: PathBuf,
        catalog: &[OperatorDescriptor],
    ) -> Result<Self, Diagnostics> {
        Self::parse_with(file, source, base_dir, catalog, &[])
    }

    /// As [`Dataflow::parse`], with `--set` overrides of node configs applied to the parsed
    /// document first; the result's `source` is then the effective document, and problems
    /// caused by an override name it.
    pub fn parse_with(
        file: &str,
        source: &str,
        base_dir: PathBuf,
        catalog: &[OperatorDescriptor],
        overrides: &[Override],
    ) -> Result<Self, Diagnostics> {
        let mut v = Validator {
            file: file.to_string(),
            diags: Vec::new(),
            labels: overrides.iter().map(Override::label).collect(),
            changed: Vec::new(),
        };
        let mut root = match yaml::parse(source) {
            Ok(r) => r,
            Err(e) => {
                v.err(e.loc, format!("YAML syntax error: {}", e.message));
                return Err(Diagnostics(v.diags));
            }
        };
        let mut effective = None;
        if !overrides.is_empty() {
            for (i, o) in overrides.iter().enumerate() {
                match o.apply(&mut root, i) {
                    Ok(node) => v.changed.push((node, o.label())),
                    Err(message) => v.diags.push(Diagnostic {
                        file: o.label(),
                        loc: Loc::default(),
                        message: message
                            .strip_prefix(&format!("{}: ", o.label()))
                            .unwrap_or(&message)
                            .to_string(),
                    }),
                }
            }
            let labels: Vec<&str> = v.labels.iter().map(String::as_str).collect();
            let mut text = format!(
                "# Effective dataflow: {file} {}\n# (the file with these overrides applied; its comments are not kept)\n",
                labels.join(" ")
            );
            let body = yaml::emit(&root);
            match yaml::parse(&body) {
                Ok(back) if yaml::canonical(&back) == yaml::canonical(&root) => {}
                _ => v.err(
                    Loc::default(),
                    "internal error: the dataflow with the overrides applied cannot be written back as YAML",
                ),
            }
            text.push_str(&body);
            effective = Some(text);
        }
        let source = effective.as_deref().unwrap_or(source);
        let flow = v.dataflow(&root, catalog, source, base_dir);
        if v.diags.is_empty() {
            Ok(flow)
        } else {
            v.diags.sort_by_key(|d| d.loc);
            Err(Diagnostics(v.diags))
        }
    }

    /// Node with id `id`.
    pub fn node(&self, id: &str) -> Option<&NodeSpec> {
        self.nodes.iter().find(|n| n.id == id)
    }

    /// Machine with id `id`.
    pub fn machine(&self, id: &str) -> Option<&MachineSpec> {
        self.machines.iter().find(|m| m.id == id)
    }

    /// Every (consumer node, input) reading `node/output`.
    pub fn consumers<'a>(
        &'a self,
        node: &'a str,
        output: &'a str,
    ) -> impl Iterator<Item = (&'a NodeSpec, &'a InputSpec)> + 'a {
        self.nodes.iter().flat_map(move |n| {
            n.inputs
                .iter()
                .filter(move |i| i.source_node == node && i.source_output == output)
                .map(move |i| (n, i))
        })
    }
}

struct Validator {
    file: String,
    diags: Vec<Diagnostic>,
    /// `--set` overrides as shown in messages, in command-line order.
    labels: Vec<String>,
    /// (node id, override label) for each override applied.
    changed: Vec<(String, String)>,
}

/// A node as written, before cross-node checks.
struct RawNode<'a> {
    id: String,
    id_loc: Loc,
    implementation: Option<NodeImpl>,
    descriptor: Option<&'a OperatorDescriptor>,
    inputs: Vec<(String, Loc, String, Loc, usize, DropPolicy)>,
    outputs: Vec<OutputSpec>,
    config: serde_json::Value,
    timers: Vec<TimerSpec>,
    machine: Option<(String, Loc)>,
    restart: RestartPolicy,
    evaluation: bool,
    loc: Loc,
}

impl Validator {
    fn err(&mut self, loc: Loc, message: impl Into<String>) {
        // A value brought by an override: the diagnostic names the override, not the file.
        let file = match Override::index_of(loc).and_then(|i| self.labels.get(i)) {
            Some(label) => label.clone(),
            None => self.file.clone(),
        };
        self.diags.push(Diagnostic {
            file,
            loc,
            message: message.into(),
        });
    }

    fn entries<'n>(&mut self, node: &'n Node, what: &str) -> &'n [(String, Loc, Node)] {
        match node {
            Node::Map { entries, .. } => entries,
            other => {
                self.err(
                    other.loc(),
                    format!("{what} must be a mapping, found {}", other.type_name()),
                );
                &[]
            }
        }
    }

    fn items<'n>(&mut self, node: &'n Node, what: &str) -> &'n [Node] {
        match node {
            Node::Seq { items, .. } => items,
            other => {
                self.err(
                    other.loc(),
                    format!("{what} must be a sequence, found {}", other.type_name()),
                );
                &[]
            }
        }
    }

    fn string(&mut self, node: &Node, what: &str) -> Option<String> {
        match node.as_str() {
            Some(s) if !s.is_empty() => Some(s.to_string()),
            _ => {
                self.err(node.loc(), format!("{what} must be a non-empty string"));
                None
            }
        }
    }

    fn strings(&mut self, node: &Node, what: &str) -> Vec<String> {
        let items = self.items(node, what);
        items.iter().filter_map(|i| self.string(i, what)).collect()
    }

    fn dataflow(
        &mut self,
        root: &Node,
        catalog: &[OperatorDescriptor],
        source: &str,
        base_dir: PathBuf,
    ) -> Dataflow {
        let mut machines = Vec::new();
        let mut nodes_node = None;
        for (key, key_loc, value) in self.entries(root, "the dataflow file") {
            match key.as_str() {
                "machines" => machines = self.machines(value),
                "nodes" => nodes_node = Some(value),
                other => self.err(
                    *key_loc,
                    format!("unknown top-level key `{other}` (expected `nodes` or `machines`)"),
                ),
            }
        }
        if machines.is_empty() {
            machines.push(MachineSpec {
                id: DEFAULT_MACHINE.into(),
                listen: vec!["tcp/127.0.0.1:0".into()],
                connect: vec![],
                tls: None,
            });
        }
        let Some(nodes_node) = nodes_node else {
            let loc = match root {
                Node::Map { entries, .. } if !entries.is_empty() => entries[0].1,
                _ => root.loc(),
            };
            self.err(loc, "missing `nodes:` list");
            return Dataflow {
                file: self.file.clone(),
                base_dir,
                source: source.into(),
                machines,
                nodes: vec![],
            };
        };
        let raw: Vec<RawNode> = self
            .items(nodes_node, "`nodes`")
            .iter()
            .filter_map(|n| self.raw_node(n, catalog))
            .collect();
        let nodes = self.resolve(raw, &machines);
        Dataflow {
            file: self.file.clone(),
            base_dir,
            source: source.into(),
            machines,
            nodes,
        }
    }

    fn machines(&mut self, node: &Node) -> Vec<MachineSpec> {
        let mut out: Vec<MachineSpec> = Vec::new();
        for m in self.items(node, "`machines`") {
            let mut spec = MachineSpec {
                id: String::new(),
                listen: vec!["tcp/127.0.0.1:0".into()],
                connect: vec![],
                tls: None,
            };
            for (key, key_loc, value) in self.entries(m, "a machine") {
                match key.as_str() {
                    "id" => {
                        if let Some(id) = self.string(value, "machine `id`") {
                            if out.iter().any(|o| o.id == id) {
                                self.err(value.loc(), format!("duplicate machine id `{id}`"));
                            }
                            spec.id = id;
                        }
                    }
                    "listen" => spec.listen = self.endpoints(value),
                    "connect" => spec.connect = self.endpoints(value),
                    "tls" => spec.tls = Some(value.to_json()),
                    other => self.err(*key_loc, format!("unknown machine key `{other}`")),
                }
            }
            if spec.id.is_empty() {
                self.err(m.loc(), "machine without `id`");
            }
            out.push(spec);
        }
        out
    }

    fn endpoints(&mut self, node: &Node) -> Vec<String> {
        let items = match node {
            Node::Seq { items, .. } => items.as_slice(),
            single => std::slice::from_ref(single),
        };
        let mut out = Vec::new();
        for item in items {
            if let Some(e) = self.string(item, "a Zenoh endpoint") {
                if e.split_once('/')
                    .is_none_or(|(proto, addr)| proto.is_empty() || !addr.contains(':'))
                {
                    self.err(
                        item.loc(),
                        format!("bad Zenoh endpoint `{e}` (expected e.g. tcp/127.0.0.1:7447)"),
                    );
                }
                out.push(e);
            }
        }
        out
    }

    fn raw_node<'a>(
        &mut self,
        node: &Node,
        catalog: &'a [OperatorDescriptor],
    ) -> Option<RawNode<'a>> {
        let mut raw = RawNode {
            id: String::new(),
            id_loc: node.loc(),
            implementation: None,
            descriptor: None,
            inputs: vec![],
            outputs: vec![],
            config: serde_json::Value::Null,
            timers: vec![],
            machine: None,
            restart: RestartPolicy::Never,
            evaluation: false,
            loc: node.loc(),
        };
        let entries = self.entries(node, "a node");
        if !matches!(node, Node::Map { .. }) {
            return None;
        }
        let mut config_node = None;
        let mut outputs_node = None;
        let mut path_args = Vec::new();
        for (key, key_loc, value) in entries {
            match key.as_str() {
                "id" => {
                    if let Some(id) = self.string(value, "node `id`") {
                        if id.contains('/') || id.contains('*') {
                            self.err(
                                value.loc(),
                                format!("node id `{id}` must not contain `/` or `*`"),
                            );
                        }
                        raw.id = id;
                        raw.id_loc = value.loc();
                    }
                }
                "operator" => {
                    if let Some(name) = self.string(value, "`operator`") {
                        match catalog.iter().find(|d| d.name == name) {
                            Some(d) => raw.descriptor = Some(d),
                            None => {
                                let known: Vec<_> = catalog.iter().map(|d| d.name).collect();
                                self.err(
                                    value.loc(),
                                    format!(
                                        "unknown operator `{name}` (known: {})",
                                        known.join(", ")
                                    ),
                                );
                            }
                        }
                        if raw.implementation.is_some() {
                            self.err(
                                value.loc(),
                                "a node has either `operator:` or `path:`, not both",
                            );
                        }
                        raw.implementation = Some(NodeImpl::Operator(name));
                    }
                }
                "path" => {
                    if let Some(path) = self.string(value, "`path`") {
                        if raw.implementation.is_some() {
                            self.err(
                                value.loc(),
                                "a node has either `operator:` or `path:`, not both",
                            );
                        }
                        raw.implementation = Some(NodeImpl::Path { path, args: vec![] });
                    }
                }
                "args" => path_args = self.strings(value, "`args`"),
                "inputs" => {
                    for (name, name_loc, input) in self.entries(value, "`inputs`") {
                        if let Some((source, source_loc, queue, drop)) = self.input(input) {
                            raw.inputs.push((
                                name.clone(),
                                *name_loc,
                                source,
                                source_loc,
                                queue,
                                drop,
                            ));
                        }
                    }
                }
                "outputs" => outputs_node = Some(value),
                "config" => config_node = Some(value),
                "timers" => {
                    for (name, _, period) in self.entries(value, "`timers`") {
                        if let Some(period) = self.duration(period) {
                            raw.timers.push(TimerSpec {
                                name: name.clone(),
                                period,
                            });
                        }
                    }
                }
                "deploy" => {
                    for (k, k_loc, v) in self.entries(value, "`deploy`") {
                        match k.as_str() {
                            "machine" => {
                                if let Some(m) = self.string(v, "`deploy.machine`") {
                                    raw.machine = Some((m, v.loc()));
                                }
                            }
                            other => self.err(
                                *k_loc,
                                format!("unknown deploy key `{other}` (expected `machine`)"),
                            ),
                        }
                    }
                }
                "restart" => raw.restart = self.restart(value),
                "evaluation" => match value.to_json() {
                    serde_json::Value::Bool(b) => raw.evaluation = b,
                    _ => self.err(value.loc(), "`evaluation` must be true or false"),
                },
                other => self.err(*key_loc, format!("unknown node key `{other}`")),
            }
        }
        if raw.id.is_empty() {
            self.err(node.loc(), "node without `id`");
            return None;
        }
        match &mut raw.implementation {
            None => self.err(
                node.loc(),
                format!("node `{}` needs `operator:` or `path:`", raw.id),
            ),
            Some(NodeImpl::Path { args, .. }) => *args = path_args,
            Some(NodeImpl::Operator(_)) => {
                if !path_args.is_empty() {
                    self.err(node.loc(), "`args` only applies to `path:` nodes");
                }
            }
        }
        if let Some(d) = raw.descriptor {
            raw.evaluation |= d.evaluation;
        }
        // Outputs: built-ins take their declared ports; external nodes must type theirs.
        match (raw.descriptor, outputs_node) {
            (Some(d), None) => {
                raw.outputs = d
                    .outputs
                    .iter()
                    .map(|p| OutputSpec {
                        name: p.name.into(),
                        kind: p.kind,
                    })
                    .collect();
            }
            (d, Some(list)) => {
                for item in self.items(list, "`outputs`") {
                    let (name, kind) = match item {
                        Node::Map { entries, .. } => {
                            let name = item.get("id").and_then(|n| self.string(n, "output `id`"));
                            let kind = match item.get("type") {
                                Some(t) => self.kind(t),
                                None => None,
                            };
                            for (k, k_loc, _) in entries {
                                if k != "id" && k != "type" {
                                    self.err(
                                        *k_loc,
                                        format!("unknown output key `{k}` (expected `id`, `type`)"),
                                    );
                                }
                            }
                            (name, kind)
                        }
                        other => (self.string(other, "an output"), None),
                    };
                    let Some(name) = name else { continue };
                    let kind = match (d, kind) {
                        (Some(d), k) => {
                            match d.output(&name) {
                                Some(p) => {
                                    if k.is_some_and(|k| k != p.kind) {
                                        self.err(item.loc(), format!(
                                        "output `{name}` of operator `{}` carries {}, not {}",
                                        d.name, p.kind.name(), k.map(|k| k.name()).unwrap_or_default()
                                    ));
                                    }
                                    p.kind
                                }
                                None => {
                                    let known: Vec<_> = d.outputs.iter().map(|p| p.name).collect();
                                    self.err(
                                        item.loc(),
                                        format!(
                                            "operator `{}` has no output `{name}` (outputs: {})",
                                            d.name,
                                            known.join(", ")
                                        ),
                                    );
                                    continue;
                                }
                            }
                        }
                        (None, Some(k)) => k,
                        (None, None) => {
                            if matches!(raw.implementation, Some(NodeImpl::Path { .. })) {
                                self.err(item.loc(), format!(
                                    "output `{name}` of external node `{}` needs a type: `{{id: {name}, type: <MessageKind>}}`", raw.id
                                ));
                            }
                            continue;
                        }
                    };
                    if raw.outputs.iter().any(|o| o.name == name) {
                        self.err(item.loc(), format!("duplicate output `{name}`"));
                    }
                    raw.outputs.push(OutputSpec { name, kind });
                }
            }
            (None, None) => {}
        }
        if let Some(c) = config_node {
            raw.config = c.to_json();
        }
        if let Some(d) = raw.descriptor
            && let Err(e) = (d.check_config)(&raw.config)
        {
            let loc = config_node
                .map(|c| self.config_error_loc(c, &e))
                .unwrap_or(raw.loc);
            let mut message = format!(
                "bad config for operator `{}` of node `{}`: {e}",
                d.name, raw.id
            );
            // Not pinned on an override's value, but the node's config was overridden.
            let by: Vec<&str> = self
                .changed
                .iter()
                .filter(|(node, _)| *node == raw.id)
                .map(|(_, label)| label.as_str())
                .collect();
            if Override::index_of(loc).is_none() && !by.is_empty() {
                message.push_str(&format!(" (config changed by {})", by.join(", ")));
            }
            self.err(loc, message);
        }
        Some(raw)
    }

    /// Point a config error at what it names: the key of an unknown field, or the scalar whose
    /// value the message quotes; otherwise the `config:` value itself.
    fn config_error_loc(&self, config: &Node, message: &str) -> Loc {
        fn quoted_after<'m>(
            message: &'m str,
            marker: &str,
            open: char,
            close: char,
        ) -> Option<&'m str> {
            let rest = &message[message.find(marker)? + marker.len()..];
            let rest = rest.strip_prefix(open)?;
            Some(&rest[..rest.find(close)?])
        }
        fn find_key(node: &Node, key: &str) -> Option<Loc> {
            match node {
                Node::Map { entries, .. } => {
                    entries.iter().find_map(
                        |(k, l, v)| {
                            if k == key { Some(*l) } else { find_key(v, key) }
                        },
                    )
                }
                Node::Seq { items, .. } => items.iter().find_map(|i| find_key(i, key)),
                Node::Scalar { .. } => None,
            }
        }
        fn find_value(node: &Node, value: &str) -> Option<Loc> {
            match node {
                Node::Scalar { value: v, loc, .. } => (v == value).then_some(*loc),
                Node::Map { entries, .. } => {
                    entries.iter().find_map(|(_, _, v)| find_value(v, value))
                }
                Node::Seq { items, .. } => items.iter().find_map(|i| find_value(i, value)),
            }
        }
        if let Some(field) = quoted_after(message, "unknown field ", '`', '`')
            && let Some(loc) = find_key(config, field)
        {
            return loc;
        }
        for (marker, open, close) in [
            ("string ", '"', '"'),
            ("integer ", '`', '`'),
            ("floating point ", '`', '`'),
            ("boolean ", '`', '`'),
        ] {
            if let Some(value) = quoted_after(message, marker, open, close)
                && let Some(loc) = find_value(config, value)
            {
                return loc;
            }
        }
        config.loc()
    }

    fn kind(&mut self, node: &Node) -> Option<MessageKind> {
        let name = self.string(node, "a message type")?;
        let kind = MessageKind::from_name(&name);
        if kind.is_none() {
            let known: Vec<_> = MessageKind::ALL.iter().map(|k| k.name()).collect();
            self.err(
                node.loc(),
                format!(
                    "unknown message type `{name}` (known: {})",
                    known.join(", ")
                ),
            );
        }
        kind
    }

    fn input(&mut self, node: &Node) -> Option<(String, Loc, usize, DropPolicy)> {
        let mut queue = 4usize;
        let mut drop = DropPolicy::DropOldest;
        let source_node = match node {
            Node::Scalar { .. } => node,
            Node::Map { entries, .. } => {
                for (k, k_loc, v) in entries {
                    match k.as_str() {
                        "source" => {}
                        "queue_size" => match v.to_json().as_u64() {
                            Some(q) if (1..=1024).contains(&q) => queue = q as usize,
                            _ => self.err(v.loc(), "`queue_size` must be an integer in 1..=1024"),
                        },
                        "drop" => match v.as_str() {
                            Some("drop_oldest") => drop = DropPolicy::DropOldest,
                            Some("block") => drop = DropPolicy::Block,
                            _ => self.err(v.loc(), "`drop` must be `drop_oldest` or `block`"),
                        },
                        other => self.err(
                            *k_loc,
                            format!(
                                "unknown input key `{other}` (expected source, queue_size, drop)"
                            ),
                        ),
                    }
                }
                match node.get("source") {
                    Some(s) => s,
                    None => {
                        self.err(node.loc(), "input without `source: node/output`");
                        return None;
                    }
                }
            }
            Node::Seq { .. } => {
                self.err(
                    node.loc(),
                    "an input is `node/output` or a mapping with `source:`",
                );
                return None;
            }
        };
        let source = self.string(source_node, "input source")?;
        Some((source, source_node.loc(), queue, drop))
    }

    fn duration(&mut self, node: &Node) -> Option<Duration> {
        let text = node.as_str().unwrap_or_default().trim();
        let parsed = if let Some(ms) = text.strip_suffix("ms") {
            ms.trim().parse::<f64>().ok().map(|v| v / 1000.0)
        } else if let Some(s) = text.strip_suffix('s') {
            s.trim().parse::<f64>().ok()
        } else {
            text.parse::<f64>().ok().map(|v| v / 1000.0)
        };
        match parsed {
            Some(secs) if secs > 0.0 && secs.is_finite() && secs < 86_400.0 => {
                Some(Duration::from_secs_f64(secs))
            }
            _ => {
                self.err(node.loc(), format!("bad timer period `{text}` (expected e.g. 100ms, 0.5s or a number of ms > 0)"));
                None
            }
        }
    }

    fn restart(&mut self, node: &Node) -> RestartPolicy {
        match node {
            Node::Scalar { value, .. } if value == "never" => RestartPolicy::Never,
            Node::Scalar { value, .. } if value == "on-failure" => RestartPolicy::OnFailure(3),
            Node::Map { entries, .. } if entries.len() == 1 && entries[0].0 == "on-failure" => {
                match entries[0].2.to_json().as_u64() {
                    Some(n) if n <= 100 => RestartPolicy::OnFailure(n as u32),
                    _ => {
                        self.err(
                            entries[0].2.loc(),
                            "`on-failure` takes a restart count in 0..=100",
                        );
                        RestartPolicy::Never
                    }
                }
            }
            other => {
                self.err(
                    other.loc(),
                    "`restart` must be `never`, `on-failure` or `{on-failure: N}`",
                );
                RestartPolicy::Never
            }
        }
    }

    fn resolve(&mut self, raw: Vec<RawNode>, machines: &[MachineSpec]) -> Vec<NodeSpec> {
        let mut seen: HashMap<&str, Loc> = HashMap::new();
        for n in &raw {
            if let Some(first) = seen.get(n.id.as_str()) {
                let msg = format!("duplicate node id `{}` (first declared at {first})", n.id);
                self.err(n.id_loc, msg);
            } else {
                seen.insert(&n.id, n.id_loc);
            }
        }
        let outputs: BTreeMap<&str, &RawNode> = raw.iter().map(|n| (n.id.as_str(), n)).collect();
        let mut nodes = Vec::new();
        for n in &raw {
            let mut inputs = Vec::new();
            for (name, name_loc, source, source_loc, queue_size, drop) in &n.inputs {
                let expected = match n.descriptor {
                    Some(d) => match d.input(name) {
                        Some(p) => Some(p.kind),
                        None => {
                            let known: Vec<_> = d.inputs.iter().map(|p| p.name).collect();
                            self.err(
                                *name_loc,
                                format!(
                                    "operator `{}` has no input `{name}` (inputs: {})",
                                    d.name,
                                    known.join(", ")
                                ),
                            );
                            continue;
                        }
                    },
                    None => None,
                };
                let Some((src_node, src_output)) = source.split_once('/') else {
                    self.err(
                        *source_loc,
                        format!("input source `{source}` must be `node/output`"),
                    );
                    continue;
                };
                let Some(producer) = outputs.get(src_node) else {
                    self.err(
                        *source_loc,
                        format!("input `{name}` reads from unknown node `{src_node}`"),
                    );
                    continue;
                };
                let Some(out) = producer.outputs.iter().find(|o| o.name == src_output) else {
                    let known: Vec<_> = producer.outputs.iter().map(|o| o.name.as_str()).collect();
                    self.err(*source_loc, format!(
                        "input `{name}` reads `{source}`, but node `{src_node}` has no output `{src_output}` (outputs: {})",
                        known.join(", ")
                    ));
                    continue;
                };
                if let Some(expected) = expected
                    && expected != out.kind
                {
                    self.err(*source_loc, format!(
                            "type mismatch: input `{name}` of node `{}` expects {}, but `{source}` carries {}",
                            n.id, expected.name(), out.kind.name()
                        ));
                    continue;
                }
                if out.kind.evaluation_only() && !n.evaluation {
                    self.err(*source_loc, format!(
                        "node `{}` reads `{source}` ({}), which is evaluation-only ground truth; only evaluation nodes may subscribe",
                        n.id, out.kind.name()
                    ));
                    continue;
                }
                inputs.push(InputSpec {
                    name: name.clone(),
                    source_node: src_node.into(),
                    source_output: src_output.into(),
                    kind: out.kind,
                    queue_size: *queue_size,
                    drop: *drop,
                    loc: *source_loc,
                });
            }
            let machine = match &n.machine {
                Some((m, loc)) => {
                    if !machines.iter().any(|x| &x.id == m) {
                        let known: Vec<_> = machines.iter().map(|x| x.id.as_str()).collect();
                        self.err(
                            *loc,
                            format!("unknown machine `{m}` (machines: {})", known.join(", ")),
                        );
                    }
                    m.clone()
                }
                None => machines[0].id.clone(),
            };
            let Some(implementation) = n.implementation.clone() else {
                continue;
            };
            nodes.push(NodeSpec {
                id: n.id.clone(),
                implementation,
                inputs,
                outputs: n.outputs.clone(),
                config: n.config.clone(),
                timers: n.timers.clone(),
                machine,
                restart: n.restart,
                evaluation: n.evaluation,
                loc: n.loc,
            });
        }
        nodes
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::{PortSpec, check_config_as};

    #[derive(serde::Deserialize)]
    #[serde(deny_unknown_fields)]
    #[allow(dead_code)]
    struct PingConfig {
        #[serde(default)]
        gain: f64,
    }

    fn catalog() -> Vec<OperatorDescriptor> {
        vec![
            OperatorDescriptor {
                name: "ping",
                summary: "test",
                inputs: &[PortSpec {
                    name: "in",
                    kind: MessageKind::Counter,
                }],
                outputs: &[PortSpec {
                    name: "out",
                    kind: MessageKind::Counter,
                }],
                evaluation: false,
                check_config: check_config_as::<PingConfig>,
            },
            OperatorDescriptor {
                name: "judge",
                summary: "test",
                inputs: &[PortSpec {
                    name: "truth",
                    kind: MessageKind::TruePose,
                }],
                outputs: &[],
                evaluation: true,
                check_config: check_config_as::<PingConfig>,
            },
        ]
    }

    #[test]
    fn cycles_defaults_and_external_nodes_are_accepted() {
        let src = "nodes:\n  - id: a\n    operator: ping\n    inputs:\n      in: b/out\n  - id: b\n    operator: ping\n    config: { gain: 2.5 }\n    inputs:\n      in: { source: a/out, queue_size: 2, drop: block }\n  - id: gt\n    path: ./gt.sh\n    args: [--fast]\n    outputs: [{ id: pose, type: TruePose }]\n  - id: j\n    operator: judge\n    inputs:\n      truth: gt/pose\n";
        let flow = Dataflow::parse("t.yaml", src, PathBuf::new(), &catalog()).unwrap();
        assert_eq!(flow.nodes.len(), 4);
        let b = flow.node("b").unwrap();
        assert_eq!(b.inputs[0].queue_size, 2);
        assert_eq!(b.inputs[0].drop, DropPolicy::Block);
        assert_eq!(b.config, serde_json::json!({"gain": 2.5}));
        let a = flow.node("a").unwrap();
        assert_eq!(
            (a.inputs[0].queue_size, a.inputs[0].drop),
            (4, DropPolicy::DropOldest)
        );
        assert_eq!(a.machine, DEFAULT_MACHINE);
        assert!(flow.node("j").unwrap().evaluation);
        assert_eq!(
            flow.node("gt").unwrap().implementation,
            NodeImpl::Path {
                path: "./gt.sh".into(),
                args: vec!["--fast".into()]
            }
        );
        let consumers: Vec<_> = flow
            .consumers("a", "out")
            .map(|(n, _)| n.id.as_str())
            .collect();
        assert_eq!(consumers, vec!["b"]);
    }

    #[test]
    fn several_errors_are_all_reported_in_file_order() {
        let src = "nodes:\n  - id: a\n    operator: nope\n  - id: b\n    operator: ping\n    inputs:\n      in: zz/out\n";
        let err = Dataflow::parse("t.yaml", src, PathBuf::new(), &catalog()).unwrap_err();
        let text = err.to_string();
        assert_eq!(err.0.len(), 2, "{text}");
        assert!(
            text.starts_with("t.yaml:3:15: error: unknown operator `nope`"),
            "{text}"
        );
        assert!(
            text.contains("t.yaml:7:11: error: input `in` reads from unknown node `zz`"),
            "{text}"
        );
    }

    #[test]
    fn timers_restart_and_machines_parse() {
        let src = "machines:\n  - id: m1\n    listen: tcp/127.0.0.2:7447\n    tls: { root_ca_certificate: ca.pem }\n  - id: m2\n    connect: [tcp/127.0.0.2:7447]\nnodes:\n  - id: a\n    operator: ping\n    timers: { fast: 5ms, slow: 1.5s, plain: 250 }\n    restart: { on-failure: 2 }\n    deploy: { machine: m2 }\n";
        let flow = Dataflow::parse("t.yaml", src, PathBuf::new(), &catalog()).unwrap();
        let a = flow.node("a").unwrap();
        let periods: Vec<_> = a.timers.iter().map(|t| t.period).collect();
        assert_eq!(
            periods,
            vec![
                Duration::from_millis(5),
                Duration::from_millis(1500),
                Duration::from_millis(250)
            ]
        );
        assert_eq!(a.restart, RestartPolicy::OnFailure(2));
        assert_eq!(a.machine, "m2");
        let m1 = flow.machine("m1").unwrap();
        assert_eq!(m1.listen, vec!["tcp/127.0.0.2:7447".to_string()]);
        assert_eq!(
            m1.tls,
            Some(serde_json::json!({"root_ca_certificate": "ca.pem"}))
        );
    }

    fn overrides(texts: &[&str]) -> Vec<Override> {
        texts.iter().map(|t| Override::parse(t).unwrap()).collect()
    }

    #[test]
    fn override_syntax_reads_the_value_as_yaml() {
        let json = |t: &str| {
            let o = Override::parse(t).unwrap();
            let mut root = yaml::parse("nodes: [{ id: sim }]").unwrap();
            o.apply(&mut root, 0).unwrap();
            root.get("nodes").unwrap().to_json()[0]["config"].clone()
        };
        assert_eq!(
            json("sim.scene=house:3"),
            serde_json::json!({"scene": "house:3"})
        );
        assert_eq!(json("sim.width=320"), serde_json::json!({"width": 320}));
        assert_eq!(json("sim.lock=true"), serde_json::json!({"lock": true}));
        assert_eq!(json("sim.m={a: 1}"), serde_json::json!({"m": {"a": 1}}));
        assert_eq!(json("sim.s=\"7\""), serde_json::json!({"s": "7"}));
        assert_eq!(json("sim.n="), serde_json::json!({"n": null}));
        for (bad, why) in [
            (
                "sim.scene",
                "`--set sim.scene`: expected NODE.KEY=VALUE (no `=`)",
            ),
            ("sim=3", "is not NODE.KEY"),
            ("sim..x=3", "is not NODE.KEY"),
            ("sim.x=[1, 2", "the value is not valid YAML"),
        ] {
            let e = Override::parse(bad).unwrap_err();
            assert!(e.contains(why) && e.contains(bad), "{bad}: {e}");
        }
        assert_eq!(
            Override::parse("sim.scene=a b").unwrap().label(),
            "--set 'sim.scene=a b'"
        );
    }

    #[test]
    fn overrides_set_nested_keys_and_create_missing_ones() {
        let src = "nodes:\n  - id: a\n    operator: ping\n  - id: b.c\n    path: ./b\n    config: { x: { y: 1 }, s: str, e: }\n";
        let mut root = yaml::parse(src).unwrap();
        for (i, o) in overrides(&["a.gain=2", "b.c.x.z=[1, 2]", "b.c.x.y=3", "b.c.e.f.g=h"])
            .iter()
            .enumerate()
        {
            o.apply(&mut root, i).unwrap();
        }
        let nodes = root.get("nodes").unwrap().to_json();
        assert_eq!(nodes[0]["config"], serde_json::json!({"gain": 2}));
        assert_eq!(
            nodes[1]["config"],
            serde_json::json!({"x": {"y": 3, "z": [1, 2]}, "s": "str", "e": {"f": {"g": "h"}}})
        );
        let e = overrides(&["simm.scene=x"])[0]
            .apply(&mut root, 0)
            .unwrap_err();
        assert_eq!(e, "--set simm.scene=x: no node `simm` (nodes: a, b.c)");
        let e = overrides(&["b.c.s.t=1"])[0]
            .apply(&mut root, 0)
            .unwrap_err();
        assert!(
            e.contains("`b.c.s` is a scalar (`str`), not a mapping"),
            "{e}"
        );
        let mut scalar_config = yaml::parse("nodes: [{ id: a, config: 3 }]").unwrap();
        let e = overrides(&["a.k=1"])[0]
            .apply(&mut scalar_config, 0)
            .unwrap_err();
        assert!(e.contains("the `config` of node `a` is a scalar"), "{e}");
    }

    #[test]
    fn overridden_flows_validate_and_carry_the_effective_text() {
        let src = "# comment\nnodes:\n  - id: a\n    operator: ping\n    config: { gain: 1 }\n    inputs:\n      in: a/out\n";
        let set = overrides(&["a.gain=2.5"]);
        let flow = Dataflow::parse_with("t.yaml", src, PathBuf::new(), &catalog(), &set).unwrap();
        assert_eq!(
            flow.node("a").unwrap().config,
            serde_json::json!({"gain": 2.5})
        );
        assert!(
            flow.source
                .starts_with("# Effective dataflow: t.yaml --set a.gain=2.5\n"),
            "{}",
            flow.source
        );
        // The effective text is a dataflow of its own, with the same values.
        let again = Dataflow::parse(
            "run/dataflow.yaml",
            &flow.source,
            PathBuf::new(),
            &catalog(),
        )
        .unwrap();
        assert_eq!(
            again.node("a").unwrap().config,
            flow.node("a").unwrap().config
        );
        // Without overrides the text is kept as written.
        let plain = Dataflow::parse_with("t.yaml", src, PathBuf::new(), &catalog(), &[]).unwrap();
        assert_eq!(plain.source, src);
    }

    #[test]
    fn override_errors_name_the_override_and_file_errors_keep_their_location() {
        let src = "nodes:\n  - id: a\n    operator: ping\n    inputs:\n      in: zz/out\n";
        let set = overrides(&["a.gain=abc", "b.gain=1"]);
        let err = Dataflow::parse_with("t.yaml", src, PathBuf::new(), &catalog(), &set)
            .unwrap_err()
            .to_string();
        assert!(
            err.contains("--set a.gain=abc: error: bad config for operator `ping` of node `a`: invalid type: string \"abc\""),
            "{err}"
        );
        assert!(
            err.contains("--set b.gain=1: error: no node `b` (nodes: a)"),
            "{err}"
        );
        assert!(
            err.contains("t.yaml:5:11: error: input `in` reads from unknown node `zz`"),
            "{err}"
        );
        let parse = |src: &str, set: &[&str]| {
            Dataflow::parse_with("t.yaml", src, PathBuf::new(), &catalog(), &overrides(set))
                .unwrap_err()
                .to_string()
        };
        let err = parse(src, &["a.extra.deep=1"]);
        assert!(
            err.contains("--set a.extra.deep=1: error: bad config for operator `ping` of node `a`: unknown field `extra`"),
            "{err}"
        );
        // A refusal pinned on the file still says the config was overridden.
        let src = "nodes:\n  - id: a\n    operator: ping\n    config: { gain: 1, bogus: 2 }\n";
        let err = parse(src, &["a.gain=3"]);
        assert!(
            err.starts_with("t.yaml:4:24: error: bad config for operator `ping` of node `a`: unknown field `bogus`")
                && err.ends_with("(config changed by --set a.gain=3)"),
            "{err}"
        );
    }
}
