"""Episodes and their run folders, and the ``bench results`` table.

A run folder is read through the Rust reader every other tool uses
(``activemap_eval::run_folder::RunFolder``): files are parsed and checked there and arrive here as
numpy arrays or JSON documents. Episodes run the ``activemap`` CLI binary in a subprocess
(linking the whole runtime into the extension would make the wheel enormous); see
:func:`find_binary` for where it is looked for.
"""

from __future__ import annotations

import json
import os
import shutil
import subprocess
from functools import cached_property
from pathlib import Path
from typing import TYPE_CHECKING, Any, Mapping, Sequence

import numpy as np

from . import _native
from .splat import Gaussians

if TYPE_CHECKING:
    import pandas as pd

#: Environment variable naming the ``activemap`` binary to run.
BINARY_ENV = "ACTIVEMAP_BIN"


class BinaryNotFoundError(FileNotFoundError):
    """The ``activemap`` CLI binary could not be found (see :func:`find_binary`)."""


class EpisodeError(RuntimeError):
    """An episode (``activemap run``) or a suite (``activemap bench results``) failed; the
    message holds the command and the end of its error output."""


def _checkouts() -> list[Path]:
    """Checkouts of the repository this package may sit in or be run from."""
    found = []
    for start in (Path(__file__).resolve().parent, Path.cwd().resolve()):
        for d in (start, *start.parents):
            if (d / "Cargo.toml").is_file() and (d / "crates" / "cli").is_dir():
                if d not in found:
                    found.append(d)
                break
    return found


def find_binary() -> Path:
    """The ``activemap`` binary: ``$ACTIVEMAP_BIN``, else ``activemap`` on ``PATH``, else the
    checkout's ``target/release/activemap`` then ``target/debug/activemap`` (the checkout this
    package was installed from in editable mode, or one the working directory lies in).

    Raises :class:`BinaryNotFoundError` naming what was looked for and how to build it.
    """
    env = os.environ.get(BINARY_ENV)
    if env:
        path = Path(env)
        if path.is_file() and os.access(path, os.X_OK):
            return path
        raise BinaryNotFoundError(f"{BINARY_ENV}={env} is not an executable file")
    on_path = shutil.which("activemap")
    if on_path:
        return Path(on_path)
    looked = []
    for checkout in _checkouts():
        for profile in ("release", "debug"):
            candidate = checkout / "target" / profile / "activemap"
            looked.append(str(candidate))
            if candidate.is_file() and os.access(candidate, os.X_OK):
                return candidate
    raise BinaryNotFoundError(
        "the activemap CLI binary was not found: set "
        f"{BINARY_ENV}=/path/to/activemap, put `activemap` on PATH, or build it in the checkout "
        "with `cargo build --release` (target/release/activemap)"
        + (f"; looked in {', '.join(looked)}" if looked else "")
    )


def _yaml_value(value: Any) -> str:
    """A Python value as the YAML text ``--set`` reads (JSON is YAML)."""
    if isinstance(value, str):
        return value
    if isinstance(value, (bool, int, float, list, tuple, dict)) or value is None:
        return json.dumps(value)
    if isinstance(value, Path):
        return str(value)
    raise TypeError(f"cannot pass {type(value).__name__} {value!r} as a --set value")


def _run_cli(args: list[str], cwd: str | os.PathLike[str] | None, timeout: float | None) -> None:
    binary = find_binary()
    cmd = [str(binary), *args]
    proc = subprocess.run(cmd, cwd=cwd, capture_output=True, text=True, timeout=timeout)
    if proc.returncode != 0:
        tail = "\n".join((proc.stderr or proc.stdout).strip().splitlines()[-20:])
        raise EpisodeError(f"`{' '.join(cmd)}` exited with {proc.returncode}:\n{tail}")


def run(
    flow: str | os.PathLike[str],
    out: str | os.PathLike[str],
    sets: Mapping[str, Any] | None = None,
    max_steps: int | None = None,
    *,
    record: bool = False,
    evaluate: bool = True,
    eval_views: int | None = None,
    cwd: str | os.PathLike[str] | None = None,
    timeout: float | None = None,
) -> "Run":
    """Run one episode of the dataflow ``flow`` into the run folder ``out`` and return it.

    ``sets`` maps ``NODE.KEY`` to a value, passed as ``--set NODE.KEY=VALUE`` (e.g.
    ``{"sim.width": 64, "sim.noise": "realistic"}``); ``max_steps`` is the step budget. Without
    ``record`` no ``recording.mcap`` is written; with ``evaluate`` the run is evaluated when it
    ends (``metrics.json``, ``eval_views`` test views). Raises :class:`EpisodeError` when the
    episode fails and :class:`BinaryNotFoundError` without a binary.
    """
    args = ["run", os.fspath(flow), "--out", os.fspath(out)]
    if max_steps is not None:
        args += ["--max-steps", str(int(max_steps))]
    for key, value in (sets or {}).items():
        args += ["--set", f"{key}={_yaml_value(value)}"]
    if not record:
        args.append("--no-record")
    if not evaluate:
        args.append("--no-eval")
    if eval_views is not None:
        args += ["--eval-views", str(int(eval_views))]
    _run_cli(args, cwd, timeout)
    return Run(Path(out) if Path(out).is_absolute() or cwd is None else Path(cwd) / out)


def bench_results(
    suite: str | os.PathLike[str] | None,
    out: str | os.PathLike[str],
    *,
    jobs: int | None = None,
    extra_args: Sequence[str] = (),
    cwd: str | os.PathLike[str] | None = None,
    timeout: float | None = None,
) -> "pd.DataFrame":
    """Run (or resume) the benchmark suite file ``suite`` with ``activemap bench results --suite
    SUITE --out OUT`` and return :func:`results` of ``out``. Method names of the suite resolve
    against ``cwd`` (the repository root for ``benchmarks/*.yaml``). With ``suite=None`` the grid
    comes from ``extra_args`` (``["--method", "fbe", "--houses", "1", ...]``, see
    ``activemap bench results --help``)."""
    args = ["bench", "results", "--out", os.fspath(out)]
    if suite is not None:
        args += ["--suite", os.fspath(suite)]
    if jobs is not None:
        args += ["--jobs", str(int(jobs))]
    args += [str(a) for a in extra_args]
    _run_cli(args, cwd, timeout)
    folder = Path(out) if Path(out).is_absolute() or cwd is None else Path(cwd) / out
    return results(folder)


def results(dir: str | os.PathLike[str], table: str = "results") -> "pd.DataFrame":
    """The table ``activemap bench results --out DIR`` wrote, as a pandas DataFrame.

    ``table="results"`` (``results.csv``): one row per method over all scenes (``scene`` =
    ``all``) then per method and scene; ``<metric>`` the mean over seeds, ``<metric>_std`` the
    spread, ``<metric>_n`` the seeds; percentages x100; ``complete``/``cells``/``invalid`` counts.
    ``table="paired"`` (``paired.csv``): every method against the baseline. Missing values are NaN.
    """
    import pandas as pd

    names = {"results": "results.csv", "paired": "paired.csv"}
    if table not in names:
        raise ValueError(f"table must be 'results' or 'paired', got {table!r}")
    path = Path(dir) / names[table]
    if not path.is_file():
        raise FileNotFoundError(
            f"{path}: missing (written by `activemap bench results --out {dir}`)"
        )
    return pd.read_csv(path, keep_default_na=False, na_values=[""])


class Run:
    """A run folder (what one ``activemap run`` writes), read through the Rust reader.

    Properties are read on first use and kept. Missing optional files give ``None``; a missing
    required file raises ``FileNotFoundError`` and a malformed one ``RunFolderError``, both
    naming the file.
    """

    def __init__(self, path: str | os.PathLike[str]) -> None:
        self.path = Path(path)
        if not self.path.is_dir():
            raise FileNotFoundError(f"{self.path}: not a run folder (no such directory)")

    def __repr__(self) -> str:
        return f"Run({str(self.path)!r})"

    @cached_property
    def summary(self) -> dict[str, Any]:
        """``summary.json``: what the evaluator node measured (steps, coverage, ATE, path length,
        the scene, ``valid`` and its ``warnings``...)."""
        return json.loads(_native.read_summary(self.path))

    @cached_property
    def metrics(self) -> dict[str, Any] | None:
        """``metrics.json`` of ``activemap eval`` (PSNR, SSIM, LPIPS, depth MAE, ATE,
        completeness, coverage...), ``None`` when the run was not evaluated. ``"inf"`` strings
        are read as ``float('inf')``."""
        text = _native.read_metrics(self.path)
        if text is None:
            return None
        return json.loads(text, parse_constant=float, object_hook=_extended_floats)

    @cached_property
    def trajectory_est(self) -> np.ndarray:
        """The estimated trajectory, (N, 8) float64 ``t tx ty tz qx qy qz qw`` (map frame)."""
        return _native.read_trajectory(self.path, "trajectory_est.tum")

    @cached_property
    def trajectory_true(self) -> np.ndarray:
        """The true trajectory, (N, 8) float64 ``t tx ty tz qx qy qz qw`` (world frame)."""
        return _native.read_trajectory(self.path, "trajectory_true.tum")

    def trajectory_final(self) -> np.ndarray | None:
        """With the tracker's pose graph: the estimates as the graph finally placed them,
        ``None`` without it."""
        if not (self.path / "trajectory_final.tum").is_file():
            return None
        return _native.read_trajectory(self.path, "trajectory_final.tum")

    def map(self) -> Gaussians:
        """The final map (``map.ply``) as float32 :class:`Gaussians`: ``means``, ``sh_dc``,
        ``rotations``, ``opacity_logits``, ``log_scales`` (and ``colours``, ``opacities``,
        ``scales``, ``covariances()`` derived)."""
        d = _native.read_map(self.path)
        return Gaussians(**d)

    def coverage(self) -> "pd.DataFrame | None":
        """``coverage.csv`` as a DataFrame (``step``, ``coverage`` in [0, 1]); ``None`` when
        absent."""
        return _frame(_native.read_coverage(self.path))

    def fisher(self) -> "pd.DataFrame | None":
        """``fisher.csv`` as a DataFrame, one row per Fisher replan (``step``, ``refine``,
        ``candidates``, ``paths``, ``chosen``, ``objective``, ``eig_sum``, ``eig_first``,
        ``c_local_sum``, ``actions``, ``total_ms``, ``model_reused``, ``fallback``; NaN where
        empty); ``None`` when the run made no Fisher replan."""
        return _frame(_native.read_fisher(self.path))

    def timings(self) -> "pd.DataFrame | None":
        """``timings.csv`` as a DataFrame (``stage``, ``seconds``, ``calls``), ``None`` when
        absent."""
        return _frame(_native.read_timings(self.path))

    def views(self) -> "pd.DataFrame | None":
        """``eval/views.csv`` (per test view PSNR, SSIM, LPIPS, depth MAE) as a DataFrame,
        ``None`` before ``activemap eval``."""
        return _frame(_native.read_views(self.path))

    def test_poses(self) -> "pd.DataFrame | None":
        """``eval/test_poses.csv`` (where each test view was taken: ``view``, world ``x_m``,
        ``y_m`` and heading ``yaw_deg``, row for row with :meth:`views`) as a DataFrame,
        ``None`` before ``activemap eval`` or for runs evaluated before the file existed."""
        return _frame(_native.read_test_poses(self.path))

    def llm_exchanges(self) -> list[dict[str, Any]]:
        """The LLM planner's exchanges (``llm.jsonl``), one dict per query (prompt, reply,
        decision, tokens, latency...); empty when the run made none."""
        text = _native.read_llm(self.path)
        return [] if text is None else json.loads(text)

    def checkpoints(self) -> list[tuple[int, "Run"]]:
        """The run's checkpoints ``(step, Run)``, ascending by step."""
        return [(step, Run(p)) for step, p in _native.checkpoints(self.path)]


def _frame(columns: Mapping[str, Any] | None) -> "pd.DataFrame | None":
    if columns is None:
        return None
    import pandas as pd

    return pd.DataFrame(dict(columns))


def _extended_floats(obj: dict[str, Any]) -> dict[str, Any]:
    for k, v in obj.items():
        if isinstance(v, str) and v in ("inf", "-inf", "nan", "+inf"):
            obj[k] = float(v)
    return obj

