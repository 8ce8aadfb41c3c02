//! The built-in dataflow operators: thin wrappers wiring library algorithms to typed inputs and outputs.
