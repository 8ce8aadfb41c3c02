//! The operator API of activemap, and nothing else: what an operator is ([`Operator`]), what it
//! receives ([`Event`], [`Input`]), how it sends ([`Context`]), how it declares its ports once
//! ([`ports!`], [`PortSpec`], [`OperatorDescriptor`]), and a [`Harness`] that drives it without
//! any transport, for unit tests.
//!
//! Why a crate of its own: an operator is the part people write, and it should not pull in the
//! transport (iceoryx2, Zenoh), the launcher or the recorder to be written and tested.
//! `activemap-runtime` runs operators written against this crate (and re-exports it, so
//! `activemap_runtime::Operator` is the same trait); an out-of-tree operator depends on this
//! crate and `activemap-schemas`, and adds `activemap-runtime` only in the binary that runs it
//! (`activemap_runtime::node::run_external`).
//!
//! ```
//! use activemap_operator::{Context, Event, Flow, Harness, Operator};
//! use activemap_schemas::{Counter, MessageKind};
//!
//! mod inputs {
//!     activemap_operator::ports! { VALUE = "value": activemap_schemas::MessageKind::Counter }
//! }
//! mod outputs {
//!     activemap_operator::ports! { DOUBLED = "doubled": activemap_schemas::MessageKind::Counter }
//! }
//!
//! /// Doubles every counter it receives.
//! struct Doubler;
//!
//! impl Operator for Doubler {
//!     type Config = ();
//!     fn new(_: (), _: &mut Context<'_>) -> anyhow::Result<Self> {
//!         Ok(Doubler)
//!     }
//!     fn on_event(&mut self, event: Event<'_>, ctx: &mut Context<'_>) -> anyhow::Result<Flow> {
//!         if let Event::Input(input) = event
//!             && input.port == inputs::VALUE
//!         {
//!             let c: Counter = input.decode()?;
//!             ctx.send(outputs::DOUBLED, &Counter { seq: c.seq, value: 2 * c.value })?;
//!         }
//!         Ok(Flow::Continue)
//!     }
//! }
//!
//! let mut h = Harness::<Doubler>::new("doubler", inputs::ALL, outputs::ALL, ())?;
//! h.input(inputs::VALUE, &Counter { seq: 1, value: 21 })?;
//! let out: Vec<Counter> = h.take(outputs::DOUBLED)?;
//! assert_eq!(out[0].value, 42);
//! # anyhow::Ok(())
//! ```

mod error;
mod harness;
mod operator;
mod ports;

pub use error::OperatorError;
pub use harness::{Harness, Sent};
pub use operator::{Context, Event, Flow, Input, Operator, OutputSink, loan_on_heap};
pub use ports::{ConfigCheck, OperatorDescriptor, PortSpec, check_config_as, config_from_value};
