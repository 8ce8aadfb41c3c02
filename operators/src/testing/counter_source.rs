//! `counter_source`: on each tick of its timer, sends `Counter { seq, value: start + seq }`;
//! stops after `count` messages.

use activemap_runtime::{
    Context, Event, Flow, Operator, OperatorDescriptor, OperatorImpl, PortSpec, check_config_as,
};
use activemap_schemas::{Counter, MessageKind};

use crate::Registered;

/// Config.
#[derive(Debug, serde::Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Config {
    /// Messages to send before stopping.
    #[serde(default = "default_count")]
    pub count: u64,
    /// Value of the first message.
    #[serde(default)]
    pub start: i64,
}

fn default_count() -> u64 {
    10
}

/// The operator.
pub struct CounterSource {
    config: Config,
    sent: u64,
}

impl Operator for CounterSource {
    type Config = Config;

    fn new(config: Config, _ctx: &mut Context<'_>) -> anyhow::Result<Self> {
        Ok(Self { config, sent: 0 })
    }

    fn on_event(&mut self, event: Event<'_>, ctx: &mut Context<'_>) -> anyhow::Result<Flow> {
        if let Event::Timer { .. } = event {
            if self.sent >= self.config.count {
                return Ok(Flow::Stop);
            }
            self.sent += 1;
            ctx.send(
                "count",
                &Counter {
                    seq: self.sent,
                    value: self.config.start + self.sent as i64,
                },
            )?;
        }
        Ok(Flow::Continue)
    }
}

/// Registry entry.
pub fn registered() -> Registered {
    Registered {
        descriptor: OperatorDescriptor {
            name: "counter_source",
            summary: "Sends `count` Counter messages, one per timer tick (tests, diagnostics)",
            inputs: &[],
            outputs: &[PortSpec {
                name: "count",
                kind: MessageKind::Counter,
            }],
            evaluation: false,
            check_config: check_config_as::<Config>,
        },
        implementation: Some(OperatorImpl::of::<CounterSource>()),
    }
}
