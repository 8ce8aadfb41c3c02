//! The Foxglove view of a run, registered on the runtime's recorder: the runtime knows nothing of
//! viewers, so the CLI plugs `activemap-view` in through `activemap_runtime::derived`.

use std::collections::BTreeMap;

use activemap_runtime::RuntimeError;
use activemap_runtime::derived::{
    Derived, DerivedChannel, DerivedChannels, DerivedFactory, DerivedFilter, DerivedMessage,
};
use activemap_schemas::{GaussianMapHeader, MessageKind};
use activemap_view::topics::VIEW_ENCODING;
use activemap_view::{LiveView, ViewConverter, ViewSettings, ViewTopic};

/// Makes the Foxglove view channels of every run (and the live view with `--view`).
#[derive(Debug, Default, Clone, Copy)]
pub struct FoxgloveView;

impl DerivedFactory for FoxgloveView {
    fn start(&self, live: Option<&str>) -> Result<Derived, RuntimeError> {
        let live = match live {
            Some(address) => Some(start_live(address)?),
            None => None,
        };
        Ok(Derived {
            filter: Box::new(NewKeyframes::default()),
            channels: Box::new(FoxgloveChannels {
                converter: ViewConverter::new(ViewSettings::default()),
                live,
            }),
        })
    }
}

/// Serve the view on `address`, warning when that is not loopback.
fn start_live(address: &str) -> Result<LiveView, RuntimeError> {
    let live = LiveView::start(address).map_err(|e| RuntimeError::Other(e.to_string()))?;
    let host = address.rsplit_once(':').map_or("", |(h, _)| h);
    if !activemap_view::live::is_loopback_host(host) {
        eprintln!(
            "activemap: WARNING: the live view listens on {address}, not on loopback: anyone who \
             can reach it can watch the run"
        );
    }
    eprintln!(
        "activemap: live view at {} (Foxglove: Open connection → Foxglove WebSocket)",
        live.url()
    );
    Ok(live)
}

/// Every message, except a Gaussian map whose keyframe is the one last shown on its topic (the
/// converter shows a map only when a keyframe was added, and a copy of each map costs MBs).
#[derive(Debug, Default)]
struct NewKeyframes {
    last_keyframe: BTreeMap<String, u64>,
}

impl DerivedFilter for NewKeyframes {
    fn wants(&mut self, topic: &str, kind: MessageKind, bytes: &[u8]) -> bool {
        if kind != MessageKind::GaussianMap {
            return true;
        }
        let Ok(header) = GaussianMapHeader::read(bytes) else {
            return true; // the converter reports what is wrong with it
        };
        let last = self
            .last_keyframe
            .insert(topic.to_string(), header.keyframe_id);
        last != Some(header.keyframe_id)
    }
}

/// The converter into Foxglove's schemas, and the live view it feeds.
struct FoxgloveChannels {
    converter: ViewConverter,
    live: Option<LiveView>,
}

impl DerivedChannels for FoxgloveChannels {
    fn channels(&self) -> Vec<DerivedChannel> {
        ViewTopic::ALL
            .iter()
            .map(|topic| {
                let schema = topic.schema();
                DerivedChannel {
                    topic: topic.topic().to_string(),
                    schema_name: schema.name.to_string(),
                    schema_encoding: schema.encoding.to_string(),
                    schema_data: schema.data.to_vec(),
                    message_encoding: VIEW_ENCODING.to_string(),
                }
            })
            .collect()
    }

    fn convert(
        &mut self,
        topic: &str,
        kind: MessageKind,
        bytes: &[u8],
        log_time_ns: u64,
    ) -> Result<Vec<DerivedMessage>, String> {
        let shown = self
            .converter
            .convert(topic, kind, bytes, log_time_ns)
            .map_err(|e| e.to_string())?;
        Ok(shown
            .into_iter()
            .map(|m| {
                if let Some(live) = &self.live {
                    live.publish(&m);
                }
                DerivedMessage {
                    topic: m.topic.topic().to_string(),
                    data: m.data,
                    log_time_ns: m.log_time_ns,
                }
            })
            .collect())
    }

    fn finish(self: Box<Self>) {
        if let Some(live) = self.live {
            live.stop();
        }
    }
}
