//! Transports: iceoryx2 shared memory (large payloads between processes of one machine, written in
//! place into loaned samples) and Zenoh (small messages, and anything crossing machines).
//!
//! Conventions:
//! - iceoryx2 service and Zenoh key of output `node/output` in run `R`: `activemap/R/node/output`,
//!   so two runs never collide;
//! - every message carries the producer's sequence number (1, 2, ...): iceoryx2 user header or
//!   Zenoh attachment. A zero-length payload is end-of-stream (the producer finished);
//! - Zenoh: explicit endpoints only, multicast scouting off; nodes are clients of their machine's
//!   router (the launcher or daemon), routers connect to each other.

use std::time::Duration;

use iceoryx2::port::publisher::Publisher as IoxPublisher;
use iceoryx2::port::subscriber::Subscriber as IoxSubscriber;
use iceoryx2::prelude::*;
use zenoh::Wait;
use zenoh::handlers::{FifoChannel, FifoChannelHandler, RingChannel, RingChannelHandler};
use zenoh::qos::CongestionControl;
use zenoh::sample::Sample;

use crate::RuntimeError;
use crate::dataflow::DropPolicy;

/// Initial shared-memory slice size of a publisher; samples grow (power of two) past it.
pub const SHM_INITIAL_SLICE: usize = 1 << 20;

/// iceoryx2 service / Zenoh key of `node/output` in run `run_id`.
pub fn topic_key(run_id: &str, node: &str, output: &str) -> String {
    format!("activemap/{run_id}/{node}/{output}")
}

fn iox_err(what: &str, e: impl std::fmt::Debug) -> RuntimeError {
    RuntimeError::Transport(format!("iceoryx2: {what}: {e:?}"))
}

fn zenoh_err(what: &str, e: impl std::fmt::Display) -> RuntimeError {
    RuntimeError::Transport(format!("zenoh: {what}: {e}"))
}

/// Create an iceoryx2 node (signal handling left to the runtime) and remove the shared-memory
/// resources of dead nodes (e.g. after a `kill -9`), so a new run starts clean.
pub fn iox_node(name: &str) -> Result<Node<ipc::Service>, RuntimeError> {
    // iceoryx2 warns on every start that it uses its default config; keep only real errors.
    set_log_level(LogLevel::Error);
    let node_name = NodeName::new(name).map_err(|e| iox_err("node name", e))?;
    let node = NodeBuilder::new()
        .name(&node_name)
        .signal_handling_mode(SignalHandlingMode::Disabled)
        .create::<ipc::Service>()
        .map_err(|e| iox_err("create node", e))?;
    node.try_cleanup_dead_nodes();
    Ok(node)
}

/// Explicit iceoryx2 limits of one shared-memory topic. Every participant opens the service with
/// the same values (derived from the dataflow), so `open_or_create` never conflicts.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct ShmLimits {
    /// Subscribers allowed (consumers + recorder + spare).
    pub max_subscribers: usize,
    /// Publishers allowed (the producer, and a restarted producer while the old one is cleaned).
    pub max_publishers: usize,
    /// Per-subscriber queue depth.
    pub buffer: usize,
    /// Drop oldest when full (true) or apply back-pressure (false).
    pub safe_overflow: bool,
}

/// Queue depth of a topic that no node consumes: only the recorder reads it, and with a queue
/// of one it lost 800×800 frames published every 50 ms while it compressed the previous one on
/// a loaded machine (nothing applies back-pressure to such a topic).
pub const RECORDER_ONLY_BUFFER: usize = 8;

impl ShmLimits {
    /// Limits for a topic with these consumer queue sizes and policies (none: the recorder's
    /// [`RECORDER_ONLY_BUFFER`]).
    pub fn for_consumers(queues: &[(usize, DropPolicy)]) -> Self {
        Self {
            max_subscribers: queues.len() + 2,
            max_publishers: 2,
            buffer: queues
                .iter()
                .map(|q| q.0)
                .max()
                .unwrap_or(RECORDER_ONLY_BUFFER)
                .max(1),
            safe_overflow: queues.iter().all(|q| q.1 == DropPolicy::DropOldest),
        }
    }
}

fn iox_service(
    node: &Node<ipc::Service>,
    key: &str,
    limits: ShmLimits,
) -> Result<
    iceoryx2::service::port_factory::publish_subscribe::PortFactory<ipc::Service, [u8], u64>,
    RuntimeError,
> {
    let name = ServiceName::new(key).map_err(|e| iox_err("service name", e))?;
    node.service_builder(&name)
        .publish_subscribe::<[u8]>()
        .user_header::<u64>()
        .payload_alignment(Alignment::new(8).expect("8 is a power of two"))
        .max_publishers(limits.max_publishers)
        .max_subscribers(limits.max_subscribers)
        .subscriber_max_buffer_size(limits.buffer)
        .subscriber_max_borrowed_samples(2)
        .history_size(0)
        .enable_safe_overflow(limits.safe_overflow)
        .open_or_create()
        .map_err(|e| iox_err(&format!("open service {key}"), e))
}

/// Publisher of a shared-memory topic.
pub struct ShmPublisher {
    publisher: IoxPublisher<ipc::Service, [u8], u64>,
}

impl std::fmt::Debug for ShmPublisher {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str("ShmPublisher")
    }
}

impl ShmPublisher {
    /// Open (or create) the service `key` and a publisher on it.
    pub fn create(
        node: &Node<ipc::Service>,
        key: &str,
        limits: ShmLimits,
    ) -> Result<Self, RuntimeError> {
        let service = iox_service(node, key, limits)?;
        let backpressure = if limits.safe_overflow {
            BackpressureStrategy::DiscardData
        } else {
            BackpressureStrategy::RetryUntilDelivered
        };
        let publisher = service
            .publisher_builder()
            .initial_max_slice_len(SHM_INITIAL_SLICE)
            .allocation_strategy(AllocationStrategy::PowerOfTwo)
            .max_loaned_samples(2)
            .backpressure_strategy(backpressure)
            .create()
            .map_err(|e| iox_err(&format!("publisher on {key}"), e))?;
        Ok(Self { publisher })
    }

    /// Loan a `len`-byte sample, let `fill` write it in place, send it with sequence number `seq`.
    pub fn loan_and_send(
        &self,
        seq: u64,
        len: usize,
        fill: &mut dyn FnMut(&mut [u8]) -> anyhow::Result<()>,
    ) -> Result<(), RuntimeError> {
        let sample = self
            .publisher
            .loan_slice_uninit(len)
            .map_err(|e| iox_err("loan", e))?;
        // SAFETY: the data segment is shared memory the kernel zero-fills when it is created and that
        // only ever holds bytes written by earlier samples, so every byte is initialised; u8 has no
        // invalid bit patterns. This avoids a 4.5 MB memset per frame on the in-place path.
        let mut sample = unsafe { sample.assume_init() };
        *sample.user_header_mut() = seq;
        fill(sample.payload_mut()).map_err(|e| RuntimeError::Operator(format!("{e:#}")))?;
        sample.send().map_err(|e| iox_err("send", e))?;
        Ok(())
    }

    /// Copy `bytes` into a loaned sample and send it.
    pub fn send_copy(&self, seq: u64, bytes: &[u8]) -> Result<(), RuntimeError> {
        let sample = self
            .publisher
            .loan_slice_uninit(bytes.len())
            .map_err(|e| iox_err("loan", e))?;
        let mut sample = sample.write_from_slice(bytes);
        *sample.user_header_mut() = seq;
        sample.send().map_err(|e| iox_err("send", e))?;
        Ok(())
    }
}

/// Subscriber of a shared-memory topic.
pub struct ShmSubscriber {
    subscriber: IoxSubscriber<ipc::Service, [u8], u64>,
}

impl ShmSubscriber {
    /// Open (or create) the service `key` and subscribe with queue depth `buffer`.
    pub fn create(
        node: &Node<ipc::Service>,
        key: &str,
        limits: ShmLimits,
        buffer: usize,
    ) -> Result<Self, RuntimeError> {
        let service = iox_service(node, key, limits)?;
        let subscriber = service
            .subscriber_builder()
            .buffer_size(buffer.min(limits.buffer).max(1))
            .create()
            .map_err(|e| iox_err(&format!("subscriber on {key}"), e))?;
        Ok(Self { subscriber })
    }

    /// Hand the next sample (sequence number, bytes borrowed from shared memory) to `f`.
    /// Returns false when no sample is waiting.
    pub fn try_recv(&self, f: &mut dyn FnMut(u64, &[u8])) -> Result<bool, RuntimeError> {
        match self
            .subscriber
            .receive()
            .map_err(|e| iox_err("receive", e))?
        {
            Some(sample) => {
                f(*sample.user_header(), sample.payload());
                Ok(true)
            }
            None => Ok(false),
        }
    }
}

/// Zenoh session settings of one process.
#[derive(Debug, Clone, Default, serde::Serialize, serde::Deserialize)]
pub struct ZenohSettings {
    /// `client` (nodes), `peer` or `router` (launcher, daemons).
    pub mode: String,
    /// Endpoints to listen on.
    pub listen: Vec<String>,
    /// Endpoints to connect to.
    pub connect: Vec<String>,
    /// `transport/link/tls` settings, verbatim.
    pub tls: Option<serde_json::Value>,
}

/// Open a Zenoh session with explicit endpoints and multicast scouting off.
pub fn open_zenoh(settings: &ZenohSettings) -> Result<zenoh::Session, RuntimeError> {
    let mut config = zenoh::Config::default();
    let set = |config: &mut zenoh::Config, key: &str, value: String| {
        config
            .insert_json5(key, &value)
            .map_err(|e| zenoh_err(&format!("config {key}={value}"), e))
    };
    set(
        &mut config,
        "mode",
        serde_json::to_string(&settings.mode).expect("string"),
    )?;
    set(&mut config, "scouting/multicast/enabled", "false".into())?;
    set(&mut config, "scouting/gossip/enabled", "false".into())?;
    set(
        &mut config,
        "listen/endpoints",
        serde_json::to_string(&settings.listen).expect("strings"),
    )?;
    set(
        &mut config,
        "connect/endpoints",
        serde_json::to_string(&settings.connect).expect("strings"),
    )?;
    if settings.mode != "client" {
        // Keep retrying connections to other machines' routers that are not up yet.
        set(&mut config, "connect/timeout_ms", "-1".into())?;
        set(&mut config, "connect/exit_on_failure", "false".into())?;
    }
    if let Some(tls) = &settings.tls {
        set(&mut config, "transport/link/tls", tls.to_string())?;
    }
    zenoh::open(config)
        .wait()
        .map_err(|e| zenoh_err("open session", e))
}

/// Publisher of a Zenoh topic (reliable, blocking congestion control: nothing dropped in transit).
pub struct ZenohPublisher {
    publisher: zenoh::pubsub::Publisher<'static>,
}

impl ZenohPublisher {
    /// Declare a publisher on `key`.
    pub fn create(session: &zenoh::Session, key: &str) -> Result<Self, RuntimeError> {
        let publisher = session
            .declare_publisher(key.to_string())
            .congestion_control(CongestionControl::Block)
            .wait()
            .map_err(|e| zenoh_err(&format!("publisher on {key}"), e))?;
        Ok(Self { publisher })
    }

    /// Send `bytes` with sequence number `seq`.
    pub fn send(&self, seq: u64, bytes: Vec<u8>) -> Result<(), RuntimeError> {
        self.publisher
            .put(bytes)
            .attachment(seq.to_le_bytes().to_vec())
            .wait()
            .map_err(|e| zenoh_err("put", e))
    }
}

/// Subscriber of a Zenoh topic with a bounded queue (ring: drop oldest; FIFO: back-pressure).
pub enum ZenohSubscriber {
    /// Drop-oldest queue.
    Ring(zenoh::pubsub::Subscriber<RingChannelHandler<Sample>>),
    /// Blocking queue.
    Fifo(zenoh::pubsub::Subscriber<FifoChannelHandler<Sample>>),
}

impl ZenohSubscriber {
    /// Subscribe to `key` (wildcards allowed) with queue depth `queue`.
    pub fn create(
        session: &zenoh::Session,
        key: &str,
        queue: usize,
        drop: DropPolicy,
    ) -> Result<Self, RuntimeError> {
        let builder = session.declare_subscriber(key.to_string());
        Ok(match drop {
            DropPolicy::DropOldest => ZenohSubscriber::Ring(
                builder
                    .with(RingChannel::new(queue.max(1)))
                    .wait()
                    .map_err(|e| zenoh_err(&format!("subscriber on {key}"), e))?,
            ),
            DropPolicy::Block => ZenohSubscriber::Fifo(
                builder
                    .with(FifoChannel::new(queue.max(1)))
                    .wait()
                    .map_err(|e| zenoh_err(&format!("subscriber on {key}"), e))?,
            ),
        })
    }

    /// Take the next sample, if any, without blocking; or wait up to `timeout` when given.
    pub fn recv(&self, timeout: Option<Duration>) -> Result<Option<Sample>, RuntimeError> {
        let r = match (self, timeout) {
            (ZenohSubscriber::Ring(s), None) => s.try_recv(),
            (ZenohSubscriber::Ring(s), Some(t)) => s.recv_timeout(t),
            (ZenohSubscriber::Fifo(s), None) => s.try_recv(),
            (ZenohSubscriber::Fifo(s), Some(t)) => s.recv_timeout(t),
        };
        r.map_err(|e| zenoh_err("receive", e))
    }

    /// Hand the next sample (sequence number, bytes) to `f`; false when none is waiting.
    pub fn try_recv(&self, f: &mut dyn FnMut(u64, &[u8])) -> Result<bool, RuntimeError> {
        match self.recv(None)? {
            Some(sample) => {
                f(sample_seq(&sample), &sample.payload().to_bytes());
                Ok(true)
            }
            None => Ok(false),
        }
    }
}

/// Sequence number carried in a Zenoh sample's attachment (0 when absent).
pub fn sample_seq(sample: &Sample) -> u64 {
    sample
        .attachment()
        .and_then(|a| <[u8; 8]>::try_from(a.to_bytes().as_ref()).ok())
        .map(u64::from_le_bytes)
        .unwrap_or(0)
}
