//! Channels derived from the recorded messages: the extension point through which the CLI plugs a
//! view of the run (the Foxglove view of `activemap-view`) into the recorder, so that the runtime
//! itself knows nothing of viewers, images or maps.
//!
//! The recorder hands each message to a [`DerivedFilter`] on its own thread (it must be cheap: it
//! decides whether the message is worth a copy), and the messages it accepts to the
//! [`DerivedChannels`] converter on a thread of its own, whose output it writes to the file on the
//! channels the converter declared. A converter that is behind loses derived messages, never an
//! exact one.

use std::fmt::Debug;

use activemap_schemas::MessageKind;

use crate::RuntimeError;

/// A channel of derived messages, declared once when the recording starts.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct DerivedChannel {
    /// MCAP topic, e.g. `/view/camera/color`.
    pub topic: String,
    /// Schema name, e.g. `foxglove.CompressedImage`.
    pub schema_name: String,
    /// Schema encoding, e.g. `protobuf`.
    pub schema_encoding: String,
    /// Schema data (e.g. a serialised `FileDescriptorSet`).
    pub schema_data: Vec<u8>,
    /// Message encoding of the channel, e.g. `protobuf`.
    pub message_encoding: String,
}

/// One derived message, for one of the declared channels.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct DerivedMessage {
    /// Topic of a declared [`DerivedChannel`].
    pub topic: String,
    /// Encoded message.
    pub data: Vec<u8>,
    /// Log and publish time of the message, in nanoseconds since the Unix epoch.
    pub log_time_ns: u64,
}

/// Decides, on the recorder's thread, which recorded messages the converter sees.
pub trait DerivedFilter: Send {
    /// True when the message (`topic` = `node/output`, of `kind`) should be converted.
    fn wants(&mut self, topic: &str, kind: MessageKind, bytes: &[u8]) -> bool;
}

/// Turns recorded messages into derived ones, on a thread of its own.
pub trait DerivedChannels: Send {
    /// The channels this converter writes (declared in the file before any message).
    fn channels(&self) -> Vec<DerivedChannel>;
    /// The derived messages of one recorded message (received at `log_time_ns`). An error is
    /// counted and reported once per topic; the recording goes on.
    fn convert(
        &mut self,
        topic: &str,
        kind: MessageKind,
        bytes: &[u8],
        log_time_ns: u64,
    ) -> Result<Vec<DerivedMessage>, String>;
    /// The run's recording ends (e.g. stop serving a live view).
    fn finish(self: Box<Self>) {}
}

/// The two halves of one run's derived channels.
pub struct Derived {
    /// Runs on the recorder's thread.
    pub filter: Box<dyn DerivedFilter>,
    /// Runs on a thread of its own.
    pub channels: Box<dyn DerivedChannels>,
}

/// Makes the derived channels of each run: registered by the CLI on the launcher and on the
/// daemons (`LaunchOptions::derived`), so a build without a viewer records the exact channels
/// only.
pub trait DerivedFactory: Send + Sync + Debug {
    /// The derived channels of one run; with `live`, also served live on that `HOST:PORT`
    /// (`--view`).
    fn start(&self, live: Option<&str>) -> Result<Derived, RuntimeError>;
}
