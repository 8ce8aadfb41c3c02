//! Behavioural tests of the simulator against analytic truth and real data.

mod artefacts;
mod auto_up_tests;
mod bridge_tests;
mod fixtures;
mod house_tests;
mod inspect_tests;
mod load_tests;
mod motion_tests;
mod noise_tests;
mod placement_tests;
mod render_tests;
mod truth_tests;
