//! `doubler`: multiplies each incoming counter value by `factor` (deterministic; used by the
//! record/replay test).

use activemap_runtime::{
    Context, Event, Flow, Operator, OperatorDescriptor, OperatorImpl, PortSpec, check_config_as,
};
use activemap_schemas::{Counter, MessageKind};

use crate::Registered;

/// Config.
#[derive(Debug, serde::Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Config {
    /// Multiplier.
    #[serde(default = "default_factor")]
    pub factor: i64,
}

fn default_factor() -> i64 {
    2
}

/// The operator.
pub struct Doubler {
    factor: i64,
}

impl Operator for Doubler {
    type Config = Config;

    fn new(config: Config, _ctx: &mut Context<'_>) -> anyhow::Result<Self> {
        Ok(Self {
            factor: config.factor,
        })
    }

    fn on_event(&mut self, event: Event<'_>, ctx: &mut Context<'_>) -> anyhow::Result<Flow> {
        if let Event::Input(input) = event {
            let c: Counter = input.decode()?;
            ctx.send(
                "doubled",
                &Counter {
                    seq: c.seq,
                    value: c
                        .value
                        .checked_mul(self.factor)
                        .ok_or_else(|| anyhow::anyhow!("overflow"))?,
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
            name: "doubler",
            summary: "Multiplies Counter values by `factor` (tests)",
            inputs: &[PortSpec {
                name: "value",
                kind: MessageKind::Counter,
            }],
            outputs: &[PortSpec {
                name: "doubled",
                kind: MessageKind::Counter,
            }],
            evaluation: false,
            check_config: check_config_as::<Config>,
        },
        implementation: Some(OperatorImpl::of::<Doubler>()),
    }
}
