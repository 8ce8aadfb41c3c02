//! Two machines on two loopback addresses, multicast off, run a two-machine flow: small messages
//! and a shared-memory topic bridged over Zenoh between machines. Once with one-shot `up FILE`
//! per machine, once with long-lived daemons (`up --listen`) that accept `start`, answer `list`
//! and `logs`, and go `down`.

use std::time::Duration;

use activemap_runtime::record::read_recording;
use activemap_schemas::{Counter, SmallMessage};

use super::harness::{Finished, root, run, run_env, spawn, wait};

fn free_port(ip: &str) -> u16 {
    std::net::TcpListener::bind((ip, 0))
        .unwrap()
        .local_addr()
        .unwrap()
        .port()
}

/// `activemap start FILE --connect CONTROL --timeout 2`, retried (up to 40 times, 250 ms apart)
/// while `not_up` says from its stderr that the daemon there does not answer yet.
fn start_when_up(file: &str, control: &str, not_up: impl Fn(&str) -> bool) -> Finished {
    for _ in 0..40 {
        let o = run(
            &["start", file, "--connect", control, "--timeout", "2"],
            &root(),
            Duration::from_secs(60),
        );
        if !not_up(&o.stderr) {
            return o;
        }
        std::thread::sleep(Duration::from_millis(250));
    }
    panic!("the daemon at {control} never answered");
}

/// A two-machine flow: machine a produces counters and frames, machine b doubles and checks them.
fn two_machine_flow(pa: u16, pb: u16) -> String {
    two_machine_flow_over("tcp", pa, pb)
}

/// [`two_machine_flow`] with its data plane over `scheme` (`tcp`, `tls` or `quic`).
fn two_machine_flow_over(scheme: &str, pa: u16, pb: u16) -> String {
    format!(
        "machines:
  - id: a
    listen: [{scheme}/127.0.0.2:{pa}]
  - id: b
    listen: [{scheme}/127.0.0.3:{pb}]
    connect: [{scheme}/127.0.0.2:{pa}]
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
    )
}

/// What machine b's recording must hold: the doubled counters and three bit-exact frames.
fn check_machine_b(dir_b: &std::path::Path) {
    let rec = read_recording(&dir_b.join("recording.mcap")).unwrap();
    let values = |topic: &str| -> Vec<Counter> {
        rec.messages
            .iter()
            .filter(|m| m.topic == topic && !m.bytes.is_empty())
            .map(|m| Counter::decode(&m.bytes).unwrap())
            .collect()
    };
    let doubled: Vec<i64> = values("double/doubled").iter().map(|c| c.value).collect();
    // On a mismatch, machine b's node logs say where a message went missing (a gap warning,
    // a Zenoh transport error).
    let logs = || -> String {
        let dir = dir_b.join("logs");
        let mut out = String::new();
        for entry in std::fs::read_dir(&dir).into_iter().flatten().flatten() {
            let text = std::fs::read_to_string(entry.path()).unwrap_or_default();
            out += &format!("--- {} ---\n{text}\n", entry.path().display());
        }
        out
    };
    assert_eq!(
        doubled,
        (1..=10).map(|v| 2 * v).collect::<Vec<_>>(),
        "machine b's logs:\n{}",
        logs()
    );
    let reports = values("checker/report");
    assert_eq!(reports.len(), 3, "{reports:?}");
    assert!(
        reports.iter().all(|r| r.value == 1),
        "a bridged frame differed: {reports:?}"
    );
}

#[test]
fn two_daemons_on_two_loopback_addresses_run_a_two_machine_flow() {
    let tmp = tempfile::tempdir().unwrap();
    let (pa, pb) = (free_port("127.0.0.2"), free_port("127.0.0.3"));
    let flow = two_machine_flow(pa, pb);
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
    check_machine_b(&dir_b);
    // Nodes ran where deploy.machine says.
    assert!(dir_a.join("logs/source.stderr.log").exists());
    assert!(!dir_a.join("logs/double.stderr.log").exists());
    assert!(dir_b.join("logs/double.stderr.log").exists());
}

#[test]
fn long_lived_daemons_accept_a_flow_list_it_show_logs_and_go_down() {
    let tmp = tempfile::tempdir().unwrap();
    let (pa, pb) = (free_port("127.0.0.2"), free_port("127.0.0.3"));
    let (ca, cb) = (free_port("127.0.0.2"), free_port("127.0.0.3"));
    let file = tmp.path().join("two.yaml");
    std::fs::write(&file, two_machine_flow(pa, pb)).unwrap();
    let file = file.to_str().unwrap();
    let (runs_a, runs_b) = (tmp.path().join("a"), tmp.path().join("b"));
    let control_a = format!("tcp/127.0.0.2:{ca}");
    let control_b = format!("tcp/127.0.0.3:{cb}");
    let daemon_a = spawn(
        &[
            "up",
            "--machine",
            "a",
            "--listen",
            &control_a,
            "--runs",
            runs_a.to_str().unwrap(),
        ],
        &root(),
    );
    let daemon_b = spawn(
        &[
            "up",
            "--machine",
            "b",
            "--listen",
            &control_b,
            "--connect",
            &control_a,
            "--runs",
            runs_b.to_str().unwrap(),
        ],
        &root(),
    );
    // A client reaches both daemons through a's endpoint; retry while they come up.
    let run_id = format!("d{}", std::process::id());
    start_and_check_flow(file, &control_a, &run_id, &[], &runs_b);
    assert!(runs_a.join(&run_id).join("logs/source.stderr.log").exists());
    assert!(!runs_a.join(&run_id).join("logs/double.stderr.log").exists());

    // Both machines list the run as finished.
    let list = run(
        &["list", "--connect", &control_a],
        &root(),
        Duration::from_secs(30),
    );
    assert!(list.status.success(), "{}", list.stderr);
    let lines: Vec<&str> = list
        .stdout
        .lines()
        .filter(|l| l.contains(&run_id))
        .collect();
    assert_eq!(lines.len(), 2, "{}", list.stdout);
    assert!(
        lines.iter().all(|l| l.contains("finished")),
        "{}",
        list.stdout
    );

    // Logs come from the machine that ran the node.
    let logs = run(
        &[
            "logs",
            "--run-id",
            &run_id,
            "--node",
            "double",
            "--connect",
            &control_a,
        ],
        &root(),
        Duration::from_secs(30),
    );
    assert!(logs.status.success(), "{}", logs.stderr);
    assert!(
        logs.stdout.contains("==> b: double.stderr.log <=="),
        "{}",
        logs.stdout
    );
    assert!(!logs.stdout.contains("==> a:"), "{}", logs.stdout);

    // A second submission under the same id is refused with the machine named.
    let again = run(
        &["start", file, "--connect", &control_a, "--run-id", &run_id],
        &root(),
        Duration::from_secs(60),
    );
    assert!(!again.status.success());
    assert!(
        again.stderr.contains("already exists on machine"),
        "{}",
        again.stderr
    );

    // `down` stops both daemons.
    let down = run(
        &["down", "--connect", &control_a],
        &root(),
        Duration::from_secs(30),
    );
    assert!(down.status.success(), "{}", down.stderr);
    assert!(down.stdout.contains("a, b"), "{}", down.stdout);
    let out_a = wait(daemon_a, Duration::from_secs(60), "daemon a");
    let out_b = wait(daemon_b, Duration::from_secs(60), "daemon b");
    assert!(out_a.status.success(), "daemon a:\n{}", out_a.stderr);
    assert!(out_b.status.success(), "daemon b:\n{}", out_b.stderr);
}

#[test]
fn start_names_the_machine_whose_daemon_is_missing() {
    let tmp = tempfile::tempdir().unwrap();
    let (pa, pb) = (free_port("127.0.0.2"), free_port("127.0.0.3"));
    let ca = free_port("127.0.0.2");
    let file = tmp.path().join("two.yaml");
    std::fs::write(&file, two_machine_flow(pa, pb)).unwrap();
    let control_a = format!("tcp/127.0.0.2:{ca}");
    let runs_a = tmp.path().join("a");
    let daemon_a = spawn(
        &[
            "up",
            "--machine",
            "a",
            "--listen",
            &control_a,
            "--runs",
            runs_a.to_str().unwrap(),
        ],
        &root(),
    );
    // Daemon a may not listen yet (no session at all) or not answer yet: both mean retry.
    let out = start_when_up(file.to_str().unwrap(), &control_a, |stderr| {
        stderr.contains("no daemon reachable") || stderr.contains("machine `a`: no daemon answered")
    });
    assert!(!out.status.success());
    assert!(
        out.stderr.contains("machine `b`: no daemon answered"),
        "{}",
        out.stderr
    );
    // Nothing was started on machine a, and its daemon still serves.
    let down = run(
        &["down", "--connect", &control_a],
        &root(),
        Duration::from_secs(30),
    );
    assert!(down.status.success(), "{}", down.stderr);
    let out_a = wait(daemon_a, Duration::from_secs(60), "daemon a");
    assert!(out_a.status.success(), "daemon a:\n{}", out_a.stderr);
}

/// A daemon refuses to listen on a non-loopback address without TLS unless `--insecure`, and
/// runs `path:` executables only from its `--allow-exec` folders: a flow with another one is
/// refused, naming the node, and nothing of it runs.
/// Zenoh's own `tracing` events reach stderr at the level `RUST_LOG` asks for (errors only
/// by default), never stdout: a client that cannot connect logs Zenoh's warning under
/// `RUST_LOG=zenoh=warn` and nothing of it at `error`.
#[test]
fn library_log_events_go_to_stderr_at_the_level_asked() {
    let endpoint = format!("tcp/127.0.0.5:{}", free_port("127.0.0.5"));
    let args = ["list", "--connect", endpoint.as_str()];
    let verbose = run_env(
        &args,
        &root(),
        &[("RUST_LOG", "zenoh=warn")],
        Duration::from_secs(60),
    );
    assert!(!verbose.status.success());
    assert!(
        verbose.stderr.contains("WARN zenoh") && verbose.stderr.contains(&endpoint),
        "{}",
        verbose.stderr
    );
    assert!(verbose.stdout.trim().is_empty(), "{}", verbose.stdout);
    let quiet = run_env(
        &args,
        &root(),
        &[("RUST_LOG", "error")],
        Duration::from_secs(60),
    );
    assert!(!quiet.status.success());
    assert!(!quiet.stderr.contains("WARN"), "{}", quiet.stderr);
    assert!(
        quiet.stderr.contains("no daemon reachable"),
        "{}",
        quiet.stderr
    );
}

#[test]
fn daemons_refuse_exposed_listening_and_executables_outside_allow_exec() {
    let exposed = run(
        &["up", "--machine", "a", "--listen", "tcp/10.255.255.1:7400"],
        &root(),
        Duration::from_secs(30),
    );
    assert!(!exposed.status.success());
    assert!(
        exposed
            .stderr
            .contains("refusing to listen on tcp/10.255.255.1:7400 without TLS")
            && exposed.stderr.contains("--insecure"),
        "{}",
        exposed.stderr
    );

    let tmp = tempfile::tempdir().unwrap();
    let tools = tmp.path().join("tools");
    std::fs::create_dir_all(&tools).unwrap();
    let script = tmp.path().join("outside.sh");
    std::fs::write(&script, "#!/bin/sh\ntouch \"$0.ran\"\n").unwrap();
    let pa = free_port("127.0.0.4");
    let ca = free_port("127.0.0.4");
    let file = tmp.path().join("exec.yaml");
    std::fs::write(
        &file,
        format!(
            "machines:\n  - id: a\n    listen: [tcp/127.0.0.4:{pa}]\nnodes:\n  - id: intruder\n    path: {}\n    outputs: [{{ id: out, type: Counter }}]\n    deploy: {{ machine: a }}\n",
            script.display()
        ),
    )
    .unwrap();
    let control = format!("tcp/127.0.0.4:{ca}");
    let runs = tmp.path().join("runs");
    let daemon = spawn(
        &[
            "up",
            "--machine",
            "a",
            "--listen",
            &control,
            "--runs",
            runs.to_str().unwrap(),
            "--allow-exec",
            tools.to_str().unwrap(),
        ],
        &root(),
    );
    let out = start_when_up(file.to_str().unwrap(), &control, |stderr| {
        stderr.contains("no daemon reachable") || stderr.contains("no daemon answered")
    });
    assert!(!out.status.success());
    assert!(
        out.stderr.contains("node `intruder`") && out.stderr.contains("--allow-exec"),
        "{}",
        out.stderr
    );

    // An allowed node that fails: `start --wait` exits non-zero and names, on stderr, the run,
    // the machine and the launcher's reason (the crash, with the node's name).
    let failing = tools.join("fails.sh");
    std::fs::write(&failing, "#!/bin/sh\necho 'cannot go on' >&2\nexit 3\n").unwrap();
    std::fs::set_permissions(
        &failing,
        std::os::unix::fs::PermissionsExt::from_mode(0o755),
    )
    .unwrap();
    let failing_flow = tmp.path().join("fails.yaml");
    std::fs::write(
        &failing_flow,
        format!(
            "machines:\n  - id: a\n    listen: [tcp/127.0.0.4:{}]\nnodes:\n  - id: quitter\n    path: {}\n    outputs: [{{ id: out, type: Counter }}]\n    deploy: {{ machine: a }}\n",
            free_port("127.0.0.4"),
            failing.display()
        ),
    )
    .unwrap();
    let failed = run(
        &[
            "start",
            failing_flow.to_str().unwrap(),
            "--connect",
            &control,
            "--run-id",
            "quits",
            "--wait",
        ],
        &root(),
        Duration::from_secs(120),
    );
    assert!(!failed.status.success(), "{}", failed.stdout);
    assert!(
        failed.stderr.contains("run quits failed on machine `a`")
            && failed.stderr.contains("node `quitter` crashed"),
        "{}\n{}",
        failed.stderr,
        failed.stdout
    );

    let down = run(
        &["down", "--connect", &control],
        &root(),
        Duration::from_secs(30),
    );
    assert!(down.status.success(), "{}", down.stderr);
    let done = wait(daemon, Duration::from_secs(60), "daemon");
    assert!(done.status.success(), "daemon:\n{}", done.stderr);
    assert!(
        !tmp.path().join("outside.sh.ran").exists(),
        "the refused node ran"
    );
}

/// A test certificate authority named `name` in `dir`, and for each party (name, subject
/// alternative names) a certificate it signs (both server and client use) with its key: the
/// PEM paths `[ca, cert, key]` of each party.
fn test_pki(dir: &std::path::Path, name: &str, parties: &[(&str, &[&str])]) -> Vec<[String; 3]> {
    use rcgen::{
        BasicConstraints, CertificateParams, DnType, ExtendedKeyUsagePurpose, IsCa, Issuer,
        KeyPair, KeyUsagePurpose,
    };
    let mut ca_params = CertificateParams::new(Vec::<String>::new()).unwrap();
    ca_params.is_ca = IsCa::Ca(BasicConstraints::Unconstrained);
    ca_params
        .distinguished_name
        .push(DnType::CommonName, format!("{name} test CA"));
    ca_params.key_usages = vec![
        KeyUsagePurpose::KeyCertSign,
        KeyUsagePurpose::CrlSign,
        KeyUsagePurpose::DigitalSignature,
    ];
    let ca_key = KeyPair::generate().unwrap();
    let ca_cert = ca_params.self_signed(&ca_key).unwrap();
    let ca_path = dir.join(format!("{name}-ca.pem"));
    std::fs::write(&ca_path, ca_cert.pem()).unwrap();
    let issuer = Issuer::new(ca_params, ca_key);
    parties
        .iter()
        .map(|(party, sans)| {
            let mut params =
                CertificateParams::new(sans.iter().map(|s| s.to_string()).collect::<Vec<_>>())
                    .unwrap();
            params.distinguished_name.push(DnType::CommonName, *party);
            params.extended_key_usages = vec![
                ExtendedKeyUsagePurpose::ServerAuth,
                ExtendedKeyUsagePurpose::ClientAuth,
            ];
            let key = KeyPair::generate().unwrap();
            let cert = params.signed_by(&key, &issuer).unwrap();
            let cert_path = dir.join(format!("{name}-{party}.pem"));
            let key_path = dir.join(format!("{name}-{party}.key"));
            std::fs::write(&cert_path, cert.pem()).unwrap();
            std::fs::write(&key_path, key.serialize_pem()).unwrap();
            [&ca_path, &cert_path, &key_path].map(|p| p.display().to_string())
        })
        .collect()
}

/// The `--tls-ca/--tls-cert/--tls-key` arguments of an identity.
fn tls_args(id: &[String; 3]) -> Vec<&str> {
    vec![
        "--tls-ca",
        &id[0],
        "--tls-cert",
        &id[1],
        "--tls-key",
        &id[2],
    ]
}

/// Issue 18: two daemons on 127.0.0.2 and 127.0.0.3 with mutual TLS over `tls/` (certificates
/// made here) come up and answer a trusted client; a client whose certificate another CA
/// signed, a client without a certificate and a plain-TCP client are all refused; a daemon
/// given a `tls/` endpoint without its files is refused at start. No flow runs over `tls/`:
/// Zenoh 1.10.2's TLS link can lose a message under load (README, "Known limitation"; CI lost
/// one and the run stalled), so the flow itself is checked over `quic/` below.
#[test]
fn daemons_with_mutual_tls_answer_trusted_clients_and_refuse_clients_without_a_valid_certificate() {
    mutual_tls_daemons("tls", false);
}

/// The same over `quic/` (TLS 1.3 inside QUIC, the same certificates and settings), and the
/// two-machine flow runs with control and data plane both over `quic/`.
#[test]
fn daemons_with_mutual_tls_over_quic_run_a_flow_and_refuse_clients_without_a_valid_certificate() {
    mutual_tls_daemons("quic", true);
}

/// A free UDP port on `ip` (QUIC listens on UDP).
fn free_udp_port(ip: &str) -> u16 {
    std::net::UdpSocket::bind((ip, 0))
        .unwrap()
        .local_addr()
        .unwrap()
        .port()
}

/// The mutual-TLS daemon scenario with every endpoint over `scheme` (`tls` or `quic`); with
/// `run_flow` the two-machine flow runs and is checked on both machines.
fn mutual_tls_daemons(scheme: &str, run_flow: bool) {
    let port = |ip: &str| match scheme {
        "quic" => free_udp_port(ip),
        _ => free_port(ip),
    };
    let tmp = tempfile::tempdir().unwrap();
    let ids = test_pki(
        tmp.path(),
        "trusted",
        &[
            ("a", &["127.0.0.2"]),
            ("b", &["127.0.0.3"]),
            ("client", &["activemap-client"]),
        ],
    );
    let (id_a, id_b, id_client) = (&ids[0], &ids[1], &ids[2]);
    let rogue = &test_pki(tmp.path(), "rogue", &[("client", &["activemap-client"])])[0];

    let no_files_endpoint = format!("{scheme}/127.0.0.2:1");
    let no_files = run(
        &["up", "--machine", "a", "--listen", &no_files_endpoint],
        &root(),
        Duration::from_secs(30),
    );
    assert!(!no_files.status.success());
    assert!(
        no_files.stderr.contains("--tls-cert"),
        "{}",
        no_files.stderr
    );

    let (pa, pb) = (port("127.0.0.2"), port("127.0.0.3"));
    let (ca, cb) = (port("127.0.0.2"), port("127.0.0.3"));
    let file = tmp.path().join(format!("two-{scheme}.yaml"));
    std::fs::write(&file, two_machine_flow_over(scheme, pa, pb)).unwrap();
    let file = file.to_str().unwrap();
    let (runs_a, runs_b) = (tmp.path().join("a"), tmp.path().join("b"));
    let control_a = format!("{scheme}/127.0.0.2:{ca}");
    let control_b = format!("{scheme}/127.0.0.3:{cb}");
    let mut up_a = vec!["up", "--machine", "a", "--listen", &control_a, "--runs"];
    up_a.push(runs_a.to_str().unwrap());
    up_a.extend(tls_args(id_a));
    let daemon_a = spawn(&up_a, &root());
    let mut up_b = vec![
        "up",
        "--machine",
        "b",
        "--listen",
        &control_b,
        "--connect",
        &control_a,
    ];
    up_b.extend(["--runs", runs_b.to_str().unwrap()]);
    up_b.extend(tls_args(id_b));
    let daemon_b = spawn(&up_b, &root());

    let run_id = format!("m{}", std::process::id());
    let started_stdout = if run_flow {
        start_and_check_flow(file, &control_a, &run_id, &tls_args(id_client), &runs_b)
    } else {
        // The daemons are up once both answer the trusted client.
        let mut list = vec!["list", "--connect", &control_a];
        list.extend(tls_args(id_client));
        let answered = (0..120).any(|_| {
            let out = run(&list, &root(), Duration::from_secs(60));
            let both = out.status.success() && out.stderr.contains("daemons answering: a, b");
            if !both {
                std::thread::sleep(Duration::from_millis(250));
            }
            both
        });
        assert!(
            answered,
            "the TLS daemons never both answered the trusted client"
        );
        String::new()
    };

    // Refused: a certificate of another CA, no certificate, plain TCP on the TLS port.
    let mut rogue_list = vec!["list", "--connect", &control_a];
    rogue_list.extend(tls_args(rogue));
    let plain = format!("tcp/127.0.0.2:{ca}");
    for (what, args) in [
        ("another CA's certificate", rogue_list),
        ("no certificate", vec!["list", "--connect", &control_a]),
        ("plain TCP", vec!["list", "--connect", &plain]),
    ] {
        let out = run(&args, &root(), Duration::from_secs(60));
        assert!(!out.status.success(), "{what}: accepted:\n{}", out.stdout);
        assert!(
            out.stderr.contains("no daemon reachable"),
            "{what}: {}",
            out.stderr
        );
        assert!(!out.stdout.contains(&run_id), "{what}: {}", out.stdout);
    }
    // The trusted client lists the run on both machines; no key content in any output.
    let mut list = vec!["list", "--connect", &control_a];
    list.extend(tls_args(id_client));
    let listed = run(&list, &root(), Duration::from_secs(60));
    assert!(listed.status.success(), "{}", listed.stderr);
    assert_eq!(
        listed
            .stdout
            .lines()
            .filter(|l| l.contains(&run_id))
            .count(),
        if run_flow { 2 } else { 0 },
        "{}",
        listed.stdout
    );
    let mut down = vec!["down", "--connect", &control_a];
    down.extend(tls_args(id_client));
    let down = run(&down, &root(), Duration::from_secs(30));
    assert!(down.status.success(), "{}", down.stderr);
    let out_a = wait(daemon_a, Duration::from_secs(60), "daemon a");
    let out_b = wait(daemon_b, Duration::from_secs(60), "daemon b");
    assert!(out_a.status.success(), "daemon a:\n{}", out_a.stderr);
    assert!(out_b.status.success(), "daemon b:\n{}", out_b.stderr);
    let key_line = std::fs::read_to_string(&id_a[2]).unwrap();
    let key_body = key_line.lines().nth(1).unwrap();
    for text in [
        &out_a.stderr,
        &out_b.stderr,
        &listed.stdout,
        &started_stdout,
    ] {
        assert!(!text.contains(key_body), "a private key was printed");
    }
    if run_flow {
        let run_json = std::fs::read_to_string(runs_a.join(&run_id).join("run.json")).unwrap();
        assert!(!run_json.contains(key_body));
    }
}

/// Starts the two-machine flow `file` through `control_a` with the client arguments `client`
/// (the TLS identity, if any), retrying while the daemons come up (until then the client
/// cannot connect or a machine does not answer), waits for it and checks machine b's
/// outputs; returns start's stdout.
fn start_and_check_flow(
    file: &str,
    control_a: &str,
    run_id: &str,
    client: &[&str],
    runs_b: &std::path::Path,
) -> String {
    let mut start = vec![
        "start",
        file,
        "--connect",
        control_a,
        "--run-id",
        run_id,
        "--wait",
    ];
    start.extend(client);
    let mut started = None;
    for _ in 0..60 {
        let out = run(&start, &root(), Duration::from_secs(120));
        if out.status.success() {
            started = Some(out);
            break;
        }
        assert!(
            out.stderr.contains("no daemon answered") || out.stderr.contains("no daemon reachable"),
            "start failed for another reason:\n{}\n{}",
            out.stderr,
            out.stdout
        );
        std::thread::sleep(Duration::from_millis(250));
    }
    let started = started.expect("the daemons never accepted the flow");
    assert!(
        started.stdout.contains(&format!("run {run_id} started")),
        "{}",
        started.stdout
    );
    check_machine_b(&runs_b.join(run_id));
    started.stdout
}

/// Issue 38: `bench results --connect` with mutual TLS over `quic/`, against three daemons on
/// 127.0.0.2–.4 (one slot each), on a 6-cell suite (a procedural house and a scene file, which
/// travels to the daemons by content): a daemon killed while it runs a cell loses that cell to
/// the others, its episode does not outlive it, and every cell completes with its files brought
/// back and the local run's figures. To 5 %, not bit for bit: on a loaded machine the pipeline
/// is not bit-reproducible, locally either (the user guide's distributed page says where).
#[test]
fn bench_results_over_tls_daemons_equals_a_local_run_and_survives_a_killed_daemon() {
    let tmp = tempfile::tempdir().unwrap();
    let ids = test_pki(
        tmp.path(),
        "suite",
        &[
            ("m2", &["127.0.0.2"]),
            ("m3", &["127.0.0.3"]),
            ("m4", &["127.0.0.4"]),
            ("client", &["activemap-client"]),
        ],
    );
    let suite = tmp.path().join("suite.yaml");
    let room = root().join("../shared/data/scenes/simple_room.glb");
    std::fs::write(
        &suite,
        format!(
            "description: distributed check\nmethods: [fbe]\nscenes:\n  - house:3\n  - scene: {}\n\
             houses: {{ max_rooms: 2, max_area: 30 }}\nseeds: [1, 2, 3]\nsteps: 25\n\
             camera: {{ resolution: 64 }}\neval_views: 8\n",
            room.display()
        ),
    )
    .unwrap();
    let suite = suite.to_str().unwrap();

    // The same suite on this machine alone.
    let local = tmp.path().join("local");
    let alone = run(
        &[
            "bench",
            "results",
            "--suite",
            suite,
            "--out",
            local.to_str().unwrap(),
            "--jobs",
            "1",
        ],
        &root(),
        Duration::from_secs(600),
    );
    assert!(alone.status.success(), "{}", alone.stderr);

    let (control, runs) = suite_daemons(tmp.path(), 3);
    let up = |k: usize| Some(up_suite_daemon(k, &control, &runs, &ids[k]));
    let client = tls_args(&ids[3]);
    let remote_args = |out: &std::path::Path| -> Vec<String> {
        let mut args: Vec<String> = ["bench", "results", "--suite", suite, "--out"]
            .iter()
            .map(|s| s.to_string())
            .collect();
        args.extend([
            out.display().to_string(),
            "--connect".into(),
            control[0].clone(),
        ]);
        args.extend(client.iter().map(|s| s.to_string()));
        args
    };
    let metrics_of = |dir: &std::path::Path| -> Vec<(std::path::PathBuf, Vec<u8>)> {
        let mut all: Vec<_> = walk(dir)
            .into_iter()
            .filter(|p| p.file_name().is_some_and(|f| f == "metrics.json"))
            .map(|p| {
                (
                    p.strip_prefix(dir).unwrap().to_path_buf(),
                    std::fs::read(&p).unwrap(),
                )
            })
            .collect();
        all.sort();
        all
    };
    let local_metrics = metrics_of(&local);
    assert_eq!(local_metrics.len(), 6);

    // Three daemons; m4 is killed as soon as it runs a cell.
    let mut daemons = vec![up(0), up(1), up(2)];
    until_answering(&control[0], &client, "m2, m3, m4");
    let three = tmp.path().join("three");
    let args = remote_args(&three);
    let args: Vec<&str> = args.iter().map(String::as_str).collect();
    let bench = spawn(&args, &root());
    let episodes4 = runs[2].join("episodes");
    let deadline = std::time::Instant::now() + Duration::from_secs(300);
    let killed_in = loop {
        let started = std::fs::read_dir(&episodes4)
            .ok()
            .and_then(|d| d.flatten().next())
            .map(|e| e.path());
        if let Some(dir) = started {
            let daemon = daemons[2].take().unwrap();
            super::harness::kill9(daemon.id());
            let _ = wait(daemon, Duration::from_secs(30), "daemon m4");
            break dir;
        }
        assert!(std::time::Instant::now() < deadline, "m4 never got a cell");
        std::thread::sleep(Duration::from_millis(20));
    };
    let finished = wait(bench, Duration::from_secs(600), "bench results --connect");
    assert!(finished.status.success(), "{}", finished.stderr);
    let err = &finished.stderr;
    assert!(
        err.contains("machine `m4` lost") && err.contains("re-queued"),
        "{err}"
    );
    assert!(err.contains("dispatch overhead per cell"), "{err}");
    // The killed daemon's episode went down with it (PR_SET_PDEATHSIG).
    let gone = (0..100).any(|_| {
        let left = super::harness::pids_with(&["run", killed_in.to_str().unwrap()]);
        if !left.is_empty() {
            std::thread::sleep(Duration::from_millis(100));
        }
        left.is_empty()
    });
    assert!(gone, "the episode of the killed daemon outlived it");
    let three_metrics = metrics_of(&three);
    assert_eq!(three_metrics.len(), 6);
    let identical = three_metrics
        .iter()
        .zip(&local_metrics)
        .filter(|(a, b)| a == b)
        .count();
    eprintln!("{identical} of 6 cells bit-identical to the local run");
    for ((rel, want), (rel3, got)) in local_metrics.iter().zip(&three_metrics) {
        assert_eq!(rel, rel3);
        for brought in [
            "summary.json",
            "trajectory_est.tum",
            "trajectory_true.tum",
            "report.html",
            "bench.log",
        ] {
            assert!(
                three.join(rel).with_file_name(brought).is_file(),
                "{brought}"
            );
        }
        assert!(!three.join(rel).with_file_name("recording.mcap").exists());
        let want: serde_json::Value = serde_json::from_slice(want).unwrap();
        let got: serde_json::Value = serde_json::from_slice(got).unwrap();
        for (key, w) in want.as_object().unwrap() {
            if let (Some(w), Some(g)) = (w.as_f64(), got[key].as_f64()) {
                assert!(
                    (w - g).abs() <= 0.05 * w.abs().max(g.abs()) + 5e-3,
                    "{}: {key} {w} locally, {g} over three daemons",
                    rel.display()
                );
            }
        }
    }
    // The scene file reached the daemons that ran its cells, each once, by content (which
    // daemons those are depends on which slot was free first).
    let stored: Vec<usize> = runs
        .iter()
        .map(|r| {
            std::fs::read_dir(r.join("scenes"))
                .unwrap()
                .flatten()
                .count()
        })
        .collect();
    assert!(
        stored.contains(&1) && stored.iter().all(|&n| n <= 1),
        "{stored:?}"
    );

    let mut down = vec!["down", "--connect", &control[0]];
    down.extend(client.iter());
    let down = run(&down, &root(), Duration::from_secs(30));
    assert!(down.status.success(), "{}", down.stderr);
    for (k, d) in daemons.into_iter().enumerate() {
        if let Some(d) = d {
            let out = wait(d, Duration::from_secs(60), "daemon");
            assert!(out.status.success(), "daemon m{}:\n{}", k + 2, out.stderr);
        }
    }
}

/// The issue's own check, as a user runs it: `activemap bench results --suite
/// benchmarks/smoke.yaml --connect …` (FBE and `fisher` on one house, 300 steps at 96×96) over
/// two daemons with mutual TLS on `quic/`, one slot each. Both cells run on the daemons, never
/// locally, come back with their files, and the suite's table and paired comparison are
/// written. About two minutes on 2 cores.
#[test]
fn the_smoke_suite_runs_over_two_mutual_tls_daemons() {
    let tmp = tempfile::tempdir().unwrap();
    let ids = test_pki(
        tmp.path(),
        "smoke",
        &[
            ("m2", &["127.0.0.2"]),
            ("m3", &["127.0.0.3"]),
            ("client", &["activemap-client"]),
        ],
    );
    let (control, runs) = suite_daemons(tmp.path(), 2);
    let daemons: Vec<_> = (0..2)
        .map(|k| up_suite_daemon(k, &control, &runs, &ids[k]))
        .collect();
    let client = tls_args(&ids[2]);
    until_answering(&control[0], &client, "m2, m3");

    let out = tmp.path().join("smoke");
    let mut args = vec![
        "bench",
        "results",
        "--suite",
        "benchmarks/smoke.yaml",
        "--out",
        out.to_str().unwrap(),
        "--connect",
        &control[0],
    ];
    args.extend(client.iter());
    let done = run(&args, &root(), Duration::from_secs(1200));
    let err = &done.stderr;
    assert!(done.status.success(), "{err}");
    assert!(!err.contains("started on local"), "{err}");
    assert!(err.contains("dispatch overhead per cell"), "{err}");
    let table = std::fs::read_to_string(out.join("results.md")).unwrap();
    assert!(
        table.contains("| fbe |") && table.contains("| fisher |"),
        "{table}"
    );
    assert!(table.contains("Paired against `fbe`"), "{table}");
    let metrics: Vec<_> = walk(&out)
        .into_iter()
        .filter(|p| p.file_name().is_some_and(|f| f == "metrics.json"))
        .collect();
    assert_eq!(metrics.len(), 2, "{metrics:?}");
    for m in &metrics {
        for brought in ["summary.json", "trajectory_est.tum", "report.html"] {
            assert!(
                m.with_file_name(brought).is_file(),
                "{brought} of {}",
                m.display()
            );
        }
    }

    let mut down = vec!["down", "--connect", &control[0]];
    down.extend(client.iter());
    let down = run(&down, &root(), Duration::from_secs(30));
    assert!(down.status.success(), "{}", down.stderr);
    for (k, d) in daemons.into_iter().enumerate() {
        let out = wait(d, Duration::from_secs(60), "daemon");
        assert!(out.status.success(), "daemon m{}:\n{}", k + 2, out.stderr);
    }
}

/// The control endpoints (`quic/127.0.0.{2,3,…}` on free ports) and run folders (under `dir`)
/// of `n` suite daemons `m2`, `m3`, ….
fn suite_daemons(dir: &std::path::Path, n: usize) -> (Vec<String>, Vec<std::path::PathBuf>) {
    (2..2 + n)
        .map(|i| {
            let ip = format!("127.0.0.{i}");
            (
                format!("quic/{ip}:{}", free_udp_port(&ip)),
                dir.join(format!("runs{i}")),
            )
        })
        .unzip()
}

/// Starts suite daemon `k` (`m{k+2}`, one slot, mutual TLS with `id`), joined to the first.
fn up_suite_daemon(
    k: usize,
    control: &[String],
    runs: &[std::path::PathBuf],
    id: &[String; 3],
) -> std::process::Child {
    let machine = format!("m{}", k + 2);
    let mut args = vec!["up", "--machine", &machine, "--listen", &control[k]];
    if k > 0 {
        args.extend(["--connect", &control[0]]);
    }
    args.extend(["--runs", runs[k].to_str().unwrap(), "--slots", "1"]);
    args.extend(tls_args(id));
    spawn(&args, &root())
}

/// Waits until `list` through `control` (as the TLS client `client`) names the daemons
/// `machines` (`m2, m3`) as answering; fails after about a minute.
fn until_answering(control: &str, client: &[&str], machines: &str) {
    let mut list = vec!["list", "--connect", control];
    list.extend(client.iter());
    let answered = (0..120).any(|_| {
        let out = run(&list, &root(), Duration::from_secs(60));
        let all = out
            .stderr
            .contains(&format!("daemons answering: {machines}"));
        if !all {
            std::thread::sleep(Duration::from_millis(250));
        }
        all
    });
    assert!(answered, "the daemons {machines} never all answered");
}

/// Every file under `dir`.
fn walk(dir: &std::path::Path) -> Vec<std::path::PathBuf> {
    let mut out = Vec::new();
    for entry in std::fs::read_dir(dir).unwrap().flatten() {
        let path = entry.path();
        if path.is_dir() {
            out.extend(walk(&path));
        } else {
            out.push(path);
        }
    }
    out
}
