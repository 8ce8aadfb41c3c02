//! Dataflow runtime: operator API, iceoryx2/Zenoh transport, launcher, recorder and replay.
