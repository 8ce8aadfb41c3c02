//! `frame_checker`: compares every received RGB-D frame bit for bit with the pattern
//! [`super::frame_source`] writes, and reports `Counter { seq: frame_id, value: 1 }` when exact
//! (0 otherwise, with the first differing byte on stderr).

use activemap_runtime::{
    Context, Event, Flow, Operator, OperatorDescriptor, OperatorImpl, PortSpec, check_config_as,
};
use activemap_schemas::{Counter, MessageKind, RgbdFrameView};

use super::frame_source::{pattern_depth, pattern_header, pattern_rgb};
use crate::Registered;

/// Config (none).
#[derive(Debug, serde::Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Config {}

/// The operator.
pub struct FrameChecker;

impl Operator for FrameChecker {
    type Config = Config;

    fn new(_config: Config, _ctx: &mut Context<'_>) -> anyhow::Result<Self> {
        Ok(Self)
    }

    fn on_event(&mut self, event: Event<'_>, ctx: &mut Context<'_>) -> anyhow::Result<Flow> {
        if let Event::Input(input) = event {
            // Zero-copy view of the shared-memory sample.
            let view = RgbdFrameView::parse(input.bytes)?;
            let id = view.header.frame_id;
            let expected = pattern_header(id, view.header.width);
            let mut exact = view.header == expected && view.header.width == view.header.height;
            if exact {
                if let Some(i) = view
                    .rgb
                    .iter()
                    .enumerate()
                    .position(|(i, v)| *v != pattern_rgb(id, i))
                {
                    eprintln!("frame {id}: rgb byte {i} differs");
                    exact = false;
                }
                let depth = view.depth();
                if let Some(i) = depth
                    .iter()
                    .enumerate()
                    .position(|(i, d)| d.to_bits() != pattern_depth(id, i).to_bits())
                {
                    eprintln!("frame {id}: depth value {i} differs");
                    exact = false;
                }
            } else {
                eprintln!("frame {id}: header differs: {:?}", view.header);
            }
            ctx.send(
                "report",
                &Counter {
                    seq: id,
                    value: i64::from(exact),
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
            name: "frame_checker",
            summary: "Checks RGB-D test frames bit for bit (tests)",
            inputs: &[PortSpec {
                name: "frame",
                kind: MessageKind::RgbdFrame,
            }],
            outputs: &[PortSpec {
                name: "report",
                kind: MessageKind::Counter,
            }],
            evaluation: false,
            check_config: check_config_as::<Config>,
        },
        implementation: Some(OperatorImpl::of::<FrameChecker>()),
    }
}
