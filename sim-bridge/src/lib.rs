//! Built-in RGB-D simulator: mesh scenes, procedural houses, Habitat-style motion, ground truth.
