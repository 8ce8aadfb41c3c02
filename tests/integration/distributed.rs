//! Two daemons (`activemap up`) on two loopback addresses, multicast off, run a two-machine flow:
//! small messages and a shared-memory topic bridged over Zenoh between machines.

use std::time::Duration;

use activemap_runtime::record::read_recording;
use activemap_schemas::{Counter, SmallMessage};

use super::harness::{root, spawn, wait};

fn free_port(ip: &str) -> u16 {
    std::net::TcpListener::bind((ip, 0))
        .unwrap()
        .local_addr()
        .unwrap()
        .port()
}

#[test]
fn two_daemons_on_two_loopback_addresses_run_a_two_machine_flow() {
    let tmp = tempfile::tempdir().unwrap();
    let (pa, pb) = (free_port("127.0.0.2"), free_port("127.0.0.3"));
    let flow = format!(
        "machines:
  - id: a
    listen: [tcp/127.0.0.2:{pa}]
  - id: b
    listen: [tcp/127.0.0.3:{pb}]
    connect: [tcp/127.0.0.2:{pa}]
nodes:
  - id: source
    operator: counter_source
    config: {{ count: 10 }}
    timers: {{ tick: 20ms }}
    deploy: {{ machine: a }}
  - id: camera
    operator: frame_source
    config: {{ count: 3, size: 128 }}
    timers: {{ tick: 50ms }}
    deploy: {{ machine: a }}
  - id: double
    operator: doubler
    inputs:
      value: {{ source: source/count, queue_size: 64, drop: block }}
    deploy: {{ machine: b }}
  - id: checker
    operator: frame_checker
    inputs:
      frame: {{ source: camera/frame, queue_size: 8, drop: block }}
    deploy: {{ machine: b }}
"
    );
    let file = tmp.path().join("two.yaml");
    std::fs::write(&file, flow).unwrap();
    let file = file.to_str().unwrap();
    let run_id = format!("t{}", std::process::id());
    let dir_a = tmp.path().join("a");
    let dir_b = tmp.path().join("b");
    let a = spawn(
        &[
            "up",
            file,
            "--machine",
            "a",
            "--run-id",
            &run_id,
            "--out",
            dir_a.to_str().unwrap(),
        ],
        &root(),
    );
    let b = spawn(
        &[
            "up",
            file,
            "--machine",
            "b",
            "--run-id",
            &run_id,
            "--out",
            dir_b.to_str().unwrap(),
        ],
        &root(),
    );
    let out_a = wait(a, Duration::from_secs(120), "daemon a");
    let out_b = wait(b, Duration::from_secs(120), "daemon b");
    assert!(out_a.status.success(), "daemon a:\n{}", out_a.stderr);
    assert!(out_b.status.success(), "daemon b:\n{}", out_b.stderr);
    // Machine b's recording holds what its nodes produced from machine a's data.
    let rec = read_recording(&dir_b.join("recording.mcap")).unwrap();
    let values = |topic: &str| -> Vec<Counter> {
        rec.messages
            .iter()
            .filter(|m| m.topic == topic && !m.bytes.is_empty())
            .map(|m| Counter::decode(&m.bytes).unwrap())
            .collect()
    };
    let doubled: Vec<i64> = values("double/doubled").iter().map(|c| c.value).collect();
    assert_eq!(doubled, (1..=10).map(|v| 2 * v).collect::<Vec<_>>());
    let reports = values("checker/report");
    assert_eq!(reports.len(), 3, "{reports:?}");
    assert!(
        reports.iter().all(|r| r.value == 1),
        "a bridged frame differed: {reports:?}"
    );
    // Nodes ran where deploy.machine says.
    assert!(dir_a.join("logs/source.stderr.log").exists());
    assert!(!dir_a.join("logs/double.stderr.log").exists());
    assert!(dir_b.join("logs/double.stderr.log").exists());
}
