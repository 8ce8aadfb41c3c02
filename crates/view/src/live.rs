//! The live view: the view channels served over the Foxglove WebSocket protocol while a run goes
//! on (`activemap run … --view`), so Foxglove connects to `ws://127.0.0.1:8765` and watches.
//!
//! Loopback by default; another address only when the user names it. The server runs on a
//! tokio runtime of its own with one worker thread, so it takes little from the operators.

use std::collections::BTreeMap;
use std::sync::Arc;

use foxglove::{ChannelBuilder, Context, PartialMetadata, RawChannel, WebSocketServer};
use thiserror::Error;

use crate::convert::ViewMessage;
use crate::topics::{VIEW_ENCODING, ViewTopic};

/// Where the live view listens unless told otherwise (Foxglove's default port, on loopback).
pub const DEFAULT_LIVE_ADDRESS: &str = "127.0.0.1:8765";

/// The live view could not start.
#[derive(Debug, Error)]
pub enum LiveViewError {
    /// The address is not `HOST:PORT`.
    #[error("live view: `{0}` is not HOST:PORT (e.g. 127.0.0.1:8765)")]
    BadAddress(String),
    /// The runtime or the server failed to start (e.g. the port is taken).
    #[error("live view: cannot serve on {address}: {reason}")]
    Start {
        /// The address asked for.
        address: String,
        /// Why.
        reason: String,
    },
}

/// A running live view server with one channel per [`ViewTopic`].
pub struct LiveView {
    /// Held for the server's life: the server and the channels keep only weak references to
    /// their context, and a dropped context advertises nothing to clients that connect.
    _context: Arc<Context>,
    channels: BTreeMap<ViewTopic, Arc<RawChannel>>,
    server: Option<foxglove::WebSocketServerHandle>,
    runtime: Option<tokio::runtime::Runtime>,
    host: String,
    port: u16,
}

impl std::fmt::Debug for LiveView {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("LiveView")
            .field("host", &self.host)
            .field("port", &self.port)
            .finish_non_exhaustive()
    }
}

/// True when `host` is a loopback address or `localhost`.
pub fn is_loopback_host(host: &str) -> bool {
    host == "localhost"
        || host
            .trim_matches(['[', ']'])
            .parse::<std::net::IpAddr>()
            .is_ok_and(|ip| ip.is_loopback())
}

impl LiveView {
    /// Serve on `address` (`HOST:PORT`; port 0 picks a free one). The caller warns when the host
    /// is not loopback ([`is_loopback_host`]).
    pub fn start(address: &str) -> Result<Self, LiveViewError> {
        let (host, port) = address
            .rsplit_once(':')
            .and_then(|(h, p)| Some((h.trim_matches(['[', ']']), p.parse::<u16>().ok()?)))
            .filter(|(h, _)| !h.is_empty())
            .ok_or_else(|| LiveViewError::BadAddress(address.to_string()))?;
        let start_err = |reason: String| LiveViewError::Start {
            address: address.to_string(),
            reason,
        };
        let runtime = tokio::runtime::Builder::new_multi_thread()
            .worker_threads(1)
            .thread_name("live-view")
            .enable_all()
            .build()
            .map_err(|e| start_err(e.to_string()))?;
        let context = Context::new();
        let mut channels = BTreeMap::new();
        for topic in ViewTopic::ALL {
            let channel = ChannelBuilder::new(topic.topic())
                .schema(topic.schema())
                .message_encoding(VIEW_ENCODING)
                .context(&context)
                .build_raw()
                .map_err(|e| start_err(e.to_string()))?;
            channels.insert(topic, channel);
        }
        let server = WebSocketServer::new()
            .name("activemap")
            .bind(host, port)
            .context(&context)
            .tokio_runtime(runtime.handle())
            .start_blocking()
            .map_err(|e| start_err(e.to_string()))?;
        let port = server.port();
        Ok(Self {
            _context: context,
            channels,
            server: Some(server),
            runtime: Some(runtime),
            host: host.to_string(),
            port,
        })
    }

    /// The port it listens on.
    pub fn port(&self) -> u16 {
        self.port
    }

    /// The WebSocket URL to give Foxglove ("Open connection" → Foxglove WebSocket).
    pub fn url(&self) -> String {
        if self.host.contains(':') {
            format!("ws://[{}]:{}", self.host, self.port)
        } else {
            format!("ws://{}:{}", self.host, self.port)
        }
    }

    /// Number of connected clients.
    pub fn clients(&self) -> usize {
        self.server.as_ref().map_or(0, |s| s.client_count())
    }

    /// Send one view message to every subscribed client (nothing is buffered for absent ones).
    pub fn publish(&self, msg: &ViewMessage) {
        if let Some(channel) = self.channels.get(&msg.topic) {
            channel.log_with_meta(&msg.data, PartialMetadata::with_log_time(msg.log_time_ns));
        }
    }

    /// Stop the server and close its connections.
    pub fn stop(mut self) {
        self.shutdown();
    }

    fn shutdown(&mut self) {
        if let (Some(server), Some(runtime)) = (self.server.take(), self.runtime.as_ref()) {
            let handle = server.stop();
            runtime.block_on(handle.wait());
        }
        for channel in self.channels.values() {
            channel.close();
        }
        if let Some(runtime) = self.runtime.take() {
            runtime.shutdown_timeout(std::time::Duration::from_secs(2));
        }
    }
}

impl Drop for LiveView {
    fn drop(&mut self) {
        self.shutdown();
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn addresses_are_checked_and_loopback_is_recognised() {
        assert!(matches!(
            LiveView::start("8765"),
            Err(LiveViewError::BadAddress(_))
        ));
        assert!(matches!(
            LiveView::start("127.0.0.1:notaport"),
            Err(LiveViewError::BadAddress(_))
        ));
        assert!(is_loopback_host("127.0.0.1"));
        assert!(is_loopback_host("127.0.0.3"));
        assert!(is_loopback_host("localhost"));
        assert!(is_loopback_host("[::1]"));
        assert!(!is_loopback_host("0.0.0.0"));
        assert!(!is_loopback_host("10.0.0.1"));
    }

    #[test]
    fn a_taken_port_is_a_clear_error() {
        let first = LiveView::start("127.0.0.1:0").unwrap();
        let taken = format!("127.0.0.1:{}", first.port());
        let err = LiveView::start(&taken).unwrap_err().to_string();
        assert!(err.contains(&taken), "{err}");
        first.stop();
    }

    /// A client speaking the Foxglove WebSocket protocol (`foxglove.sdk.v1`) to a live view:
    /// it is told about every view channel with its schema, subscribes to one, and receives
    /// exactly the bytes published on it afterwards (and nothing of the channel it did not ask
    /// for).
    #[test]
    fn a_client_sees_every_channel_subscribes_and_receives_what_is_published() {
        use tungstenite::Message;
        use tungstenite::client::IntoClientRequest;

        let live = LiveView::start("127.0.0.1:0").unwrap();
        let mut request = live.url().into_client_request().unwrap();
        request
            .headers_mut()
            .insert("Sec-WebSocket-Protocol", "foxglove.sdk.v1".parse().unwrap());
        let (mut socket, response) = tungstenite::connect(request).unwrap();
        assert_eq!(
            response.headers()["Sec-WebSocket-Protocol"],
            "foxglove.sdk.v1"
        );
        if let tungstenite::stream::MaybeTlsStream::Plain(s) = socket.get_ref() {
            s.set_read_timeout(Some(std::time::Duration::from_secs(10)))
                .unwrap();
        }
        // serverInfo, then the advertisement of all twelve channels.
        let mut channel_of = BTreeMap::new();
        while channel_of.len() < ViewTopic::ALL.len() {
            let Message::Text(text) = socket.read().unwrap() else {
                continue;
            };
            let v: serde_json::Value = serde_json::from_str(&text).unwrap();
            if v["op"] != "advertise" {
                continue;
            }
            for ch in v["channels"].as_array().unwrap() {
                let topic = ViewTopic::from_topic(ch["topic"].as_str().unwrap()).unwrap();
                assert_eq!(ch["encoding"], VIEW_ENCODING);
                assert_eq!(ch["schemaName"], topic.schema().name);
                channel_of.insert(topic, ch["id"].as_u64().unwrap());
            }
        }
        assert_eq!(live.clients(), 1);
        let subscribe = serde_json::json!({
            "op": "subscribe",
            "subscriptions": [{ "id": 7, "channelId": channel_of[&ViewTopic::EstimatedPose] }],
        });
        socket.send(Message::text(subscribe.to_string())).unwrap();
        // The subscription takes effect asynchronously: publish until the message arrives.
        if let tungstenite::stream::MaybeTlsStream::Plain(s) = socket.get_ref() {
            s.set_read_timeout(Some(std::time::Duration::from_millis(200)))
                .unwrap();
        }
        let payload: Vec<u8> = (0..=255).collect();
        for attempt in 0.. {
            assert!(attempt < 100, "nothing arrived on the subscription");
            for (topic, time) in [(ViewTopic::Log, 1), (ViewTopic::EstimatedPose, 42)] {
                live.publish(&ViewMessage {
                    topic,
                    log_time_ns: time,
                    data: payload.clone(),
                });
            }
            let Ok(Message::Binary(data)) = socket.read() else {
                continue;
            };
            // Message data: opcode 1, subscription id, log time, payload.
            assert_eq!(data[0], 1);
            assert_eq!(u32::from_le_bytes(data[1..5].try_into().unwrap()), 7);
            assert_eq!(u64::from_le_bytes(data[5..13].try_into().unwrap()), 42);
            assert_eq!(&data[13..], payload.as_slice());
            break;
        }
        let _ = socket.close(None);
        live.stop();
    }
}
