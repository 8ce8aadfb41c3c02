//! The operator API: an operator reacts to events (inputs, timer ticks, stop) and sends outputs
//! through a [`Context`]. It never sees the transport.

use activemap_schemas::{MessageKind, Payload};

use crate::OperatorError;

/// What the operator wants after handling an event.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Flow {
    /// Keep running.
    Continue,
    /// Finish: the node sends end-of-stream on its outputs and exits successfully.
    Stop,
}

/// One message on an input port. The bytes are borrowed from the transport (zero-copy for
/// shared-memory inputs) and valid only during the event.
#[derive(Debug, Clone, Copy)]
pub struct Input<'a> {
    /// Input port name (as in the dataflow file).
    pub port: &'a str,
    /// Message kind of the port.
    pub kind: MessageKind,
    /// Sequence number assigned by the producer (1, 2, ...).
    pub seq: u64,
    /// Encoded payload.
    pub bytes: &'a [u8],
}

impl Input<'_> {
    /// Decode into an owned message, checking the port carries `T`.
    pub fn decode<T: Payload>(&self) -> Result<T, OperatorError> {
        if T::KIND != self.kind {
            return Err(OperatorError::WrongType {
                port: self.port.to_string(),
                declared: self.kind.name(),
                used: T::KIND.name(),
            });
        }
        T::from_bytes(self.bytes).map_err(|e| OperatorError::Decode {
            port: self.port.to_string(),
            source: e,
        })
    }
}

/// An event delivered to an operator.
#[derive(Debug, Clone, Copy)]
pub enum Event<'a> {
    /// A message arrived.
    Input(Input<'a>),
    /// A timer declared under `timers:` fired.
    Timer {
        /// Timer name.
        name: &'a str,
    },
    /// Every producer of this input port has finished (end of stream).
    InputClosed {
        /// Input port name.
        port: &'a str,
    },
    /// The node is stopping (Ctrl-C, SIGTERM, launcher stop, or all inputs closed). Last event.
    Stop,
}

/// Where a context's outputs go (the transport in a real run, a recorder in a replay).
pub trait OutputSink {
    /// Send an encoded payload on output `port` (index into the node's outputs).
    fn send(&mut self, port: usize, bytes: &[u8]) -> Result<(), OperatorError>;
    /// Loan a `len`-byte, 8-byte aligned buffer for output `port`, let `fill` write the payload in
    /// place, then send it.
    fn loan(
        &mut self,
        port: usize,
        len: usize,
        fill: &mut dyn FnMut(&mut [u8]) -> anyhow::Result<()>,
    ) -> Result<(), OperatorError>;
}

/// The `loan` of a sink without shared memory: fills a heap buffer of `len` bytes, 8-byte
/// aligned as a shared-memory sample is (large payloads are read in place as f32 and u64), and
/// hands it to `send`. The operator's own failure comes back as [`OperatorError::Fill`].
pub fn loan_on_heap<E>(
    len: usize,
    fill: &mut dyn FnMut(&mut [u8]) -> anyhow::Result<()>,
    send: impl FnOnce(&[u8]) -> Result<(), E>,
) -> Result<(), E>
where
    E: From<OperatorError>,
{
    let mut storage = vec![0u64; len.div_ceil(8)];
    let buf = &mut bytemuck::cast_slice_mut::<u64, u8>(&mut storage)[..len];
    fill(buf).map_err(|e| OperatorError::Fill(format!("{e:#}")))?;
    send(buf)
}

/// The operator's handle on its node: send outputs, read node facts.
pub struct Context<'a> {
    pub(crate) node_id: &'a str,
    pub(crate) outputs: &'a [(String, MessageKind)],
    pub(crate) sink: &'a mut dyn OutputSink,
    pub(crate) max_steps: Option<u64>,
}

impl<'a> Context<'a> {
    /// Build a context (used by the node runner and by replay).
    pub fn new(
        node_id: &'a str,
        outputs: &'a [(String, MessageKind)],
        sink: &'a mut dyn OutputSink,
        max_steps: Option<u64>,
    ) -> Self {
        Self {
            node_id,
            outputs,
            sink,
            max_steps,
        }
    }

    /// Id of the node this operator runs as.
    pub fn node_id(&self) -> &str {
        self.node_id
    }

    /// The run's step budget from `activemap run --max-steps`, if given.
    pub fn max_steps(&self) -> Option<u64> {
        self.max_steps
    }

    fn port(&self, name: &str, kind: Option<MessageKind>) -> Result<usize, OperatorError> {
        let index = self
            .outputs
            .iter()
            .position(|(n, _)| n == name)
            .ok_or_else(|| OperatorError::UnknownOutput {
                node: self.node_id.to_string(),
                port: name.to_string(),
            })?;
        if let Some(kind) = kind {
            let declared = self.outputs[index].1;
            if declared != kind {
                return Err(OperatorError::WrongType {
                    port: name.to_string(),
                    declared: declared.name(),
                    used: kind.name(),
                });
            }
        }
        Ok(index)
    }

    /// Encode and send a message on output `port`; the port must carry `T`.
    pub fn send<T: Payload>(&mut self, port: &str, message: &T) -> Result<(), OperatorError> {
        let index = self.port(port, Some(T::KIND))?;
        let bytes = message.to_bytes().map_err(|e| OperatorError::Encode {
            port: port.to_string(),
            source: e,
        })?;
        self.sink.send(index, &bytes)
    }

    /// Send an already encoded payload on output `port`.
    pub fn send_bytes(&mut self, port: &str, bytes: &[u8]) -> Result<(), OperatorError> {
        let index = self.port(port, None)?;
        self.sink.send(index, bytes)
    }

    /// Loan a `len`-byte buffer (8-byte aligned; shared memory when the port is a shared-memory
    /// topic) and let `fill` write the payload in place, e.g. with
    /// [`activemap_schemas::RgbdFrameMut::init`]. No copy is made on the shared-memory path.
    /// The buffer's prior content is unspecified (zeros or an earlier message): write all of it.
    pub fn loan(
        &mut self,
        port: &str,
        len: usize,
        mut fill: impl FnMut(&mut [u8]) -> anyhow::Result<()>,
    ) -> Result<(), OperatorError> {
        let index = self.port(port, None)?;
        self.sink.loan(index, len, &mut fill)
    }
}

/// A dataflow operator. Built once per node from its config, then fed events until it returns
/// [`Flow::Stop`] or receives [`Event::Stop`].
pub trait Operator: Sized + 'static {
    /// Per-operator config, deserialised from the node's `config:` (use `#[serde(deny_unknown_fields)]`).
    type Config: serde::de::DeserializeOwned;

    /// Create the operator.
    fn new(config: Self::Config, ctx: &mut Context<'_>) -> anyhow::Result<Self>;

    /// Handle one event.
    fn on_event(&mut self, event: Event<'_>, ctx: &mut Context<'_>) -> anyhow::Result<Flow>;
}
