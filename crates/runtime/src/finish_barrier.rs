//! The finish barrier of a distributed run: a machine whose nodes are done keeps its router up
//! until every other machine's nodes are done too.
//!
//! Each machine's launcher session is that machine's Zenoh router, and other machines' traffic
//! may pass through it (machine b connects to machine a's router and reaches a's producers
//! there). A launcher that closed its router as soon as its own nodes ended would cut off
//! what was still in flight to the others: the last samples and the end-of-stream markers of
//! a's producers, so that b's consumers lose data or wait for an end that never comes.
//!
//! So every launcher holds a liveliness token `…/_ctl/alive/<machine>` for the whole run and,
//! once its own nodes are done, announces `…/_ctl/finished` (payload: its machine id) until
//! every other machine has either announced the same or lost its token (its launcher ended or
//! became unreachable: nothing is left to wait for).

use std::collections::BTreeSet;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};

use zenoh::Wait;
use zenoh::handlers::FifoChannelHandler;
use zenoh::sample::{Sample, SampleKind};

use crate::RuntimeError;
use crate::dataflow::DropPolicy;
use crate::node::control_key;
use crate::transport::{ZenohPublisher, ZenohSubscriber};

/// How often a finished machine repeats its announcement while it waits.
const ANNOUNCE_EVERY: Duration = Duration::from_millis(200);

/// How long a machine whose launcher was never seen is waited for (it cannot have run: the
/// start barrier needs every node of every machine).
const UNSEEN_GRACE: Duration = Duration::from_secs(10);

/// One machine's side of the finish barrier (declared when the run starts, so no announcement
/// is missed).
pub(crate) struct FinishBarrier {
    machine: String,
    others: BTreeSet<String>,
    _token: zenoh::liveliness::LivelinessToken,
    alive: zenoh::pubsub::Subscriber<FifoChannelHandler<Sample>>,
    finished: ZenohSubscriber,
    announce: ZenohPublisher,
    stop: ZenohSubscriber,
}

impl FinishBarrier {
    /// The barrier of `machine` among `machines` on the run's router session; `None` when the
    /// run has no other machine.
    pub(crate) fn declare(
        session: &zenoh::Session,
        run_id: &str,
        machine: &str,
        machines: impl IntoIterator<Item = String>,
    ) -> Result<Option<Self>, RuntimeError> {
        let others: BTreeSet<String> = machines.into_iter().filter(|m| m != machine).collect();
        if others.is_empty() {
            return Ok(None);
        }
        let err = |what: &str, e: zenoh::Error| {
            RuntimeError::Other(format!("zenoh: finish barrier: {what}: {e}"))
        };
        let token = session
            .liveliness()
            .declare_token(control_key(run_id, &format!("alive/{machine}")))
            .wait()
            .map_err(|e| err("liveliness token", e))?;
        let alive = session
            .liveliness()
            .declare_subscriber(control_key(run_id, "alive/*"))
            .history(true)
            .wait()
            .map_err(|e| err("liveliness subscriber", e))?;
        Ok(Some(Self {
            machine: machine.to_string(),
            others,
            _token: token,
            alive,
            finished: ZenohSubscriber::create(
                session,
                &control_key(run_id, "finished"),
                1024,
                DropPolicy::DropOldest,
            )?,
            announce: ZenohPublisher::create(session, &control_key(run_id, "finished"))?,
            stop: ZenohSubscriber::create(
                session,
                &control_key(run_id, "stop"),
                1,
                DropPolicy::DropOldest,
            )?,
        }))
    }

    /// Announce that this machine's nodes are done and wait until every other machine's are
    /// (or their launcher is gone), a stop is broadcast, or `stop` is set. `say` reports the
    /// wait once. Returns the machines that ended without announcing (gone).
    pub(crate) fn wait_for_others(
        &self,
        stop: &AtomicBool,
        say: impl Fn(String),
    ) -> Result<Vec<String>, RuntimeError> {
        let mut finished: BTreeSet<String> = BTreeSet::new();
        let mut seen_alive: BTreeSet<String> = BTreeSet::new();
        let mut alive: BTreeSet<String> = BTreeSet::new();
        let mut last_announce: Option<Instant> = None;
        let mut said = false;
        let started = Instant::now();
        let prefix_len = self.prefix_len();
        loop {
            if last_announce.is_none_or(|t| t.elapsed() >= ANNOUNCE_EVERY) {
                self.announce.send(0, self.machine.as_bytes().to_vec())?;
                last_announce = Some(Instant::now());
            }
            while let Some(sample) = self.finished.recv(None)? {
                finished.insert(String::from_utf8_lossy(&sample.payload().to_bytes()).into());
            }
            while let Ok(Some(sample)) = self.alive.try_recv() {
                let key = sample.key_expr().as_str();
                let Some(machine) = key.get(prefix_len..) else {
                    continue;
                };
                match sample.kind() {
                    SampleKind::Put => {
                        seen_alive.insert(machine.to_string());
                        alive.insert(machine.to_string());
                    }
                    SampleKind::Delete => {
                        alive.remove(machine);
                    }
                }
            }
            let waiting: Vec<&String> = self
                .others
                .iter()
                .filter(|m| {
                    !finished.contains(*m)
                        && (alive.contains(*m)
                            || (!seen_alive.contains(*m) && started.elapsed() < UNSEEN_GRACE))
                })
                .collect();
            if waiting.is_empty() {
                return Ok(self
                    .others
                    .iter()
                    .filter(|m| !finished.contains(*m))
                    .cloned()
                    .collect());
            }
            if stop.load(Ordering::Relaxed) || self.stop.recv(None)?.is_some() {
                return Ok(Vec::new());
            }
            if !said {
                said = true;
                say(format!(
                    "activemap: machine `{}` is done; keeping its router up for {} (their \
                     traffic may pass through it)",
                    self.machine,
                    waiting
                        .iter()
                        .map(|m| format!("`{m}`"))
                        .collect::<Vec<_>>()
                        .join(", ")
                ));
            }
            std::thread::sleep(Duration::from_millis(20));
        }
    }

    /// Length of `…/_ctl/alive/` in the token keys.
    fn prefix_len(&self) -> usize {
        self.alive.key_expr().as_str().len() - 1
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::launch::free_port;
    use crate::transport::{ZenohSettings, open_zenoh};
    use std::sync::Arc;

    /// Two machines' routers on loopback, b connected to a (as a two-machine run).
    fn two_routers() -> (zenoh::Session, zenoh::Session) {
        let endpoint = format!("tcp/127.0.0.1:{}", free_port("127.0.0.1").unwrap());
        let router = |listen: Vec<String>, connect: Vec<String>| {
            open_zenoh(&ZenohSettings {
                mode: "router".into(),
                listen,
                connect,
                tls: None,
            })
            .unwrap()
        };
        let a = router(vec![endpoint.clone()], vec![]);
        let b = router(vec![], vec![endpoint]);
        (a, b)
    }

    fn machines() -> impl Iterator<Item = String> {
        ["a", "b"].into_iter().map(String::from)
    }

    /// Machines a and b of run `run_id`: their routers and their barriers.
    fn two_machines(
        run_id: &str,
    ) -> (zenoh::Session, zenoh::Session, FinishBarrier, FinishBarrier) {
        let (a, b) = two_routers();
        let barrier = |session: &zenoh::Session, machine: &str| {
            FinishBarrier::declare(session, run_id, machine, machines())
                .unwrap()
                .expect("two machines have a barrier")
        };
        let (barrier_a, barrier_b) = (barrier(&a, "a"), barrier(&b, "b"));
        (a, b, barrier_a, barrier_b)
    }

    #[test]
    fn a_single_machine_run_has_no_barrier() {
        let (a, _b) = two_routers();
        let only_a = FinishBarrier::declare(&a, "r1", "a", ["a".to_string()]).unwrap();
        assert!(only_a.is_none());
    }

    /// Machine a, done first, waits until machine b says it is done too, and both go.
    #[test]
    fn a_finished_machine_waits_for_the_other_to_finish() {
        let (_a, _b, barrier_a, barrier_b) = two_machines("r2");
        let b_done = Arc::new(AtomicBool::new(false));
        let b_thread = {
            let b_done = b_done.clone();
            std::thread::spawn(move || {
                // b's nodes run on for a while after a's have ended.
                std::thread::sleep(Duration::from_millis(800));
                b_done.store(true, Ordering::SeqCst);
                barrier_b
                    .wait_for_others(&AtomicBool::new(false), |_| {})
                    .unwrap()
            })
        };
        let said = std::sync::Mutex::new(Vec::new());
        let gone = barrier_a
            .wait_for_others(&AtomicBool::new(false), |m| said.lock().unwrap().push(m))
            .unwrap();
        assert!(b_done.load(Ordering::SeqCst), "a left before b was done");
        assert!(gone.is_empty(), "{gone:?}");
        assert!(b_thread.join().unwrap().is_empty());
        let said = said.into_inner().unwrap();
        assert_eq!(said.len(), 1, "{said:?}");
        assert!(
            said[0].contains("keeping its router up for `b`"),
            "{said:?}"
        );
    }

    /// A machine whose launcher is gone without a word (its token vanished) is not waited for,
    /// and is named.
    #[test]
    fn a_machine_whose_launcher_vanished_is_not_waited_for() {
        let (_a, b, barrier_a, barrier_b) = two_machines("r3");
        let closer = std::thread::spawn(move || {
            std::thread::sleep(Duration::from_millis(500));
            drop(barrier_b);
            b.close().wait().unwrap();
        });
        let started = Instant::now();
        let gone = barrier_a
            .wait_for_others(&AtomicBool::new(false), |_| {})
            .unwrap();
        closer.join().unwrap();
        assert_eq!(gone, vec!["b".to_string()]);
        assert!(
            started.elapsed() < UNSEEN_GRACE,
            "waited out the grace instead"
        );
    }

    /// A stop (Ctrl-C, `activemap stop`) ends the wait at once.
    #[test]
    fn a_stop_ends_the_wait() {
        let (_a, _b, barrier_a, _barrier_b) = two_machines("r4");
        let stop = AtomicBool::new(true);
        let started = Instant::now();
        let gone = barrier_a.wait_for_others(&stop, |_| {}).unwrap();
        assert!(gone.is_empty());
        assert!(started.elapsed() < Duration::from_secs(2));
    }
}
