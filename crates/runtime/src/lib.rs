//! Dataflow runtime: the dataflow file and its validation, the iceoryx2/Zenoh transport, the node
//! runner, the launcher, the recorder and replay, the daemons. It runs operators written against
//! `activemap-operator` (re-exported here) and knows no message's meaning: what it should do with
//! a kind (store it column-wise or as digests, read a run's progress from it, show it in a
//! viewer, serve episodes from a daemon) is registered by the program that starts it
//! ([`delta::register_codec`], [`launch::LaunchOptions`], [`derived`], [`daemon::DaemonService`]).
//!
//! # Writing an operator
//!
//! An operator is a type implementing [`Operator`] (unit-tested without any transport with
//! [`Harness`]): it is built from its node's `config:` and then
//! receives [`Event`]s — input messages, timer ticks, end of an input stream, stop — and sends
//! outputs through the [`Context`]. The runtime picks the transport: large payloads
//! (RGB-D frames, maps, grids) travel through iceoryx2 shared memory on one machine and are
//! bridged over Zenoh to other machines; small messages travel over Zenoh.
//!
//! ```no_run
//! use activemap_runtime::{Context, Event, Flow, Operator};
//! use activemap_schemas::{Action, ActionKind, RgbdFrameHeader, RgbdFrameMut, RgbdFrameView};
//!
//! /// Config from the dataflow file; unknown keys are a validation error.
//! #[derive(serde::Deserialize)]
//! #[serde(deny_unknown_fields)]
//! struct MyConfig {
//!     #[serde(default = "default_size")]
//!     size: u32,
//! }
//! fn default_size() -> u32 { 800 }
//!
//! struct MyCamera { size: u32, frame: u64 }
//!
//! // The ports, named once: registration uses `ALL`, dispatch the constants (a typo is a
//! // compile error).
//! mod inputs {
//!     activemap_runtime::ports! { ACTION = "action": activemap_schemas::MessageKind::Action }
//! }
//! mod outputs {
//!     activemap_runtime::ports! { RGBD = "rgbd": activemap_schemas::MessageKind::RgbdFrame }
//! }
//!
//! impl Operator for MyCamera {
//!     type Config = MyConfig;
//!
//!     fn new(config: MyConfig, _ctx: &mut Context<'_>) -> anyhow::Result<Self> {
//!         Ok(Self { size: config.size, frame: 0 })
//!     }
//!
//!     fn on_event(&mut self, event: Event<'_>, ctx: &mut Context<'_>) -> anyhow::Result<Flow> {
//!         match event {
//!             // An input `action:` of type Action: decode (checks the type and schema version).
//!             Event::Input(input) if input.port == inputs::ACTION => {
//!                 let action: Action = input.decode()?;
//!                 if action.action == ActionKind::Stop {
//!                     return Ok(Flow::Stop);
//!                 }
//!                 // Large output, written in place into a loaned shared-memory sample: no copy.
//!                 self.frame += 1;
//!                 let header = RgbdFrameHeader::new(self.frame, 0.0, [400.0, 400.0, 399.5, 399.5],
//!                                                   self.size, self.size);
//!                 ctx.loan(outputs::RGBD, header.payload_len()?, |buf| {
//!                     let frame = RgbdFrameMut::init(buf, header)?;
//!                     frame.rgb.fill(128);
//!                     frame.depth.fill(1.5);
//!                     Ok(())
//!                 })?;
//!             }
//!             // A large input is read in place: `RgbdFrameView::parse(input.bytes)`.
//!             Event::Input(input) => {
//!                 let _view = RgbdFrameView::parse(input.bytes)?;
//!             }
//!             Event::Timer { name: _ } => {}
//!             Event::InputClosed { .. } | Event::Stop => {}
//!         }
//!         Ok(Flow::Continue)
//!     }
//! }
//! ```
//!
//! Register it in `activemap-operators` (an [`OperatorDescriptor`] with its ports, `inputs::ALL`
//! and `outputs::ALL`, and its config check,
//! plus [`OperatorImpl::of::<MyCamera>()`]), then use it in a dataflow file:
//!
//! ```yaml
//! nodes:
//!   - id: camera
//!     operator: my_camera
//!     config: { size: 800 }
//!     inputs:
//!       action: follower/action          # or { source: follower/action, queue_size: 1, drop: block }
//! ```
//!
//! `activemap validate FILE` checks it; `activemap run FILE` runs every node as an `activemap node`
//! subprocess; `activemap replay REC --node camera` re-runs the node alone on its recorded inputs.

pub mod bench;
pub mod daemon;
pub mod dataflow;
pub mod delta;
pub mod derived;
mod error;
mod finish_barrier;
#[doc(hidden)]
pub mod fuzzing;
pub mod graph;
pub mod launch;
pub mod node;
pub mod progress;
pub mod record;
pub mod tls;
pub mod transport;
pub mod yaml;

/// The operator API lives in `activemap-operator` (no transport); re-exported here so that
/// `activemap_runtime::Operator` and `activemap_operator::Operator` are one trait.
pub use activemap_operator::{
    ConfigCheck, Context, Event, Flow, Harness, Input, Operator, OperatorDescriptor, OperatorError,
    OutputSink, PortSpec, Sent, check_config_as, config_from_value, loan_on_heap, ports,
};
pub use dataflow::{Dataflow, Diagnostic, Diagnostics, DropPolicy, NodeSpec, RestartPolicy};
pub use error::RuntimeError;
pub use node::{NodeSetup, OperatorImpl, RunInfo};
