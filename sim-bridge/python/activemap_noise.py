"""Sensor and actuation noise for external simulators, with the built-in ``sim`` node's config.

The same ``noise:`` syntax, presets, validation and models as the Rust simulator
(``sim-bridge/src/noise.rs``, the source of truth; the test
``python_noise_matches_the_rust_model`` pins the presets to it and checks the statistics):

- depth: per valid pixel, readings nearer than ``min_range`` or beyond ``max_range`` become 0;
  a pixel at a depth edge (a 4-neighbour of the clean depth differs by more than
  ``edge_threshold`` of the smaller depth, or reads 0) is dropped with ``edge_dropout``; any
  other with ``dropout``; the rest get a Gaussian error of sigma(z) = sigma_0 + sigma_z2 * z^2
  (a reading at or behind the camera becomes 0);
- colour: each channel plus round(sigma * n), clamped to 0..255;
- actuation: a forward move of d travels d + sqrt((forward_sigma_frac d)^2 + forward_sigma_m^2) n1
  (never negative) along the heading turned by half of a heading change
  heading_sigma_deg * n2 that it also applies; a turn of a turns a + turn_sigma_deg * n3
  (never negative).

Draws come from Python's ``random.Random`` seeded by the node's ``seed`` (one stream for the
sensor, one for the actuation), so an episode is reproducible; the draws are not those of the
Rust simulator (another generator), only their distribution is.

    noise: none | realistic
    noise: { preset: realistic, depth: { sigma_z2: 0.003 }, actuation: none }
"""

import array
import math
import random
import sys

DEPTH_KEYS = ("sigma_0", "sigma_z2", "min_range", "max_range", "edge_threshold", "edge_dropout", "dropout")
RGB_KEYS = ("sigma",)
ACTUATION_KEYS = ("forward_sigma_frac", "forward_sigma_m", "heading_sigma_deg", "turn_sigma_deg")
SECTIONS = {"depth": DEPTH_KEYS, "rgb": RGB_KEYS, "actuation": ACTUATION_KEYS}

#: The presets, value for value those of ``NoisePreset`` in sim-bridge/src/noise.rs (whose
#: documentation derives them: RealSense D435 depth, assumed colour noise, LoCoBot motion).
PRESETS = {
    "none": {section: {key: 0.0 for key in keys} for section, keys in SECTIONS.items()},
    "realistic": {
        "depth": {
            "sigma_0": 0.001,
            "sigma_z2": 0.0036,
            "min_range": 0.28,
            "max_range": 10.0,
            "edge_threshold": 0.05,
            "edge_dropout": 0.5,
            "dropout": 0.01,
        },
        "rgb": {"sigma": 2.0},
        "actuation": {
            "forward_sigma_frac": 0.056,
            "forward_sigma_m": 0.0,
            "heading_sigma_deg": 0.09,
            "turn_sigma_deg": 0.66,
        },
    },
}

#: Streams of the node's seed: the sensor's and the actuation's draws are independent.
SENSOR_STREAM = 1
ACTUATION_STREAM = 2


class NoiseConfigError(ValueError):
    """A ``noise:`` value that is not a preset name or a valid map; the message names the field."""


def _preset(field, name):
    if not isinstance(name, str) or name not in PRESETS:
        raise NoiseConfigError(f"{field}: unknown preset {name!r}, expected one of {', '.join(PRESETS)}")
    return {section: dict(values) for section, values in PRESETS[name].items()}


def _number(field, value):
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise NoiseConfigError(f"{field}: expected a number, got {value!r}")
    return float(value)


def parse_noise(value):
    """The explicit configuration ({section: {key: float}}) of a ``noise:`` value: ``None``, a
    preset name, or a map of ``preset`` and sections, each a preset name or key overrides."""
    if value is None:
        return _preset("noise", "none")
    if isinstance(value, str):
        config = _preset("noise", value)
    elif isinstance(value, dict):
        config = _preset("noise.preset", value["preset"]) if "preset" in value else _preset("noise", "none")
        for key, section in value.items():
            if key == "preset":
                continue
            if key not in SECTIONS:
                raise NoiseConfigError(
                    f"noise: unknown key `{key}`, expected one of `preset`, `depth`, `rgb`, `actuation`")
            if isinstance(section, str):
                config[key] = _preset(f"noise.{key}", section)[key]
            elif isinstance(section, dict):
                for name, v in section.items():
                    if name not in SECTIONS[key]:
                        raise NoiseConfigError(
                            f"noise.{key}: unknown field `{name}`, expected one of {', '.join(SECTIONS[key])}")
                    config[key][name] = _number(f"noise.{key}.{name}", v)
            else:
                raise NoiseConfigError(f"noise.{key}: expected a map of values or a preset name, got {section!r}")
    else:
        raise NoiseConfigError(f"noise: expected a preset name ({', '.join(PRESETS)}) or a map, got {value!r}")
    validate(config)
    return config


def validate(config):
    """Raises :class:`NoiseConfigError` naming the first value out of its range."""
    for section, keys in SECTIONS.items():
        for key in keys:
            v = config[section][key]
            if not (math.isfinite(v) and v >= 0.0):
                raise NoiseConfigError(f"noise.{section}.{key}: {v} must be finite and >= 0")
    d = config["depth"]
    if d["max_range"] > 0.0 and d["max_range"] <= d["min_range"]:
        raise NoiseConfigError(f"noise.depth.max_range: {d['max_range']} must exceed min_range (or be 0: no maximum)")
    for key in ("edge_dropout", "dropout"):
        if d[key] > 1.0:
            raise NoiseConfigError(f"noise.depth.{key}: {d[key]} must be a probability in [0, 1]")
    if d["edge_dropout"] > 0.0 and d["edge_threshold"] <= 0.0:
        raise NoiseConfigError("noise.depth.edge_threshold: must be > 0 when edge_dropout is")


class SensorNoise:
    """Depth and colour noise of a configuration, drawn from the sensor stream of ``seed``."""

    def __init__(self, config, seed):
        self.depth = config["depth"]
        self.rgb_sigma = config["rgb"]["sigma"]
        self.rng = random.Random(f"{seed}/{SENSOR_STREAM}")

    def active(self):
        """Whether any reading or pixel changes."""
        keys = ("sigma_0", "sigma_z2", "min_range", "max_range", "edge_dropout", "dropout")
        return any(self.depth[k] > 0.0 for k in keys) or self.rgb_sigma > 0.0

    def apply(self, rgb, depth, width):
        """Noisy copies of ``rgb`` (RGB8 bytes) and ``depth`` (float32 little-endian bytes, metres)
        of an image ``width`` pixels wide."""
        if not self.active():
            return rgb, depth
        rng = self.rng
        z_clean = array.array("f")
        z_clean.frombytes(depth)
        if sys.byteorder == "big":  # the wire is little-endian
            z_clean.byteswap()
        z_out = array.array("f", z_clean)
        d = self.depth
        height = len(z_clean) // width if width else 0
        max_range = d["max_range"] if d["max_range"] > 0.0 else math.inf
        edges = d["edge_dropout"] > 0.0
        noisy = d["sigma_0"] > 0.0 or d["sigma_z2"] > 0.0
        threshold = d["edge_threshold"]

        def differs(z, n):
            return n <= 0.0 or abs(z - n) > threshold * min(z, n)

        for y in range(height):
            for x in range(width):
                i = y * width + x
                z = z_clean[i]
                if z <= 0.0:
                    continue
                if z < d["min_range"] or z > max_range:
                    z_out[i] = 0.0
                    continue
                if edges:
                    edge = ((x > 0 and differs(z, z_clean[i - 1]))
                            or (x + 1 < width and differs(z, z_clean[i + 1]))
                            or (y > 0 and differs(z, z_clean[i - width]))
                            or (y + 1 < height and differs(z, z_clean[i + width])))
                    if edge and rng.random() < d["edge_dropout"]:
                        z_out[i] = 0.0
                        continue
                if d["dropout"] > 0.0 and rng.random() < d["dropout"]:
                    z_out[i] = 0.0
                    continue
                if noisy:
                    v = z + (d["sigma_0"] + d["sigma_z2"] * z * z) * rng.gauss(0.0, 1.0)
                    z_out[i] = v if v > 0.0 else 0.0
        if self.rgb_sigma > 0.0:
            s = self.rgb_sigma
            rgb = bytes(min(255, max(0, c + round(s * rng.gauss(0.0, 1.0)))) for c in rgb)
        if sys.byteorder == "big":
            z_out.byteswap()
        return rgb, z_out.tobytes()


class ActuationNoise:
    """Actuation noise of a configuration, drawn from the actuation stream of ``seed``."""

    def __init__(self, config, seed):
        self.a = config["actuation"]
        self.rng = random.Random(f"{seed}/{ACTUATION_STREAM}")

    def active(self):
        """Whether any action is perturbed."""
        return any(v > 0.0 for v in self.a.values())

    def forward(self, step):
        """(distance travelled, heading change in radians) of a forward move of ``step`` metres."""
        if not self.active():
            return step, 0.0
        n1, n2 = self.rng.gauss(0.0, 1.0), self.rng.gauss(0.0, 1.0)
        sigma = math.hypot(self.a["forward_sigma_frac"] * step, self.a["forward_sigma_m"])
        return max(0.0, step + sigma * n1), math.radians(self.a["heading_sigma_deg"]) * n2

    def turn(self, angle):
        """The angle turned (radians) by a turn of ``angle`` radians."""
        if not self.active():
            return angle
        return max(0.0, angle + math.radians(self.a["turn_sigma_deg"]) * self.rng.gauss(0.0, 1.0))
