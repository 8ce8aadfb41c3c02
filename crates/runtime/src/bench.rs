//! Transport benchmark (`activemap bench transport`): one-way latency of an 800×800 RGB-D frame
//! (≈4.5 MB) between two processes over iceoryx2 (frame copied in), iceoryx2 written in place,
//! Zenoh over TCP loopback, and an in-process memcpy as the floor.
//!
//! The parent process subscribes and measures; it spawns the publisher as
//! `<exe> bench transport --peer <path> --key <key> ...`, which calls [`transport_peer`].
//! Latency = receive time − send time on CLOCK_MONOTONIC (shared by all processes of the machine).

use std::path::Path;
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

use activemap_schemas::{RgbdFrame, RgbdFrameHeader, RgbdFrameView};

use crate::RuntimeError;
use crate::dataflow::DropPolicy;
use crate::transport::{
    ShmLimits, ShmPublisher, ShmSubscriber, ZenohPublisher, ZenohSettings, ZenohSubscriber,
};
use crate::transport::{iox_node, open_zenoh};

/// One result row.
#[derive(Debug, Clone, PartialEq)]
pub struct BenchRow {
    /// Path name: `memcpy`, `iceoryx2`, `iceoryx2_inplace`, `zenoh`.
    pub path: String,
    /// Frames measured.
    pub samples: usize,
    /// Median one-way latency, µs.
    pub median_us: f64,
    /// 99th percentile latency, µs.
    pub p99_us: f64,
    /// Frame bytes / median latency, GB/s.
    pub throughput_gb_s: f64,
}

/// Options of [`run_transport`].
#[derive(Debug, Clone)]
pub struct TransportBenchOptions {
    /// Frames measured per path (after 10 warm-up frames).
    pub frames: usize,
    /// Frame side in pixels (800 → 4.48 MB).
    pub size: u32,
    /// Gap between frames, so queues never build up.
    pub period: Duration,
}

impl Default for TransportBenchOptions {
    fn default() -> Self {
        Self {
            frames: 200,
            size: 800,
            period: Duration::from_millis(5),
        }
    }
}

const WARMUP: usize = 10;

/// CLOCK_MONOTONIC in nanoseconds (comparable across processes).
pub fn monotonic_ns() -> u64 {
    let mut ts = libc::timespec {
        tv_sec: 0,
        tv_nsec: 0,
    };
    // SAFETY: clock_gettime writes into the timespec we own.
    unsafe { libc::clock_gettime(libc::CLOCK_MONOTONIC, &mut ts) };
    ts.tv_sec as u64 * 1_000_000_000 + ts.tv_nsec as u64
}

/// A deterministic test frame of `size`×`size` pixels.
pub fn test_frame(size: u32) -> RgbdFrame {
    let n = (size * size) as usize;
    RgbdFrame {
        header: RgbdFrameHeader::new(
            0,
            0.0,
            [
                400.0,
                400.0,
                size as f64 / 2.0 - 0.5,
                size as f64 / 2.0 - 0.5,
            ],
            size,
            size,
        ),
        rgb: (0..n * 3)
            .map(|i| (i.wrapping_mul(2654435761) >> 13) as u8)
            .collect(),
        depth: (0..n).map(|i| 0.5 + (i % 997) as f32 * 0.004).collect(),
    }
}

/// Send time is carried in the frame id field of the header (bytes 8..16).
fn stamp_of(bytes: &[u8]) -> Option<u64> {
    Some(u64::from_le_bytes(bytes.get(8..16)?.try_into().ok()?))
}

fn row(path: &str, mut lat_ns: Vec<u64>, bytes: usize) -> BenchRow {
    lat_ns.sort_unstable();
    let pick = |q: f64| {
        if lat_ns.is_empty() {
            f64::NAN
        } else {
            lat_ns[((lat_ns.len() - 1) as f64 * q).round() as usize] as f64 / 1000.0
        }
    };
    let median_us = pick(0.5);
    BenchRow {
        path: path.into(),
        samples: lat_ns.len(),
        median_us,
        p99_us: pick(0.99),
        throughput_gb_s: bytes as f64 / (median_us * 1e-6) / 1e9,
    }
}

/// Run every path and return one row each. `exe` is the `activemap` binary used as publisher.
pub fn run_transport(
    exe: &Path,
    opts: &TransportBenchOptions,
) -> Result<Vec<BenchRow>, RuntimeError> {
    let frame = test_frame(opts.size);
    let bytes = frame
        .encode()
        .map_err(|e| RuntimeError::Other(e.to_string()))?;
    let mut rows = vec![memcpy_row(&bytes, opts.frames)];
    for path in ["iceoryx2", "iceoryx2_inplace", "zenoh"] {
        rows.push(measure_path(exe, path, &bytes, opts)?);
    }
    Ok(rows)
}

fn memcpy_row(bytes: &[u8], frames: usize) -> BenchRow {
    let mut dst = vec![0u8; bytes.len()];
    let mut lat = Vec::with_capacity(frames);
    for i in 0..frames + WARMUP {
        let t0 = Instant::now();
        dst.copy_from_slice(std::hint::black_box(bytes));
        std::hint::black_box(&mut dst);
        if i >= WARMUP {
            lat.push(t0.elapsed().as_nanos() as u64);
        }
    }
    row("memcpy", lat, bytes.len())
}

fn measure_path(
    exe: &Path,
    path: &str,
    bytes: &[u8],
    opts: &TransportBenchOptions,
) -> Result<BenchRow, RuntimeError> {
    let key = format!("activemap/bench{}/{path}", crate::launch::new_run_id());
    let total = opts.frames + WARMUP;
    let limits = ShmLimits {
        max_subscribers: 2,
        max_publishers: 1,
        buffer: 4,
        safe_overflow: true,
    };
    let mut endpoint = String::new();
    enum Sub {
        Shm(
            ShmSubscriber,
            // Keeps the iceoryx2 node alive while subscribed.
            #[allow(dead_code)] iceoryx2::prelude::Node<iceoryx2::prelude::ipc::Service>,
        ),
        // Keeps the router session alive while subscribed.
        Zenoh(ZenohSubscriber, #[allow(dead_code)] zenoh::Session),
    }
    let sub = if path == "zenoh" {
        endpoint = format!("tcp/127.0.0.1:{}", crate::launch::free_port("127.0.0.1")?);
        let session = open_zenoh(&ZenohSettings {
            mode: "router".into(),
            listen: vec![endpoint.clone()],
            connect: vec![],
            tls: None,
        })?;
        Sub::Zenoh(
            ZenohSubscriber::create(&session, &key, 8, DropPolicy::Block)?,
            session,
        )
    } else {
        let node = iox_node(&format!("bench-sub-{path}"))?;
        Sub::Shm(ShmSubscriber::create(&node, &key, limits, 4)?, node)
    };
    let mut child = Command::new(exe)
        .args([
            "bench",
            "transport",
            "--peer",
            path,
            "--key",
            &key,
            "--frames",
        ])
        .arg(total.to_string())
        .args(["--size", &opts.size.to_string(), "--period-us"])
        .arg(opts.period.as_micros().to_string())
        .args(["--endpoint", &endpoint])
        .stdin(Stdio::null())
        .stdout(Stdio::null())
        .spawn()
        .map_err(|e| {
            RuntimeError::Other(format!(
                "cannot start the bench publisher {}: {e}",
                exe.display()
            ))
        })?;
    let mut lat = Vec::with_capacity(total);
    let mut received = 0usize;
    let deadline = Instant::now() + Duration::from_secs(60) + opts.period * total as u32;
    let mut publisher_done = false;
    while received < total && Instant::now() < deadline {
        let mut got_one = None;
        let mut on_message = |_: u64, payload: &[u8]| {
            let now = monotonic_ns();
            // Check the frame is intact (header, sizes) without copying it.
            got_one = Some((
                now,
                stamp_of(payload),
                RgbdFrameView::parse(payload).is_ok(),
            ));
        };
        let got = match &sub {
            Sub::Shm(s, _) => s.try_recv(&mut on_message)?,
            Sub::Zenoh(z, _) => z.try_recv(&mut on_message)?,
        };
        if let Some((now, Some(sent), true)) = got_one {
            received += 1;
            if received > WARMUP {
                lat.push(now.saturating_sub(sent));
            }
        }
        if !got {
            if publisher_done {
                break;
            }
            // Once the publisher has exited, drain what is left, then stop.
            publisher_done = matches!(child.try_wait(), Ok(Some(_)));
            std::hint::spin_loop();
        }
    }
    let _ = child.kill();
    let _ = child.wait();
    if lat.is_empty() {
        return Err(RuntimeError::Other(format!(
            "bench {path}: no frame received"
        )));
    }
    Ok(row(path, lat, bytes.len()))
}

/// Publisher side of one path (runs in the child process).
pub fn transport_peer(
    path: &str,
    key: &str,
    frames: usize,
    size: u32,
    period: Duration,
    endpoint: &str,
) -> Result<(), RuntimeError> {
    let frame = test_frame(size);
    let bytes = frame
        .encode()
        .map_err(|e| RuntimeError::Other(e.to_string()))?;
    let limits = ShmLimits {
        max_subscribers: 2,
        max_publishers: 1,
        buffer: 4,
        safe_overflow: true,
    };
    // The send time is taken before any copy, so a path's latency includes its copy.
    let stamp = |buf: &mut [u8], t: u64| buf[8..16].copy_from_slice(&t.to_le_bytes());
    match path {
        "iceoryx2" | "iceoryx2_inplace" => {
            let node = iox_node(&format!("bench-pub-{path}"))?;
            let publisher = ShmPublisher::create(&node, key, limits)?;
            std::thread::sleep(Duration::from_millis(100));
            for i in 0..frames {
                let t = Instant::now();
                publisher.loan_and_send(i as u64 + 1, bytes.len(), &mut |buf| {
                    let t0 = monotonic_ns();
                    if path == "iceoryx2" {
                        buf.copy_from_slice(&bytes);
                        stamp(buf, t0);
                    } else {
                        // In place: the producer writes its header and stamps; the pixels are
                        // rendered straight into this buffer by a real producer (not timed here).
                        stamp(buf, t0);
                        buf[..8].copy_from_slice(&bytes[..8]);
                        buf[16..64].copy_from_slice(&bytes[16..64]);
                    }
                    Ok(())
                })?;
                std::thread::sleep(period.saturating_sub(t.elapsed()));
            }
        }
        "zenoh" => {
            let session = open_zenoh(&ZenohSettings {
                mode: "client".into(),
                listen: vec![],
                connect: vec![endpoint.to_string()],
                tls: None,
            })?;
            let publisher = ZenohPublisher::create(&session, key)?;
            std::thread::sleep(Duration::from_millis(500));
            for i in 0..frames {
                let t = Instant::now();
                let t0 = monotonic_ns();
                let mut buf = bytes.clone();
                stamp(&mut buf, t0);
                publisher.send(i as u64 + 1, buf)?;
                std::thread::sleep(period.saturating_sub(t.elapsed()));
            }
            std::thread::sleep(Duration::from_millis(200));
        }
        other => return Err(RuntimeError::Other(format!("unknown bench path `{other}`"))),
    }
    Ok(())
}

/// Text table plus one `transport <path> median_us <x> p99_us <y>` line per path.
pub fn format_rows(rows: &[BenchRow]) -> String {
    let mut s = format!(
        "{:<18} {:>8} {:>12} {:>12} {:>10}\n",
        "path", "frames", "median_us", "p99_us", "GB/s"
    );
    for r in rows {
        s.push_str(&format!(
            "{:<18} {:>8} {:>12.1} {:>12.1} {:>10.2}\n",
            r.path, r.samples, r.median_us, r.p99_us, r.throughput_gb_s
        ));
    }
    for r in rows {
        s.push_str(&format!(
            "transport {} median_us {:.1} p99_us {:.1}\n",
            r.path, r.median_us, r.p99_us
        ));
    }
    s
}
