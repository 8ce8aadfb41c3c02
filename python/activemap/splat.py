"""The CPU splat renderer and the Fisher information on numpy arrays.

Thin wrappers over ``activemap._native`` (the Rust crates ``activemap-splat`` and
``activemap-active``): arrays are checked and made C-contiguous here (no copy when they already
are), the work runs in Rust with the GIL released, and the results come back as numpy arrays that
own the Rust buffers (no copy).

Conventions (``activemap_splat::gaussians``): the 14 raw parameters per Gaussian are ``means``
(N, 3) in metres, ``sh_dc`` (N, 3) the 3DGS ``f_dc`` (colour ``0.5 + C0 * sh_dc``), ``rotations``
(N, 4) unnormalised quaternions ``[w, x, y, z]``, ``opacity_logits`` (N,) and ``log_scales``
(N, 3); Fisher diagonals are over those 14 in that order. Poses are ``T_world_camera`` as 4x4
matrices, the camera in the OpenCV optical frame (x right, y down, z forward), pixel centres at
integer coordinates.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Mapping, NamedTuple, Sequence, Union

import numpy as np

from . import _native

#: The SH degree-0 constant of the 3DGS colour convention, ``1 / (2 sqrt(pi))``.
SH_C0 = 0.28209479177387814

#: Names of the 14 parameters of a Fisher diagonal, in order.
PARAMETERS = (
    "mean_x", "mean_y", "mean_z",
    "sh_r", "sh_g", "sh_b",
    "rot_w", "rot_x", "rot_y", "rot_z",
    "opacity_logit",
    "log_scale_x", "log_scale_y", "log_scale_z",
)


@dataclass
class Gaussians:
    """A set of Gaussians as numpy arrays (structure of arrays, the renderer's raw parameters).

    All float arrays share one dtype, float32 (as ``map.ply`` stores them and the system renders)
    or float64 (for derivative checks); ``flags`` is uint8 (bit 1: unknown space).
    """

    means: np.ndarray
    sh_dc: np.ndarray
    rotations: np.ndarray
    opacity_logits: np.ndarray
    log_scales: np.ndarray
    flags: np.ndarray | None = None

    def __len__(self) -> int:
        return int(np.shape(self.means)[0])

    @classmethod
    def from_natural(
        cls,
        means: Any,
        colours: Any,
        rotations: Any,
        opacities: Any,
        scales: Any,
        dtype: Any = np.float32,
    ) -> "Gaussians":
        """Gaussians from natural units: RGB colours, opacities in (0, 1), scales in metres."""
        op = np.clip(np.asarray(opacities, dtype=np.float64), 1e-7, 1 - 1e-7)
        return cls(
            means=np.asarray(means, dtype=dtype),
            sh_dc=((np.asarray(colours, dtype=np.float64) - 0.5) / SH_C0).astype(dtype),
            rotations=np.asarray(rotations, dtype=dtype),
            opacity_logits=np.log(op / (1 - op)).astype(dtype),
            log_scales=np.log(np.asarray(scales, dtype=np.float64)).astype(dtype),
        )

    @property
    def colours(self) -> np.ndarray:
        """Rendered RGB colour per Gaussian, ``0.5 + C0 * sh_dc`` (unclamped)."""
        return 0.5 + SH_C0 * self.sh_dc

    @property
    def opacities(self) -> np.ndarray:
        """Opacity per Gaussian, ``sigmoid(opacity_logits)``."""
        return 1.0 / (1.0 + np.exp(-self.opacity_logits))

    @property
    def scales(self) -> np.ndarray:
        """Per-axis standard deviations in metres, ``exp(log_scales)``."""
        return np.exp(self.log_scales)

    @property
    def unit_rotations(self) -> np.ndarray:
        """The quaternions ``[w, x, y, z]`` normalised."""
        r = np.asarray(self.rotations, dtype=np.float64)
        return r / np.linalg.norm(r, axis=1, keepdims=True)

    def covariances(self) -> np.ndarray:
        """World-frame covariances ``R diag(s^2) R^T``, (N, 3, 3) float64."""
        w, x, y, z = self.unit_rotations.T
        r = np.stack(
            [
                np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)], -1),
                np.stack([2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)], -1),
                np.stack([2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)], -1),
            ],
            axis=1,
        )
        s2 = np.exp(2 * np.asarray(self.log_scales, dtype=np.float64))
        return np.einsum("nij,nj,nkj->nik", r, s2, r)


GaussiansLike = Union[Gaussians, Mapping[str, Any]]


@dataclass(frozen=True)
class Intrinsics:
    """A pinhole camera: image size, focal lengths and principal point, in pixels."""

    width: int
    height: int
    fx: float
    fy: float
    cx: float
    cy: float

    @classmethod
    def from_hfov(cls, width: int, height: int, hfov_deg: float) -> "Intrinsics":
        """A centred pinhole with square pixels and the horizontal field of view in degrees
        (``activemap_geometry::Intrinsics::from_hfov``)."""
        fx = 0.5 * width / np.tan(0.5 * np.radians(hfov_deg))
        return cls(width, height, fx, fx, 0.5 * width - 0.5, 0.5 * height - 0.5)

    def astuple(self) -> tuple[int, int, float, float, float, float]:
        """``(width, height, fx, fy, cx, cy)``."""
        return (int(self.width), int(self.height), float(self.fx), float(self.fy),
                float(self.cx), float(self.cy))


IntrinsicsLike = Union[Intrinsics, Sequence[float], Mapping[str, float]]


class Render(NamedTuple):
    """The three images of a render: colour (H, W, 3), depth (H, W, un-normalised ``sum z a T``
    as MonoGS) and accumulated opacity (H, W)."""

    colour: np.ndarray
    depth: np.ndarray
    opacity: np.ndarray


class ViewFisher(NamedTuple):
    """The Fisher information of one rendered view (``activemap_splat::fisher``), summed over
    pixels, not normalised: per-Gaussian diagonals (N, 14) of the colour outputs and of the depth
    output, and the 6x6 pose information ``J^T J`` of each for the left update
    ``T_cw <- Exp(tau) T_cw``, ``tau = [rho, theta]``."""

    colour: np.ndarray
    depth: np.ndarray
    pose_colour: np.ndarray
    pose_depth: np.ndarray

    def diagonal(self, depth_weight: float = 1.0) -> np.ndarray:
        """Colour plus ``depth_weight`` x depth diagonal, (N, 14) float64."""
        return self.colour.astype(np.float64) + depth_weight * self.depth.astype(np.float64)

    def pose(self, depth_weight: float = 1.0) -> np.ndarray:
        """Colour plus ``depth_weight`` x depth pose information, (6, 6)."""
        return self.pose_colour + depth_weight * self.pose_depth


class ViewInformation(NamedTuple):
    """The scorer's information of one view (``activemap_active::information``): the diagonal
    ``H(x)`` (N, 14) and the 6x6 pose information, both normalised per pixel, colour plus
    ``depth_weight`` x depth, and the count of pixels with opacity under 0.5."""

    diagonal: np.ndarray
    pose: np.ndarray
    low_opacity_pixels: int


def _field(g: GaussiansLike, name: str) -> Any:
    if isinstance(g, Gaussians):
        return getattr(g, name)
    try:
        return g[name]
    except (KeyError, TypeError):
        if name == "flags":
            return None
        raise TypeError(
            f"gaussians must be an activemap.Gaussians or a mapping with '{name}' "
            f"(means, sh_dc, rotations, opacity_logits, log_scales[, flags])"
        ) from None


def _arrays(g: GaussiansLike) -> tuple[np.ndarray, ...]:
    """The raw parameter arrays, C-contiguous, of one float dtype; shapes checked."""
    means = np.asarray(_field(g, "means"))
    if means.dtype == np.float64:
        dtype: Any = np.float64
    elif means.dtype.kind in "fiu":
        dtype = np.float32
    else:
        raise TypeError(f"means must hold real numbers, got dtype {means.dtype}")
    if means.ndim != 2 or means.shape[1] != 3:
        raise ValueError(f"means must have shape (N, 3), got {means.shape}")
    n = means.shape[0]
    out = [np.ascontiguousarray(means, dtype=dtype)]
    for name, cols in (("sh_dc", 3), ("rotations", 4), ("opacity_logits", 0), ("log_scales", 3)):
        a = np.asarray(_field(g, name))
        want = (n,) if cols == 0 else (n, cols)
        if a.shape != want:
            raise ValueError(f"{name} must have shape {want} (N = {n} from means), got {a.shape}")
        if a.dtype.kind not in "fiu":
            raise TypeError(f"{name} must hold real numbers, got dtype {a.dtype}")
        out.append(np.ascontiguousarray(a, dtype=dtype))
    flags = _field(g, "flags")
    if flags is not None:
        f = np.asarray(flags)
        if f.shape != (n,):
            raise ValueError(f"flags must have shape ({n},), got {f.shape}")
        out.append(np.ascontiguousarray(f, dtype=np.uint8))
    else:
        out.append(None)  # type: ignore[arg-type]
    return tuple(out)


def _pose(pose: Any) -> np.ndarray:
    p = np.asarray(pose, dtype=np.float64)
    if p.shape != (4, 4):
        raise ValueError(f"pose must be a 4x4 matrix T_world_camera, got shape {p.shape}")
    return np.ascontiguousarray(p)


def _intrinsics(k: IntrinsicsLike) -> tuple[int, int, float, float, float, float]:
    if isinstance(k, Intrinsics):
        return k.astuple()
    if isinstance(k, Mapping):
        try:
            return Intrinsics(
                int(k["width"]), int(k["height"]), float(k["fx"]), float(k["fy"]),
                float(k["cx"]), float(k["cy"]),
            ).astuple()
        except KeyError as e:
            raise ValueError(f"intrinsics mapping lacks {e}: needs width, height, fx, fy, cx, cy") from None
    values = tuple(k)
    if len(values) != 6:
        raise ValueError(
            f"intrinsics must be (width, height, fx, fy, cx, cy), got {len(values)} values"
        )
    return Intrinsics(*values).astuple()  # type: ignore[arg-type]


def _native_for(arrays: tuple[np.ndarray, ...], base: str) -> Any:
    return getattr(_native, f"{base}_{'f64' if arrays[0].dtype == np.float64 else 'f32'}")


def render(
    gaussians: GaussiansLike,
    pose: Any,
    intrinsics: IntrinsicsLike,
    *,
    exposure: tuple[float, float] = (0.0, 0.0),
    near: float = 0.01,
    far: float = float("inf"),
    exclude_flags: int = 0,
    depth_model: str = "plane",
) -> Render:
    """Render colour, depth and opacity of ``gaussians`` seen from ``pose`` (``T_world_camera``,
    4x4) with ``intrinsics`` (``activemap_splat::render``, SPEC 3).

    The images have the dtype of ``means`` (float32 unless it is float64). ``exposure`` ``(a, b)``
    gives colour ``e^a C + b``; Gaussians with ``flags & exclude_flags`` are left out.
    ``depth_model``: ``"plane"`` (the maps' default: each Gaussian contributes the depth of its
    densest point along the pixel's ray) or ``"centre"`` (SPEC 3: its centre's depth; the model
    ``view_fisher`` differentiates).
    Raises ``ValueError`` for bad shapes, a pose that is not rigid or an unusable camera.
    """
    arrays = _arrays(gaussians)
    colour, depth, opacity = _native_for(arrays, "render")(
        *arrays, _pose(pose), _intrinsics(intrinsics), (float(exposure[0]), float(exposure[1])),
        float(near), float(far), int(exclude_flags), str(depth_model),
    )
    return Render(colour, depth, opacity)


def view_fisher(
    gaussians: GaussiansLike,
    pose: Any,
    intrinsics: IntrinsicsLike,
    *,
    mode: str = "per_channel",
    exposure: tuple[float, float] = (0.0, 0.0),
    near: float = 0.01,
    far: float = float("inf"),
    exclude_flags: int = 0,
) -> ViewFisher:
    """The Fisher information of the view (``activemap_splat::fisher``): per Gaussian the
    diagonals ``sum_px (df/dw)^2`` over the 14 raw parameters of the colour outputs (``mode``
    ``"per_channel"``: every channel an observation; ``"channel_sum"``: FisherRF's square of the
    channel sum) and of the depth, and the 6x6 pose information of each, of a render with the
    centre depth model (``render(..., depth_model="centre")``).
    """
    arrays = _arrays(gaussians)
    d = _native_for(arrays, "fisher")(
        *arrays, _pose(pose), _intrinsics(intrinsics), str(mode),
        (float(exposure[0]), float(exposure[1])), float(near), float(far), int(exclude_flags),
    )
    return ViewFisher(d["colour"], d["depth"], d["pose_colour"], d["pose_depth"])


def view_information(
    gaussians: GaussiansLike,
    pose: Any,
    intrinsics: IntrinsicsLike,
    *,
    depth_weight: float | None = None,
    far: float | None = None,
) -> ViewInformation:
    """The information of one view as the Fisher scorer computes it (SPEC 5,
    ``activemap_active::information::view_information``): culled to what the view can see,
    ``(1/P)`` x (colour per channel + ``depth_weight`` x depth), every Gaussian counted.
    ``depth_weight`` and ``far`` default to the scorer's (``FisherConfig``).
    """
    arrays = _arrays(gaussians)
    d = _native_for(arrays, "view_information")(
        *arrays, _pose(pose), _intrinsics(intrinsics),
        None if depth_weight is None else float(depth_weight),
        None if far is None else float(far),
    )
    return ViewInformation(d["diagonal"], d["pose"], int(d["low_opacity_pixels"]))


def _diag(a: Any, what: str) -> np.ndarray:
    a = np.asarray(a)
    if a.ndim != 2 or a.shape[1] != 14:
        raise ValueError(f"{what} must have shape (N, 14), got {a.shape}")
    return np.ascontiguousarray(a, dtype=np.float64)


def eig(diagonal: Any, prior: Any) -> float:
    """The view EIG ``sum_i sum_k H_ik / I_ik`` (SPEC 5, ``activemap_active::information::eig``)
    of a view's diagonal ``H`` (N, 14, e.g. ``view_information(...).diagonal``) against the prior
    ``I + lambda`` (N, 14, positive where ``H`` is non-zero). A ``ViewInformation`` or
    ``ViewFisher`` is accepted for ``diagonal``.
    """
    if isinstance(diagonal, ViewInformation):
        diagonal = diagonal.diagonal
    elif isinstance(diagonal, ViewFisher):
        diagonal = diagonal.diagonal()
    return float(_native.eig(_diag(diagonal, "diagonal"), _diag(prior, "prior")))


def localisation_cost(pose_information: Any, degenerate_ratio: float | None = None) -> float:
    """``C_local = -log det(J^T J)`` of a 6x6 pose information (SPEC 5,
    ``activemap_active::information::localisation_cost``): +inf when not positive definite or
    degenerate (smallest eigenvalue at most ``degenerate_ratio`` x the largest; default the
    scorer's)."""
    m = np.ascontiguousarray(np.asarray(pose_information, dtype=np.float64))
    return float(_native.localisation_cost(m, degenerate_ratio))
