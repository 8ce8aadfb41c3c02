//! Integration tests of the `activemap` binary: real processes, real shared memory and Zenoh.
//! Every process is started under a timeout, so a hang fails the test instead of blocking CI.

mod integration {
    mod bench;
    mod distributed;
    mod explore;
    mod faults;
    mod fisher;
    mod fuzz_regressions;
    pub mod harness;
    mod llm;
    mod processes;
    mod python_bridge;
    mod scene;
    mod validate;
    mod view;
}
