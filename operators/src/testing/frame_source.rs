//! `frame_source`: on each tick, writes a deterministic `size`×`size` RGB-D frame straight into a
//! loaned shared-memory sample (no copy); stops after `count` frames.

use activemap_runtime::{
    Context, Event, Flow, Operator, OperatorDescriptor, OperatorImpl, PortSpec, check_config_as,
};
use activemap_schemas::{MessageKind, RgbdFrameHeader, RgbdFrameMut};

use crate::Registered;

/// Config.
#[derive(Debug, serde::Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Config {
    /// Frames to send.
    #[serde(default = "default_count")]
    pub count: u64,
    /// Image side in pixels.
    #[serde(default = "default_size")]
    pub size: u32,
    /// Each pixel pattern is sent this many times in a row (frame ids still count up), like a
    /// map republished unchanged between keyframes; see [`pattern_of`].
    #[serde(default = "default_repeat")]
    pub repeat: u64,
}

fn default_repeat() -> u64 {
    1
}

/// The pixel pattern frame `frame_id` (from 1) carries when each is sent `repeat` times.
pub fn pattern_of(frame_id: u64, repeat: u64) -> u64 {
    (frame_id - 1) / repeat.max(1) + 1
}

fn default_count() -> u64 {
    5
}
fn default_size() -> u32 {
    800
}

/// The deterministic test pattern of frame `frame_id`: the checker recomputes it independently.
pub fn pattern_rgb(frame_id: u64, i: usize) -> u8 {
    ((i as u64)
        .wrapping_mul(2_654_435_761)
        .wrapping_add(frame_id.wrapping_mul(97))
        >> 7) as u8
}

/// Depth of pixel `i` of frame `frame_id`, metres (includes non-trivial bit patterns).
pub fn pattern_depth(frame_id: u64, i: usize) -> f32 {
    0.1 + ((i as u64 * 7 + frame_id) % 10_007) as f32 * 1.0e-3 + 1.0 / (1.0 + i as f32)
}

/// Header of frame `frame_id`.
pub fn pattern_header(frame_id: u64, size: u32) -> RgbdFrameHeader {
    let c = size as f64 / 2.0 - 0.5;
    RgbdFrameHeader::new(
        frame_id,
        frame_id as f64 * 0.1,
        [size as f64 / 2.0, size as f64 / 2.0, c, c],
        size,
        size,
    )
}

/// The operator.
pub struct FrameSource {
    config: Config,
    sent: u64,
}

impl Operator for FrameSource {
    type Config = Config;

    fn new(config: Config, _ctx: &mut Context<'_>) -> anyhow::Result<Self> {
        anyhow::ensure!(
            config.size > 0 && config.size <= 4096,
            "size must be in 1..=4096"
        );
        anyhow::ensure!(config.repeat >= 1, "repeat must be at least 1");
        Ok(Self { config, sent: 0 })
    }

    fn on_event(&mut self, event: Event<'_>, ctx: &mut Context<'_>) -> anyhow::Result<Flow> {
        if let Event::Timer { .. } = event {
            if self.sent >= self.config.count {
                return Ok(Flow::Stop);
            }
            self.sent += 1;
            let header = pattern_header(self.sent, self.config.size);
            let id = pattern_of(self.sent, self.config.repeat);
            ctx.loan("frame", header.payload_len()?, |buf| {
                let frame = RgbdFrameMut::init(buf, header)?;
                for (i, v) in frame.rgb.iter_mut().enumerate() {
                    *v = pattern_rgb(id, i);
                }
                for (i, d) in frame.depth.iter_mut().enumerate() {
                    *d = pattern_depth(id, i);
                }
                Ok(())
            })?;
        }
        Ok(Flow::Continue)
    }
}

/// Registry entry.
pub fn registered() -> Registered {
    Registered {
        descriptor: OperatorDescriptor {
            name: "frame_source",
            summary: "Writes deterministic RGB-D test frames in place into shared memory (tests)",
            inputs: &[],
            outputs: &[PortSpec {
                name: "frame",
                kind: MessageKind::RgbdFrame,
            }],
            evaluation: false,
            check_config: check_config_as::<Config>,
        },
        implementation: Some(OperatorImpl::of::<FrameSource>()),
    }
}
