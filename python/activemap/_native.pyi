"""Type stubs of the Rust extension ``activemap._native`` (python/src/). Use the wrappers of
``activemap`` (``activemap.splat``, ``activemap.runs``), which check shapes and dtypes first."""

from os import PathLike
from typing import Any

import numpy as np
import numpy.typing as npt

_Path = str | PathLike[str]
_F32 = npt.NDArray[np.float32]
_F64 = npt.NDArray[np.float64]
_U8 = npt.NDArray[np.uint8]
_Intrinsics = tuple[int, int, float, float, float, float]

class RunFolderError(ValueError):
    """A run folder's file is there but malformed (the message names the file and line)."""

def read_summary(dir: _Path) -> str: ...
def read_metrics(dir: _Path) -> str | None: ...
def read_trajectory(dir: _Path, name: str) -> _F64: ...
def read_map(dir: _Path) -> dict[str, Any]: ...
def read_coverage(dir: _Path) -> dict[str, Any] | None: ...
def read_fisher(dir: _Path) -> dict[str, Any] | None: ...
def read_timings(dir: _Path) -> dict[str, Any] | None: ...
def read_views(dir: _Path) -> dict[str, Any] | None: ...
def read_test_poses(dir: _Path) -> dict[str, Any] | None: ...
def read_llm(dir: _Path) -> str | None: ...
def checkpoints(dir: _Path) -> list[tuple[int, str]]: ...
def render_f32(
    means: _F32, sh_dc: _F32, rotations: _F32, opacity_logits: _F32, log_scales: _F32,
    flags: _U8 | None, world_from_camera: _F64, intrinsics: _Intrinsics,
    exposure: tuple[float, float] = ..., near: float = ..., far: float = ...,
    exclude_flags: int = ...,
) -> tuple[_F32, _F32, _F32]: ...
def render_f64(
    means: _F64, sh_dc: _F64, rotations: _F64, opacity_logits: _F64, log_scales: _F64,
    flags: _U8 | None, world_from_camera: _F64, intrinsics: _Intrinsics,
    exposure: tuple[float, float] = ..., near: float = ..., far: float = ...,
    exclude_flags: int = ...,
) -> tuple[_F64, _F64, _F64]: ...
def fisher_f32(
    means: _F32, sh_dc: _F32, rotations: _F32, opacity_logits: _F32, log_scales: _F32,
    flags: _U8 | None, world_from_camera: _F64, intrinsics: _Intrinsics, mode: str = ...,
    exposure: tuple[float, float] = ..., near: float = ..., far: float = ...,
    exclude_flags: int = ...,
) -> dict[str, Any]: ...
def fisher_f64(
    means: _F64, sh_dc: _F64, rotations: _F64, opacity_logits: _F64, log_scales: _F64,
    flags: _U8 | None, world_from_camera: _F64, intrinsics: _Intrinsics, mode: str = ...,
    exposure: tuple[float, float] = ..., near: float = ..., far: float = ...,
    exclude_flags: int = ...,
) -> dict[str, Any]: ...
def view_information_f32(
    means: _F32, sh_dc: _F32, rotations: _F32, opacity_logits: _F32, log_scales: _F32,
    flags: _U8 | None, world_from_camera: _F64, intrinsics: _Intrinsics,
    depth_weight: float | None = ..., far: float | None = ...,
) -> dict[str, Any]: ...
def view_information_f64(
    means: _F64, sh_dc: _F64, rotations: _F64, opacity_logits: _F64, log_scales: _F64,
    flags: _U8 | None, world_from_camera: _F64, intrinsics: _Intrinsics,
    depth_weight: float | None = ..., far: float | None = ...,
) -> dict[str, Any]: ...
def eig(diagonal: _F64, prior: _F64) -> float: ...
def localisation_cost(pose_information: _F64, degenerate_ratio: float | None = ...) -> float: ...
def bench_scene(n: int) -> dict[str, Any]: ...
def rust_render_seconds(
    means: _F32, sh_dc: _F32, rotations: _F32, opacity_logits: _F32, log_scales: _F32,
    world_from_camera: _F64, intrinsics: _Intrinsics, repeats: int,
) -> list[float]: ...
