//! Driving an operator without any transport: the unit-test bench of an operator.
//!
//! A [`Harness`] builds the operator the way a node does (its config, a [`Context`] whose outputs
//! are the declared ports), feeds it events one at a time and keeps what it sends, in order, so
//! a test reads the outputs back typed. Port names and kinds are checked as a node checks them:
//! an input the operator does not declare, or a message of the wrong kind, is an error naming the
//! port.

use activemap_schemas::{MessageKind, Payload};

use crate::{Context, Event, Flow, Input, Operator, OperatorError, OutputSink, PortSpec};

/// One message the operator sent, in sending order.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Sent {
    /// Output port.
    pub port: String,
    /// Encoded payload, as the operator sent it.
    pub bytes: Vec<u8>,
}

/// Keeps every output in memory.
#[derive(Default)]
struct Collect {
    ports: Vec<String>,
    sent: Vec<Sent>,
}

impl OutputSink for Collect {
    fn send(&mut self, port: usize, bytes: &[u8]) -> Result<(), OperatorError> {
        self.sent.push(Sent {
            port: self.ports[port].clone(),
            bytes: bytes.to_vec(),
        });
        Ok(())
    }

    fn loan(
        &mut self,
        port: usize,
        len: usize,
        fill: &mut dyn FnMut(&mut [u8]) -> anyhow::Result<()>,
    ) -> Result<(), OperatorError> {
        crate::loan_on_heap(len, fill, |bytes| self.send(port, bytes))
    }
}

/// An operator under test, its ports and everything it has sent.
pub struct Harness<O: Operator> {
    operator: O,
    node_id: String,
    inputs: Vec<PortSpec>,
    outputs: Vec<(String, MessageKind)>,
    sink: Collect,
    max_steps: Option<u64>,
    seq: u64,
}

impl<O: Operator> Harness<O> {
    /// Builds the operator as node `node_id` with these ports (usually the `ALL` lists of its
    /// [`crate::ports!`] modules) and its config.
    pub fn new(
        node_id: &str,
        inputs: &[PortSpec],
        outputs: &[PortSpec],
        config: O::Config,
    ) -> anyhow::Result<Self> {
        Self::with_max_steps(node_id, inputs, outputs, config, None)
    }

    /// As [`Harness::new`], with the run's step budget (`Context::max_steps`).
    pub fn with_max_steps(
        node_id: &str,
        inputs: &[PortSpec],
        outputs: &[PortSpec],
        config: O::Config,
        max_steps: Option<u64>,
    ) -> anyhow::Result<Self> {
        let outputs: Vec<(String, MessageKind)> = outputs
            .iter()
            .map(|p| (p.name.to_string(), p.kind))
            .collect();
        let mut sink = Collect {
            ports: outputs.iter().map(|(n, _)| n.clone()).collect(),
            sent: Vec::new(),
        };
        let operator = {
            let mut ctx = Context::new(node_id, &outputs, &mut sink, max_steps);
            O::new(config, &mut ctx)?
        };
        Ok(Self {
            operator,
            node_id: node_id.to_string(),
            inputs: inputs.to_vec(),
            outputs,
            sink,
            max_steps,
            seq: 0,
        })
    }

    fn event(&mut self, event: Event<'_>) -> anyhow::Result<Flow> {
        let mut ctx = Context::new(&self.node_id, &self.outputs, &mut self.sink, self.max_steps);
        self.operator.on_event(event, &mut ctx)
    }

    fn input_kind(&self, port: &str) -> Result<MessageKind, OperatorError> {
        self.inputs
            .iter()
            .find(|p| p.name == port)
            .map(|p| p.kind)
            .ok_or_else(|| OperatorError::UnknownInput {
                node: self.node_id.clone(),
                port: port.to_string(),
            })
    }

    /// Delivers `message` on input `port` (which must carry `T`).
    pub fn input<T: Payload>(&mut self, port: &str, message: &T) -> anyhow::Result<Flow> {
        let kind = self.input_kind(port)?;
        if kind != T::KIND {
            return Err(OperatorError::WrongType {
                port: port.to_string(),
                declared: kind.name(),
                used: T::KIND.name(),
            }
            .into());
        }
        let bytes = message.to_bytes().map_err(|e| OperatorError::Encode {
            port: port.to_string(),
            source: e,
        })?;
        self.input_bytes(port, &bytes)
    }

    /// Delivers an encoded payload on input `port` (e.g. a large frame built in place).
    pub fn input_bytes(&mut self, port: &str, bytes: &[u8]) -> anyhow::Result<Flow> {
        let kind = self.input_kind(port)?;
        self.seq += 1;
        let seq = self.seq;
        self.event(Event::Input(Input {
            port,
            kind,
            seq,
            bytes,
        }))
    }

    /// Fires timer `name`.
    pub fn timer(&mut self, name: &str) -> anyhow::Result<Flow> {
        self.event(Event::Timer { name })
    }

    /// Ends input `port`'s stream (every producer finished).
    pub fn close(&mut self, port: &str) -> anyhow::Result<Flow> {
        self.input_kind(port)?;
        self.event(Event::InputClosed { port })
    }

    /// Stops the operator (its last event).
    pub fn stop(&mut self) -> anyhow::Result<Flow> {
        self.event(Event::Stop)
    }

    /// Everything sent so far, in order; the harness forgets it.
    pub fn take_all(&mut self) -> Vec<Sent> {
        std::mem::take(&mut self.sink.sent)
    }

    /// The messages sent on output `port` so far, decoded, in order; the harness forgets them
    /// (and keeps those of other ports).
    pub fn take<T: Payload>(&mut self, port: &str) -> Result<Vec<T>, OperatorError> {
        let Some((_, kind)) = self.outputs.iter().find(|(n, _)| n == port) else {
            return Err(OperatorError::UnknownOutput {
                node: self.node_id.clone(),
                port: port.to_string(),
            });
        };
        if *kind != T::KIND {
            return Err(OperatorError::WrongType {
                port: port.to_string(),
                declared: kind.name(),
                used: T::KIND.name(),
            });
        }
        let (mine, rest): (Vec<Sent>, Vec<Sent>) = std::mem::take(&mut self.sink.sent)
            .into_iter()
            .partition(|s| s.port == port);
        self.sink.sent = rest;
        mine.iter()
            .map(|s| {
                T::from_bytes(&s.bytes).map_err(|e| OperatorError::Decode {
                    port: port.to_string(),
                    source: e,
                })
            })
            .collect()
    }

    /// The operator itself, to inspect its state.
    pub fn operator(&self) -> &O {
        &self.operator
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use activemap_schemas::{Counter, Pose, TruePose};

    mod inputs {
        crate::ports! {
            VALUE = "value": activemap_schemas::MessageKind::Counter,
        }
    }
    mod outputs {
        crate::ports! {
            SUM = "sum": activemap_schemas::MessageKind::Counter,
            BLOB = "blob": activemap_schemas::MessageKind::GaussianMap,
        }
    }

    /// Sums its inputs; on each input also loans a 12-byte buffer and checks its alignment;
    /// stops at the `end` timer.
    struct Summer {
        total: i64,
        aligned: bool,
    }

    impl Operator for Summer {
        type Config = i64;
        fn new(start: i64, _: &mut Context<'_>) -> anyhow::Result<Self> {
            Ok(Self {
                total: start,
                aligned: true,
            })
        }
        fn on_event(&mut self, event: Event<'_>, ctx: &mut Context<'_>) -> anyhow::Result<Flow> {
            match event {
                Event::Input(input) => {
                    let c: Counter = input.decode()?;
                    self.total += c.value;
                    ctx.send(
                        outputs::SUM,
                        &Counter {
                            seq: input.seq,
                            value: self.total,
                        },
                    )?;
                    ctx.loan(outputs::BLOB, 12, |buf| {
                        self.aligned &= buf.as_ptr().align_offset(8) == 0;
                        buf.fill(7);
                        Ok(())
                    })?;
                    Ok(Flow::Continue)
                }
                Event::Timer { name: "end" } => Ok(Flow::Stop),
                _ => Ok(Flow::Continue),
            }
        }
    }

    fn harness() -> Harness<Summer> {
        Harness::new("summer", inputs::ALL, outputs::ALL, 10).unwrap()
    }

    #[test]
    fn outputs_come_back_typed_in_order_and_per_port() {
        let mut h = harness();
        for v in [1, 2, 3] {
            assert_eq!(
                h.input(inputs::VALUE, &Counter { seq: 0, value: v })
                    .unwrap(),
                Flow::Continue
            );
        }
        let sums: Vec<Counter> = h.take(outputs::SUM).unwrap();
        // Sequence numbers are the harness's, 1, 2, 3, as a producer's would be.
        assert_eq!(
            sums.iter().map(|c| (c.seq, c.value)).collect::<Vec<_>>(),
            [(1, 11), (2, 13), (3, 16)]
        );
        // The blobs were kept, 12 bytes each, from 8-byte aligned loans.
        let rest = h.take_all();
        assert_eq!(rest.len(), 3);
        assert!(rest.iter().all(|s| s.port == "blob" && s.bytes == [7; 12]));
        assert!(h.operator().aligned);
        assert_eq!(h.timer("end").unwrap(), Flow::Stop);
    }

    #[test]
    fn ports_and_kinds_are_checked_as_a_node_checks_them() {
        let mut h = harness();
        let wrong_port = h.input("valeu", &Counter { seq: 0, value: 1 }).unwrap_err();
        assert_eq!(wrong_port.to_string(), "node `summer` has no input `valeu`");
        let pose = TruePose {
            frame_id: 0,
            stamp: 0.0,
            t_world_camera: Pose::IDENTITY,
        };
        let wrong_kind = h.input(inputs::VALUE, &pose).unwrap_err();
        assert_eq!(
            wrong_kind.to_string(),
            "port `value` carries Counter, not TruePose"
        );
        assert!(h.take::<Counter>("total").is_err());
        assert!(h.take::<TruePose>(outputs::SUM).is_err());
        // Bytes that do not decode reach the operator, whose decode names the port.
        let bad = h.input_bytes(inputs::VALUE, &[0xff]).unwrap_err();
        assert!(format!("{bad:#}").starts_with("input `value`"), "{bad:#}");
        assert!(h.close("nope").is_err());
        assert_eq!(h.close(inputs::VALUE).unwrap(), Flow::Continue);
        assert_eq!(h.stop().unwrap(), Flow::Continue);
    }
}
