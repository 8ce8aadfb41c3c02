//! Every malformed file in tests/data/dataflows/bad/ fails validation with its location; the
//! reference dataflow.yaml, the named flows of flows/ and the good test flows validate.

use std::time::Duration;

use super::harness::{root, run};

#[test]
fn every_bad_dataflow_fails_with_its_location() {
    let dir = root().join("tests/data/dataflows/bad");
    let mut files: Vec<_> = std::fs::read_dir(&dir)
        .expect("bad dataflow folder")
        .flatten()
        .map(|e| e.path())
        .filter(|p| p.extension().is_some_and(|e| e == "yaml"))
        .collect();
    files.sort();
    assert!(
        files.len() >= 15,
        "expected one file per error kind, found {}",
        files.len()
    );
    for file in files {
        let text = std::fs::read_to_string(&file).unwrap();
        let expect = text
            .lines()
            .next()
            .and_then(|l| l.strip_prefix("# expect: "))
            .unwrap_or_else(|| {
                panic!(
                    "{}: first line must be `# expect: LINE:COL message`",
                    file.display()
                )
            });
        let (loc, fragment) = expect.split_once(' ').expect("LINE:COL message");
        let path = file.to_string_lossy().to_string();
        let out = run(&["validate", &path], &root(), Duration::from_secs(30));
        assert!(!out.status.success(), "{path} validated but should not");
        let wanted = format!("{path}:{loc}: error: ");
        let line = out
            .stderr
            .lines()
            .find(|l| l.contains(&wanted))
            .unwrap_or_else(|| panic!("{path}: no diagnostic at {loc}; stderr:\n{}", out.stderr));
        assert!(
            line.contains(fragment),
            "{path}: diagnostic at {loc} lacks `{fragment}`:\n{line}"
        );
    }
}

#[test]
fn reference_and_test_dataflows_validate() {
    for file in [
        "dataflow.yaml",
        "flows/fisher.yaml",
        "flows/fisher_eig_only.yaml",
        "flows/llm.yaml",
        "tests/data/dataflows/good/counter.yaml",
        "tests/data/dataflows/good/frames.yaml",
    ] {
        let out = run(&["validate", file], &root(), Duration::from_secs(30));
        assert!(out.status.success(), "{file}: {}", out.stderr);
        assert!(out.stdout.contains(": ok ("), "{}", out.stdout);
    }
    // The graph names every edge of the loop, including the follower → sim back edge.
    let out = run(
        &["graph", "dataflow.yaml", "--format", "dot"],
        &root(),
        Duration::from_secs(30),
    );
    assert!(out.status.success());
    assert!(
        out.stdout
            .contains("\"follower\" -> \"sim\" [label=\"action → action : Action\"]"),
        "{}",
        out.stdout
    );
}

/// `--set` overrides are checked like the file: a value the node refuses names the override.
#[test]
fn set_overrides_are_validated_and_named() {
    let check = |args: &[&str]| run(args, &root(), Duration::from_secs(30));
    let out = check(&["validate", "dataflow.yaml", "--set", "sim.width=abc"]);
    assert!(!out.status.success(), "{}", out.stdout);
    assert!(
        out.stderr
            .contains("--set sim.width=abc: error: bad config for operator `sim`"),
        "{}",
        out.stderr
    );
    let out = check(&["validate", "dataflow.yaml", "--set", "simm.width=96"]);
    assert!(out.stderr.contains("no node `simm`"), "{}", out.stderr);
    // The simulator's scene alone: the evaluator would judge house 3's episode against house 7.
    let mut args = vec!["validate", "dataflow.yaml", "--set", "sim.width=96"];
    args.extend(["--set", "sim.scene=house:3"]);
    let out = check(&args);
    assert!(!out.status.success(), "{}", out.stdout);
    assert!(
        out.stderr.contains("scene mismatch") && out.stderr.contains("evaluator.scene=X"),
        "{}",
        out.stderr
    );
    args.extend(["--set", "evaluator.scene=house:3"]);
    let out = check(&args);
    assert!(out.status.success(), "{}", out.stderr);
    assert!(out.stdout.contains(": ok ("), "{}", out.stdout);
}
