//! Small deterministic operators used by the runtime's own tests and as examples: a counter source,
//! a doubler, an RGB-D frame source that writes in place, and a bit-exact frame checker.

pub mod counter_source;
pub mod doubler;
pub mod frame_checker;
pub mod frame_source;
