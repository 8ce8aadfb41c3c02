//! Seeded sensor and actuation noise: off by default, with a `realistic` preset.
//!
//! - **Depth** (structured-light / active-stereo model, [`DepthNoise`]): per pixel a Gaussian
//!   error of standard deviation σ(z) = σ0 + c2·z² (stereo depth error grows with the square of
//!   the depth, because depth is inversely proportional to disparity); readings below a minimum
//!   or beyond a maximum range are 0 (no return); pixels at depth discontinuities are dropped with
//!   a probability (stereo matching and structured-light decoding fail at occlusion edges); and a
//!   random fraction of the remaining valid pixels is dropped. 0 stays "no reading", as in every
//!   frame of the project.
//! - **Colour** ([`ColourNoise`]): Gaussian per channel, in 8-bit levels.
//! - **Actuation** ([`ActuationNoise`], Habitat's noisy-actuation idea): per action, a Gaussian
//!   error on the travelled distance and on the turned angle, and a small heading change on
//!   forward moves. The noisy motion still goes through the collision model
//!   ([`crate::Navigation::try_forward`]); the true pose stays the ground truth and nothing
//!   tells the robot what the noise was.
//!
//! Sensor and actuation noise draw from separate ChaCha8 streams of the same seed
//! ([`SENSOR_STREAM`], [`ACTUATION_STREAM`]), so each is reproducible whatever the other does.
//!
//! # Configuration
//!
//! [`NoiseConfig`] deserialises from a preset name or a map (YAML of the `sim` node shown):
//!
//! ```yaml
//! noise: none                     # the default: noise-free
//! noise: realistic                # the preset (RealSense D435 depth, LoCoBot motion)
//! noise:                          # the preset with one value overridden
//!   preset: realistic
//!   depth: { sigma_z2: 0.003 }
//! noise:                          # no `preset`: start from none, set what is given
//!   depth: { sigma_0: 0.001, sigma_z2: 0.002, max_range: 8.0 }
//!   rgb: { sigma: 2.0 }
//! noise: { preset: realistic, actuation: none }   # a section may be a preset name too
//! ```
//!
//! Sections are `depth`, `rgb` and `actuation`; a section's keys override the preset's values
//! one by one. Unknown keys, non-numeric values and out-of-range values are refused with an
//! error naming the field (`noise.depth.sigma_z2`).

use crate::error::{Result, SimError};
use crate::render::RgbdFrame;
use rand::{Rng, RngCore, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, StandardNormal};
use serde::{Deserialize, Serialize};
use serde_json::Value;

/// ChaCha8 stream of the simulator seed that the sensor noise draws from.
pub const SENSOR_STREAM: u64 = 1;
/// ChaCha8 stream of the simulator seed that the actuation noise draws from.
pub const ACTUATION_STREAM: u64 = 2;

/// Depth noise and dropouts; all zero (off) by default.
///
/// The realistic values ([`DepthNoise::REALISTIC`]) follow the Intel RealSense D435 as given in
/// the Intel RealSense D400 Series Product Family Datasheet (Intel doc. 337029):
///
/// - `sigma_z2`: the datasheet's depth RMS error formula is
///   RMS = z²·subpixel / (f·baseline), with f the focal length in pixels. For the D435:
///   baseline 50 mm, typical subpixel 0.08, and at its recommended 848×480 depth mode with the
///   87° horizontal depth field of view f = 424 / tan(43.5°) ≈ 446.8 px. Hence
///   c2 = 0.08 / (446.8 px · 0.050 m) ≈ 0.0036 m⁻¹: σ ≈ 3.6 mm at 1 m, 14 mm at 2 m (0.7 %,
///   inside the datasheet's "≤ 2 % at 2 m" RMS specification), 58 mm at 4 m.
///   (Cross-check: Khoshelham & Elberink 2012, Sensors 12(2):1437–1454, measure the
///   Kinect v1's random error growing quadratically to about 4 cm at 5 m, i.e. c2 ≈ 0.0016.)
/// - `sigma_0` = 1 mm: a floor for the formula's near-range values, one default depth unit of
///   the D400 stream (0.001 m). An assumption, not a datasheet figure.
/// - `min_range` = 0.28 m: the D435's minimum depth distance (Min-Z) at maximum resolution.
/// - `max_range` = 10 m: the datasheet's approximate maximum range of the D435 (the ideal range
///   is about 0.3–3 m; beyond it the error above grows quickly).
/// - `dropout` = 0.01: the datasheet's fill-rate specification (≥ 99 % valid pixels).
/// - `edge_threshold` = 0.05 and `edge_dropout` = 0.5: the invalid band at occlusion edges
///   (left-camera shadows of stereo, undecodable pattern of structured light) is an assumption:
///   a pixel whose depth differs from a 4-neighbour by more than 5 % is dropped with
///   probability ½. (A 5 % step is larger than the step between neighbouring pixels of the
///   floor at 10 m seen from the robot's 0.88 m camera at 800 px / 90°, about 3 %.)
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct DepthNoise {
    /// Constant term σ0 of the depth noise standard deviation, metres.
    pub sigma_0: f64,
    /// Quadratic coefficient c2 of σ(z) = σ0 + c2·z², 1/metres.
    pub sigma_z2: f64,
    /// Readings closer than this are 0 (no return), metres; 0 = no minimum.
    pub min_range: f64,
    /// Readings farther than this are 0 (no return), metres; 0 = no maximum.
    pub max_range: f64,
    /// A pixel is at a depth edge when a 4-neighbour differs by more than this fraction of the
    /// smaller of the two depths (or reads 0); must be > 0 when `edge_dropout` is.
    pub edge_threshold: f64,
    /// Probability that a pixel at a depth edge reads 0.
    pub edge_dropout: f64,
    /// Probability that any other valid pixel reads 0.
    pub dropout: f64,
}

impl DepthNoise {
    /// The Intel RealSense D435 figures derived in the type's documentation.
    pub const REALISTIC: Self = Self {
        sigma_0: 0.001,
        sigma_z2: 0.0036,
        min_range: 0.28,
        max_range: 10.0,
        edge_threshold: 0.05,
        edge_dropout: 0.5,
        dropout: 0.01,
    };

    /// The standard deviation of the depth noise at depth `z` metres: σ0 + c2·z².
    pub fn sigma_at(&self, z: f64) -> f64 {
        self.sigma_0 + self.sigma_z2 * z * z
    }

    /// Whether this changes any reading.
    pub fn is_active(&self) -> bool {
        self.sigma_0 > 0.0
            || self.sigma_z2 > 0.0
            || self.min_range > 0.0
            || self.max_range > 0.0
            || self.edge_dropout > 0.0
            || self.dropout > 0.0
    }

    fn validate(&self) -> Result<()> {
        non_negative("noise.depth.sigma_0", self.sigma_0)?;
        non_negative("noise.depth.sigma_z2", self.sigma_z2)?;
        non_negative("noise.depth.min_range", self.min_range)?;
        non_negative("noise.depth.max_range", self.max_range)?;
        if self.max_range > 0.0 && self.max_range <= self.min_range {
            return invalid(
                "noise.depth.max_range",
                self.max_range,
                "must exceed min_range (or be 0: no maximum)",
            );
        }
        non_negative("noise.depth.edge_threshold", self.edge_threshold)?;
        probability("noise.depth.edge_dropout", self.edge_dropout)?;
        if self.edge_dropout > 0.0 && self.edge_threshold <= 0.0 {
            return invalid(
                "noise.depth.edge_threshold",
                self.edge_threshold,
                "must be > 0 when edge_dropout is",
            );
        }
        probability("noise.depth.dropout", self.dropout)
    }
}

/// Colour noise; zero (off) by default.
///
/// Realistic value ([`ColourNoise::REALISTIC`]): σ = 2 levels. The D400 datasheet gives no
/// colour-noise figure; two 8-bit levels of temporal noise is an assumption for a well-lit
/// indoor CMOS colour camera.
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ColourNoise {
    /// Standard deviation per channel, 8-bit levels.
    pub sigma: f64,
}

impl ColourNoise {
    /// The assumed realistic colour noise (see the type's documentation).
    pub const REALISTIC: Self = Self { sigma: 2.0 };

    /// Whether this changes any pixel.
    pub fn is_active(&self) -> bool {
        self.sigma > 0.0
    }

    fn validate(&self) -> Result<()> {
        non_negative("noise.rgb.sigma", self.sigma)
    }
}

/// Actuation noise; zero (exact actions) by default.
///
/// A forward action of commanded length d travels d + σ_d·n₁ with
/// σ_d = √((`forward_sigma_frac`·d)² + `forward_sigma_m`²), along the heading turned by half of
/// a heading change δ = `heading_sigma_deg`·n₂ that the action also applies (a constant-curvature
/// arc's chord). A turn of commanded angle a turns a + `turn_sigma_deg`·n₃. The n are standard
/// normal draws; travelled distance and turned angle never change sign (clamped at 0).
///
/// Realistic values ([`ActuationNoise::REALISTIC`]) from Habitat's PyRobot LoCoBot model
/// (habitat-sim `habitat_sim/agent/controls/pyrobot_noisy_controls.py`, parameters measured
/// with PyRobot on the LoCoBot, ILQR controller, the default there). Per Habitat action, that
/// model's mean errors are: on a forward move 0.014 m along the motion, 0.009 m across it and
/// 0.008 rad of heading; on a turn 0.023 rad (1.3°) of rotation. Habitat applies them as
/// absolute errors per action of its own size (0.25 m forward, 10° turns in its default
/// configuration; Habitat Challenge 2020 used 30° turns with half the noise). This project's
/// actions are much smaller (5 cm, 5°), so the preset scales those errors with the action and
/// uses them as zero-mean standard deviations (an assumption: the model's bias and its
/// truncation at 3σ are left out, and its cross-track term is not modelled):
///
/// - `forward_sigma_frac` = 0.014 / 0.25 = 0.056 of the step (2.8 mm on 5 cm);
/// - `heading_sigma_deg` = 0.008 rad (0.46°) per 0.25 m scaled to 5 cm ≈ 0.09°;
/// - `turn_sigma_deg` = 1.32° per 10° scaled to 5° = 0.66°.
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ActuationNoise {
    /// Standard deviation of the travelled distance as a fraction of the commanded step.
    pub forward_sigma_frac: f64,
    /// Standard deviation of the travelled distance independent of the step, metres (added
    /// to the fractional part in quadrature).
    pub forward_sigma_m: f64,
    /// Standard deviation of the heading change of a forward move, degrees.
    pub heading_sigma_deg: f64,
    /// Standard deviation of the turned angle, degrees.
    pub turn_sigma_deg: f64,
}

impl ActuationNoise {
    /// The LoCoBot-derived values of the type's documentation.
    pub const REALISTIC: Self = Self {
        forward_sigma_frac: 0.056,
        forward_sigma_m: 0.0,
        heading_sigma_deg: 0.09,
        turn_sigma_deg: 0.66,
    };

    /// Whether any action is perturbed.
    pub fn is_active(&self) -> bool {
        self.forward_sigma_frac > 0.0
            || self.forward_sigma_m > 0.0
            || self.heading_sigma_deg > 0.0
            || self.turn_sigma_deg > 0.0
    }

    /// Standard deviation of the travelled distance of a forward step of `step` metres.
    pub fn forward_sigma(&self, step: f64) -> f64 {
        (self.forward_sigma_frac * step).hypot(self.forward_sigma_m)
    }

    fn validate(&self) -> Result<()> {
        non_negative(
            "noise.actuation.forward_sigma_frac",
            self.forward_sigma_frac,
        )?;
        non_negative("noise.actuation.forward_sigma_m", self.forward_sigma_m)?;
        non_negative("noise.actuation.heading_sigma_deg", self.heading_sigma_deg)?;
        non_negative("noise.actuation.turn_sigma_deg", self.turn_sigma_deg)
    }
}

/// The simulator's noise: depth, colour and actuation. The default is noise-free.
///
/// Deserialises from `none`, `realistic` or a map (see the [module documentation](self));
/// serialises as the fully explicit map, which reads back to the same value.
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize)]
pub struct NoiseConfig {
    /// Depth noise and dropouts.
    pub depth: DepthNoise,
    /// Colour noise.
    pub rgb: ColourNoise,
    /// Actuation noise.
    pub actuation: ActuationNoise,
}

/// A named noise configuration.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum NoisePreset {
    /// Noise-free.
    None,
    /// RealSense D435 depth, assumed colour noise, LoCoBot-derived actuation.
    Realistic,
}

impl NoisePreset {
    /// The accepted preset names.
    pub const NAMES: [&'static str; 2] = ["none", "realistic"];

    /// The preset of a name (`none`, `realistic`).
    pub fn from_name(name: &str) -> Option<Self> {
        match name {
            "none" => Some(Self::None),
            "realistic" => Some(Self::Realistic),
            _ => None,
        }
    }

    /// The preset's configuration.
    pub fn config(self) -> NoiseConfig {
        match self {
            Self::None => NoiseConfig::default(),
            Self::Realistic => NoiseConfig {
                depth: DepthNoise::REALISTIC,
                rgb: ColourNoise::REALISTIC,
                actuation: ActuationNoise::REALISTIC,
            },
        }
    }
}

impl NoiseConfig {
    /// Noise-free (the default).
    pub fn none() -> Self {
        NoisePreset::None.config()
    }

    /// The `realistic` preset.
    pub fn realistic() -> Self {
        NoisePreset::Realistic.config()
    }

    /// Whether frames get any noise.
    pub fn sensor_active(&self) -> bool {
        self.depth.is_active() || self.rgb.is_active()
    }

    /// Whether anything is noisy.
    pub fn is_active(&self) -> bool {
        self.sensor_active() || self.actuation.is_active()
    }

    /// Checks every value; the error names the field (`noise.depth.dropout`).
    pub fn validate(&self) -> Result<()> {
        self.depth.validate()?;
        self.rgb.validate()?;
        self.actuation.validate()
    }

    /// Reads the configuration syntax of the [module documentation](self) from a JSON value
    /// (the form YAML configs take); the error names the offending field.
    pub fn from_value(value: &Value) -> std::result::Result<Self, String> {
        let config = match value {
            Value::Null => Self::none(),
            Value::String(name) => preset("noise", name)?.config(),
            Value::Object(map) => {
                let mut config = match map.get("preset") {
                    None => Self::none(),
                    Some(Value::String(name)) => preset("noise.preset", name)?.config(),
                    Some(other) => {
                        return Err(format!("noise.preset: expected a preset name, got {other}"));
                    }
                };
                for (key, v) in map {
                    match key.as_str() {
                        "preset" => {}
                        "depth" => config.depth = section("depth", &config.depth, v, |p| p.depth)?,
                        "rgb" => config.rgb = section("rgb", &config.rgb, v, |p| p.rgb)?,
                        "actuation" => {
                            config.actuation =
                                section("actuation", &config.actuation, v, |p| p.actuation)?;
                        }
                        _ => {
                            return Err(format!(
                                "noise: unknown key `{key}`, expected one of `preset`, `depth`, \
                                 `rgb`, `actuation`"
                            ));
                        }
                    }
                }
                config
            }
            other => {
                return Err(format!(
                    "noise: expected a preset name ({}) or a map, got {other}",
                    NoisePreset::NAMES.join(", ")
                ));
            }
        };
        config.validate().map_err(|e| e.to_string())?;
        Ok(config)
    }
}

impl<'de> Deserialize<'de> for NoiseConfig {
    fn deserialize<D: serde::Deserializer<'de>>(d: D) -> std::result::Result<Self, D::Error> {
        let value = Value::deserialize(d)?;
        Self::from_value(&value).map_err(serde::de::Error::custom)
    }
}

fn preset(field: &str, name: &str) -> std::result::Result<NoisePreset, String> {
    NoisePreset::from_name(name).ok_or_else(|| {
        format!(
            "{field}: unknown preset \"{name}\", expected one of {}",
            NoisePreset::NAMES.join(", ")
        )
    })
}

/// One section (`depth`, `rgb`, `actuation`): a preset name, or keys overriding `base`.
fn section<T: Serialize + serde::de::DeserializeOwned>(
    name: &str,
    base: &T,
    value: &Value,
    of_preset: impl Fn(NoiseConfig) -> T,
) -> std::result::Result<T, String> {
    match value {
        Value::String(p) => Ok(of_preset(preset(&format!("noise.{name}"), p)?.config())),
        Value::Object(overrides) => {
            let Ok(Value::Object(mut merged)) = serde_json::to_value(base) else {
                return Err(format!("noise.{name}: cannot represent the base values"));
            };
            for (key, v) in overrides {
                if merged.contains_key(key) && !v.is_number() {
                    return Err(format!("noise.{name}.{key}: expected a number, got {v}"));
                }
                merged.insert(key.clone(), v.clone());
            }
            serde_json::from_value(Value::Object(merged)).map_err(|e| format!("noise.{name}: {e}"))
        }
        other => Err(format!(
            "noise.{name}: expected a map of values or a preset name, got {other}"
        )),
    }
}

fn invalid(field: &'static str, value: f64, reason: &'static str) -> Result<()> {
    Err(SimError::InvalidConfig {
        field,
        value: value.to_string(),
        reason,
    })
}

fn non_negative(field: &'static str, v: f64) -> Result<()> {
    if v.is_finite() && v >= 0.0 {
        Ok(())
    } else {
        invalid(field, v, "must be finite and >= 0")
    }
}

fn probability(field: &'static str, v: f64) -> Result<()> {
    if (0.0..=1.0).contains(&v) {
        Ok(())
    } else {
        invalid(field, v, "must be a probability in [0, 1]")
    }
}

/// Applies depth and colour noise to frames, drawing from the sensor stream of a seed.
///
/// Draws go in pixel order, depth first, then colour; how many draws a pixel takes depends on
/// the clean frame only, so a seed and a clean frame give one noisy frame. Edge decisions read
/// the clean depth (two reusable row buffers), so dropping a pixel never makes its neighbours
/// edges. No allocation once warm.
#[derive(Debug, Clone)]
pub struct SensorNoiseSampler {
    depth: DepthNoise,
    rgb: ColourNoise,
    /// The colour noise as integer level offsets (built when `rgb` is active).
    levels: LevelNoise,
    rng: ChaCha8Rng,
    /// Clean depth of the previous row (edge test).
    prev_row: Vec<f32>,
    /// Clean depth of the current row (edge test).
    cur_row: Vec<f32>,
}

impl SensorNoiseSampler {
    /// The sensor noise of `config`, seeded by `seed` ([`SENSOR_STREAM`]).
    pub fn new(config: &NoiseConfig, seed: u64) -> Self {
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        rng.set_stream(SENSOR_STREAM);
        Self {
            depth: config.depth,
            rgb: config.rgb,
            levels: LevelNoise::new(config.rgb.sigma),
            rng,
            prev_row: Vec::new(),
            cur_row: Vec::new(),
        }
    }

    /// Adds noise to a frame in place.
    pub fn apply(&mut self, frame: &mut RgbdFrame) {
        let width = frame.width() as usize;
        self.apply_to(&mut frame.rgb, &mut frame.depth, width);
    }

    /// Adds noise in place to RGB8 and depth buffers of an image `width` pixels wide (e.g. a
    /// loaned shared-memory frame), with the same draws as [`SensorNoiseSampler::apply`].
    pub fn apply_to(&mut self, rgb: &mut [u8], depth: &mut [f32], width: usize) {
        if self.depth.is_active() && width > 0 {
            self.apply_depth(depth, width);
        }
        if self.rgb.is_active() {
            for c in rgb.iter_mut() {
                let k = self.levels.sample(&mut self.rng);
                *c = (*c as i32 + k).clamp(0, 255) as u8;
            }
        }
    }

    fn apply_depth(&mut self, depth: &mut [f32], width: usize) {
        let d = self.depth;
        let height = depth.len() / width;
        let edges = d.edge_dropout > 0.0;
        let noisy = d.sigma_0 > 0.0 || d.sigma_z2 > 0.0;
        let max_range = if d.max_range > 0.0 {
            d.max_range
        } else {
            f64::INFINITY
        };
        let threshold = d.edge_threshold as f32;
        let Self {
            rng,
            prev_row,
            cur_row,
            ..
        } = self;
        if edges {
            prev_row.resize(width, 0.0);
            cur_row.resize(width, 0.0);
        }
        for y in 0..height {
            let row = y * width;
            if edges {
                cur_row.copy_from_slice(&depth[row..row + width]);
            }
            for x in 0..width {
                let i = row + x;
                let z = depth[i];
                if z <= 0.0 {
                    continue;
                }
                let zf = z as f64;
                if zf < d.min_range || zf > max_range {
                    depth[i] = 0.0;
                    continue;
                }
                if edges {
                    // Clean neighbours: this row and the one above from the buffers, the one
                    // below not yet touched.
                    let differs = |n: f32| n <= 0.0 || (z - n).abs() > threshold * z.min(n);
                    let edge = (x > 0 && differs(cur_row[x - 1]))
                        || (x + 1 < width && differs(cur_row[x + 1]))
                        || (y > 0 && differs(prev_row[x]))
                        || (y + 1 < height && differs(depth[i + width]));
                    if edge && rng.random::<f64>() < d.edge_dropout {
                        depth[i] = 0.0;
                        continue;
                    }
                }
                if d.dropout > 0.0 && rng.random::<f64>() < d.dropout {
                    depth[i] = 0.0;
                    continue;
                }
                if noisy {
                    let n: f64 = StandardNormal.sample(rng);
                    let v = zf + d.sigma_at(zf) * n;
                    // A reading cannot be at or behind the camera: no return.
                    depth[i] = if v > 0.0 { v as f32 } else { 0.0 };
                }
            }
            if edges {
                std::mem::swap(prev_row, cur_row);
            }
        }
    }
}

/// Integer colour noise: the distribution of k = round(σ·n), n standard normal, as cumulative
/// thresholds on a 32-bit uniform draw, so one draw and a binary search give a level's offset.
/// For an integer level c, round(c + σ·n) = c + round(σ·n), so clamping c + k to 0…255 gives
/// the rounded Gaussian reading exactly, up to probabilities of 2⁻³² (tails beyond 7σ are cut).
/// It takes half the random bits of a normal sample per channel and no floating point.
#[derive(Debug, Clone, Default)]
struct LevelNoise {
    /// The offset of the first threshold.
    lowest: i32,
    /// `thresholds[j]`: 2³²·P(k ≤ lowest + j); the last is 2³².
    thresholds: Vec<u64>,
    /// `guide[b]`: the first `j` whose threshold exceeds the lowest draw of bucket `b` (the top
    /// [`LevelNoise::GUIDE_BITS`] bits of a draw), where the search for a draw starts.
    guide: Vec<u16>,
}

impl LevelNoise {
    fn new(sigma: f64) -> Self {
        if !(sigma.is_finite() && sigma > 0.0) {
            return Self::default();
        }
        // Offsets beyond ±255 clamp like ±255 on every level.
        let reach = (7.0 * sigma + 1.0).ceil().min(255.0) as i32;
        // Φ((k + ½)/σ) for k = 0…reach−1 by Simpson's rule on the normal density, piece by
        // piece (steps of at most 0.005 in units of σ; error far below 2⁻³²).
        let density = |t: f64| (-0.5 * t * t).exp() / (2.0 * std::f64::consts::PI).sqrt();
        let mut upper = Vec::with_capacity(reach as usize);
        let (mut t0, mut phi) = (0.0f64, 0.5f64);
        for k in 0..reach {
            let t1 = (k as f64 + 0.5) / sigma;
            let n = (((t1 - t0) / 0.005).ceil() as usize)
                .max(2)
                .next_multiple_of(2);
            let h = (t1 - t0) / n as f64;
            let inner: f64 = (1..n)
                .map(|i| (if i % 2 == 1 { 4.0 } else { 2.0 }) * density(t0 + i as f64 * h))
                .sum();
            phi += h / 3.0 * (density(t0) + inner + density(t1));
            upper.push(phi.min(1.0));
            t0 = t1;
        }
        // P(k ≤ j): 1 − Φ((−j + ½)/σ) for j < 0, Φ((j + ½)/σ) for j ≥ 0; the last is 1.
        let scale = 4_294_967_296.0;
        let mut thresholds = Vec::with_capacity(2 * reach as usize + 1);
        for j in -reach..reach {
            let p = if j < 0 {
                1.0 - upper[(-j - 1) as usize]
            } else {
                upper[j as usize]
            };
            thresholds.push((p * scale).round() as u64);
        }
        thresholds.push(1 << 32);
        let guide = (0..1u64 << Self::GUIDE_BITS)
            .map(|b| {
                let first = b << (32 - Self::GUIDE_BITS);
                thresholds.partition_point(|&t| t <= first) as u16
            })
            .collect();
        Self {
            lowest: -reach,
            thresholds,
            guide,
        }
    }

    /// Buckets of the guide table: 2¹² (a search then rarely takes a step).
    const GUIDE_BITS: u32 = 12;

    fn sample(&self, rng: &mut ChaCha8Rng) -> i32 {
        let u = rng.next_u32();
        let mut j = self.guide[(u >> (32 - Self::GUIDE_BITS)) as usize] as usize;
        // Ends at the last threshold (2³²) at the latest.
        while self.thresholds[j] <= u as u64 {
            j += 1;
        }
        self.lowest + j as i32
    }
}

/// Perturbs actions, drawing from the actuation stream of a seed.
///
/// An inactive configuration draws nothing and returns the commanded motion exactly; an active
/// one draws two normals per forward move and one per turn, whatever the collisions.
#[derive(Debug, Clone)]
pub struct ActuationNoiseSampler {
    noise: ActuationNoise,
    rng: ChaCha8Rng,
}

impl ActuationNoiseSampler {
    /// The actuation noise of `config`, seeded by `seed` ([`ACTUATION_STREAM`]).
    pub fn new(config: &NoiseConfig, seed: u64) -> Self {
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        rng.set_stream(ACTUATION_STREAM);
        Self {
            noise: config.actuation,
            rng,
        }
    }

    /// A forward move commanded as `step` metres (≥ 0): the distance to travel and the heading
    /// change, radians (travel along the old heading plus half of it).
    pub fn forward(&mut self, step: f64) -> (f64, f64) {
        if !self.noise.is_active() {
            return (step, 0.0);
        }
        let n1: f64 = StandardNormal.sample(&mut self.rng);
        let n2: f64 = StandardNormal.sample(&mut self.rng);
        let distance = (step + self.noise.forward_sigma(step) * n1).max(0.0);
        (distance, self.noise.heading_sigma_deg.to_radians() * n2)
    }

    /// A turn commanded as `angle` radians (≥ 0, the magnitude): the angle to turn.
    pub fn turn(&mut self, angle: f64) -> f64 {
        if !self.noise.is_active() {
            return angle;
        }
        let n: f64 = StandardNormal.sample(&mut self.rng);
        (angle + self.noise.turn_sigma_deg.to_radians() * n).max(0.0)
    }
}
