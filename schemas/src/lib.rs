//! Every message type of the dataflow and its topic, with schema versions.
