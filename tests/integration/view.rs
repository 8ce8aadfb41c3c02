//! Issue 17: the view channels. A short episode runs with `--view` on a free loopback port; a
//! Foxglove WebSocket client (protocol `foxglove.sdk.v1`) subscribes while the robot
//! explores and receives a colour image and a pose. The recording is then read back with the
//! MCAP reference crate and with the official Python `mcap` reader (plus its protobuf decoder):
//! every view channel has its Foxglove schema and encoding, and one message of each decodes.

use std::collections::BTreeMap;
use std::net::TcpStream;
use std::path::PathBuf;
use std::process::Command;
use std::time::{Duration, Instant};

use activemap_view::ViewTopic;
use activemap_view::foxglove::Decode;
use activemap_view::foxglove::messages::{
    CameraCalibration, CompressedImage, FrameTransforms, Grid, Log, PointCloud, PoseInFrame,
    SceneUpdate,
};
use tungstenite::client::IntoClientRequest;
use tungstenite::{Message, WebSocket, stream::MaybeTlsStream};

use super::harness;

/// Python packages of the reader check, pinned.
const PYTHON_PACKAGES: [&str; 2] = ["mcap==1.6.0", "mcap-protobuf-support==0.6.0"];

/// Decodes one message of a view channel with the schema type it claims; the error names it.
fn decode_view(topic: ViewTopic, data: &[u8]) -> Result<String, String> {
    let err = |e: &dyn std::fmt::Display| format!("{}: {e}", topic.topic());
    Ok(match topic {
        ViewTopic::Color | ViewTopic::Depth => {
            let m = CompressedImage::decode(data).map_err(|e| err(&e))?;
            let img = image_size(&m.data).map_err(|e| err(&e))?;
            format!("{} {}x{}", m.format, img.0, img.1)
        }
        ViewTopic::Calibration => {
            let m = CameraCalibration::decode(data).map_err(|e| err(&e))?;
            format!("{}x{} fx {}", m.width, m.height, m.k[0])
        }
        ViewTopic::EstimatedPose | ViewTopic::TruePose => {
            let m = PoseInFrame::decode(data).map_err(|e| err(&e))?;
            let p = m.pose.and_then(|p| p.position).ok_or("no position")?;
            assert!(p.z.is_finite() && (p.z - 0.0).abs() < 3.0, "{p:?}");
            format!("{} ({:.2}, {:.2}, {:.2})", m.frame_id, p.x, p.y, p.z)
        }
        ViewTopic::Transforms => {
            let m = FrameTransforms::decode(data).map_err(|e| err(&e))?;
            let t = m.transforms.first().ok_or("no transform")?;
            format!("{} -> {}", t.parent_frame_id, t.child_frame_id)
        }
        ViewTopic::Occupancy => {
            let m = Grid::decode(data).map_err(|e| err(&e))?;
            assert_eq!(m.data.len() as u32 % m.column_count, 0);
            format!("{} columns", m.column_count)
        }
        ViewTopic::Map => {
            let m = PointCloud::decode(data).map_err(|e| err(&e))?;
            format!("{} points", m.data.len() / m.point_stride as usize)
        }
        ViewTopic::Frontiers | ViewTopic::Path | ViewTopic::Candidates => {
            let m = SceneUpdate::decode(data).map_err(|e| err(&e))?;
            format!("{} entities", m.entities.len())
        }
        ViewTopic::Log => {
            let m = Log::decode(data).map_err(|e| err(&e))?;
            format!("{}: {}", m.name, m.message)
        }
    })
}

fn image_size(data: &[u8]) -> Result<(u32, u32), String> {
    // PNG: width and height in the IHDR chunk; JPEG: in the first SOF0/SOF2 segment.
    if data.starts_with(b"\x89PNG") && data.len() >= 24 {
        let be = |o: usize| u32::from_be_bytes(data[o..o + 4].try_into().unwrap());
        return Ok((be(16), be(20)));
    }
    let mut i = 2;
    while i + 9 < data.len() {
        if data[i] != 0xFF {
            return Err("bad JPEG marker".into());
        }
        let marker = data[i + 1];
        let len = u16::from_be_bytes([data[i + 2], data[i + 3]]) as usize;
        if marker == 0xC0 || marker == 0xC2 {
            let h = u16::from_be_bytes([data[i + 5], data[i + 6]]) as u32;
            let w = u16::from_be_bytes([data[i + 7], data[i + 8]]) as u32;
            return Ok((w, h));
        }
        i += 2 + len;
    }
    Err("no image size found".into())
}

/// A Foxglove WebSocket client: connects (retrying until `deadline`), reads the advertised
/// channels, subscribes to `topics` and returns the first message of each.
fn live_client(url: &str, topics: &[ViewTopic], deadline: Instant) -> BTreeMap<ViewTopic, Vec<u8>> {
    let mut request = url.into_client_request().unwrap();
    request
        .headers_mut()
        .insert("Sec-WebSocket-Protocol", "foxglove.sdk.v1".parse().unwrap());
    let mut socket: WebSocket<MaybeTlsStream<TcpStream>> = loop {
        match tungstenite::connect(request.clone()) {
            Ok((socket, response)) => {
                assert_eq!(
                    response
                        .headers()
                        .get("Sec-WebSocket-Protocol")
                        .and_then(|v| v.to_str().ok()),
                    Some("foxglove.sdk.v1")
                );
                break socket;
            }
            Err(e) if Instant::now() < deadline => {
                eprintln!("live view not up yet: {e}");
                std::thread::sleep(Duration::from_millis(200));
            }
            Err(e) => panic!("cannot connect to the live view at {url}: {e}"),
        }
    };
    if let MaybeTlsStream::Plain(s) = socket.get_ref() {
        s.set_read_timeout(Some(Duration::from_secs(5))).unwrap();
    }
    let mut channel_of: BTreeMap<u64, ViewTopic> = BTreeMap::new();
    let mut got: BTreeMap<ViewTopic, Vec<u8>> = BTreeMap::new();
    let mut subscribed = false;
    while got.len() < topics.len() {
        assert!(
            Instant::now() < deadline,
            "live view: only {:?} received",
            got.keys()
        );
        let msg = match socket.read() {
            Ok(m) => m,
            Err(tungstenite::Error::Io(e))
                if matches!(
                    e.kind(),
                    std::io::ErrorKind::WouldBlock | std::io::ErrorKind::TimedOut
                ) =>
            {
                continue;
            }
            Err(e) => panic!("live view: {e}; advertised {channel_of:?}, subscribed {subscribed}"),
        };
        match msg {
            Message::Text(text) => {
                let v: serde_json::Value = serde_json::from_str(&text).unwrap();
                if v["op"] == "advertise" {
                    for ch in v["channels"].as_array().unwrap() {
                        let topic = ch["topic"].as_str().unwrap();
                        if let Some(t) = ViewTopic::from_topic(topic) {
                            assert_eq!(ch["encoding"], "protobuf", "{topic}");
                            assert_eq!(ch["schemaName"], t.schema().name, "{topic}");
                            channel_of.insert(ch["id"].as_u64().unwrap(), t);
                        }
                    }
                }
                if !subscribed && topics.iter().all(|t| channel_of.values().any(|c| c == t)) {
                    let subscriptions: Vec<serde_json::Value> = channel_of
                        .iter()
                        .filter(|(_, t)| topics.contains(t))
                        .map(|(id, _)| serde_json::json!({ "id": *id, "channelId": *id }))
                        .collect();
                    let sub =
                        serde_json::json!({ "op": "subscribe", "subscriptions": subscriptions });
                    socket.send(Message::text(sub.to_string())).unwrap();
                    subscribed = true;
                }
            }
            // Message data: opcode 1, subscription id (u32), log time (u64), payload.
            Message::Binary(data) if data.first() == Some(&1) && data.len() >= 13 => {
                let sub = u32::from_le_bytes(data[1..5].try_into().unwrap()) as u64;
                if let Some(t) = channel_of.get(&sub) {
                    got.entry(*t).or_insert_with(|| data[13..].to_vec());
                }
            }
            _ => {}
        }
    }
    let _ = socket.close(None);
    got
}

/// A venv with the pinned Python MCAP reader (see [`harness::python_venv`]).
fn python_with_mcap() -> Option<PathBuf> {
    harness::python_venv(
        "python-mcap-venv",
        "import importlib.metadata as m, sys; sys.exit(m.version('mcap') != '1.6.0' or m.version('mcap-protobuf-support') != '0.6.0')",
        &PYTHON_PACKAGES,
    )
}

/// The Python side: every view channel's schema name and encoding, and one decoded message of
/// each (protobuf, through the schema's own descriptors), as JSON lines.
const PYTHON_READER: &str = r#"
import json, sys
from mcap.reader import make_reader
from mcap_protobuf.decoder import DecoderFactory

with open(sys.argv[1], "rb") as f:
    reader = make_reader(f, decoder_factories=[DecoderFactory()])
    summary = reader.get_summary()
    views = {c.topic: c for c in summary.channels.values() if c.message_encoding == "protobuf"}
    for c in views.values():
        s = summary.schemas[c.schema_id]
        print(json.dumps({"channel": c.topic, "schema": s.name, "schema_encoding": s.encoding, "encoding": c.message_encoding}))
    seen = set()
    for schema, channel, message, decoded in reader.iter_decoded_messages(topics=list(views)):
        if channel.topic in seen:
            continue
        seen.add(channel.topic)
        fields = [f.name for f, _ in decoded.ListFields()]
        print(json.dumps({"message": channel.topic, "type": type(decoded).__name__, "fields": fields}))
        if len(seen) == len(views):
            break
"#;

/// The view channels an FBE episode fills: all but the Fisher candidates (declared, empty; their
/// conversion is tested in `activemap-view`).
const SHOWN_BY_FBE: [ViewTopic; 11] = [
    ViewTopic::Color,
    ViewTopic::Depth,
    ViewTopic::Calibration,
    ViewTopic::EstimatedPose,
    ViewTopic::TruePose,
    ViewTopic::Transforms,
    ViewTopic::Occupancy,
    ViewTopic::Map,
    ViewTopic::Frontiers,
    ViewTopic::Path,
    ViewTopic::Log,
];

#[test]
fn the_view_channels_stream_live_and_decode_from_the_recording_with_both_readers() {
    let tmp = tempfile::tempdir().unwrap();
    let flow = tmp.path().join("view.yaml");
    std::fs::write(&flow, harness::small_house_flow("dataflow.yaml", 250, &[])).unwrap();
    let out = tmp.path().join("run");
    let child = harness::spawn(
        &[
            "run",
            flow.to_str().unwrap(),
            "--out",
            out.to_str().unwrap(),
            "--no-eval",
            "--view",
            "127.0.0.1:0",
        ],
        tmp.path(),
    );
    // Follow stderr for the live view's address; keep all of it for failures.
    let (child, url_lines) = harness::follow(child, Some("live view at ws://"));
    let deadline = Instant::now() + Duration::from_secs(300);
    let line = url_lines
        .recv_timeout(Duration::from_secs(120))
        .expect("the run never printed its live view address");
    let at = line.find("live view at ws://").expect("the needle");
    let url = line[at + "live view at ".len()..]
        .split_whitespace()
        .next()
        .unwrap()
        .to_string();
    assert!(url.starts_with("ws://127.0.0.1:"), "{url}");
    let live = live_client(
        &url,
        &[ViewTopic::Color, ViewTopic::EstimatedPose],
        deadline,
    );
    let color = decode_view(ViewTopic::Color, &live[&ViewTopic::Color]).unwrap();
    assert!(color.starts_with("jpeg 64x64"), "{color}");
    let pose = decode_view(ViewTopic::EstimatedPose, &live[&ViewTopic::EstimatedPose]).unwrap();
    assert!(pose.starts_with("world"), "{pose}");
    let finished = child.finish(
        deadline.saturating_duration_since(Instant::now()),
        "the run with a live view",
    );
    let (status, stderr) = (finished.status, finished.stderr);
    assert!(status.success(), "run failed:\n{stderr}");

    // The recording, read back with the MCAP crate.
    let path = out.join(activemap_eval::RunFolder::RECORDING);
    let bytes = std::fs::read(&path).unwrap();
    let mut first: BTreeMap<ViewTopic, Vec<u8>> = BTreeMap::new();
    let mut channels = BTreeMap::new();
    for m in mcap::MessageStream::new(&bytes).unwrap() {
        let m = m.unwrap();
        let Some(topic) = ViewTopic::from_topic(&m.channel.topic) else {
            assert!(
                m.channel.message_encoding.starts_with("activemap/"),
                "{}",
                m.channel.topic
            );
            continue;
        };
        let schema = m
            .channel
            .schema
            .as_ref()
            .expect("view channels have schemas");
        channels.insert(
            topic,
            (
                schema.name.clone(),
                schema.encoding.clone(),
                m.channel.message_encoding.clone(),
            ),
        );
        first.entry(topic).or_insert_with(|| m.data.to_vec());
    }
    for topic in SHOWN_BY_FBE {
        let (schema, schema_encoding, encoding) = channels
            .get(&topic)
            .unwrap_or_else(|| panic!("no message on {}", topic.topic()));
        assert_eq!(schema, &topic.schema().name);
        assert_eq!(
            (schema_encoding.as_str(), encoding.as_str()),
            ("protobuf", "protobuf")
        );
        let shown = decode_view(topic, &first[&topic]).unwrap();
        eprintln!("{}: {shown}", topic.topic());
    }
    // The replay readers skip the view channels.
    let rec = activemap_runtime::record::read_recording(&path).unwrap();
    assert!(rec.messages.iter().all(|m| !m.topic.starts_with('/')));

    // The same with the official Python reader.
    let Some(python) = python_with_mcap() else {
        return;
    };
    let out = Command::new(&python)
        .arg("-c")
        .arg(PYTHON_READER)
        .arg(&path)
        .output()
        .unwrap();
    let text = String::from_utf8_lossy(&out.stdout);
    assert!(
        out.status.success(),
        "python reader failed:\n{text}\n{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let rows: Vec<serde_json::Value> = text
        .lines()
        .map(|l| serde_json::from_str(l).unwrap())
        .collect();
    for topic in ViewTopic::ALL {
        let channel = rows
            .iter()
            .find(|r| r["channel"] == topic.topic())
            .unwrap_or_else(|| panic!("python: no channel {}:\n{text}", topic.topic()));
        assert_eq!(channel["schema"], topic.schema().name);
        assert_eq!(channel["schema_encoding"], "protobuf");
        assert_eq!(channel["encoding"], "protobuf");
        if !SHOWN_BY_FBE.contains(&topic) {
            continue;
        }
        let message = rows
            .iter()
            .find(|r| r["message"] == topic.topic())
            .unwrap_or_else(|| panic!("python: no message decoded on {}:\n{text}", topic.topic()));
        let ty = topic
            .schema()
            .name
            .trim_start_matches("foxglove.")
            .to_string();
        assert_eq!(message["type"], ty.as_str(), "{}", topic.topic());
        assert!(
            !message["fields"].as_array().unwrap().is_empty(),
            "{message}"
        );
    }
}
