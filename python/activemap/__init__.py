"""activemap from Python: run episodes, read their run folders and the ``bench results`` table
into numpy and pandas, and call the CPU splat renderer and the Fisher information on numpy arrays.

Example::

    import activemap
    run = activemap.Run("runs/smoke/fbe/house-1/seed1")       # a run folder
    run.summary["coverage"], run.trajectory_est.shape          # dict, (N, 8) numpy
    gaussians = run.map()                                      # numpy arrays of the final map
    k = activemap.Intrinsics.from_hfov(160, 160, 90)
    colour, depth, opacity = activemap.render(gaussians, pose_4x4, k)

The Rust crates do the work (``activemap-eval``'s run-folder reader, ``activemap-splat``'s
renderer and Fisher pass, ``activemap-active``'s view information and EIG); episodes run the
``activemap`` CLI binary (``ACTIVEMAP_BIN``, ``PATH`` or the checkout's ``target/``).
"""

from ._native import RunFolderError
from .runs import (
    BinaryNotFoundError,
    EpisodeError,
    Run,
    bench_results,
    find_binary,
    results,
    run,
)
from .splat import (
    PARAMETERS,
    SH_C0,
    Gaussians,
    Intrinsics,
    Render,
    ViewFisher,
    ViewInformation,
    eig,
    localisation_cost,
    render,
    view_fisher,
    view_information,
)

__all__ = [
    "BinaryNotFoundError",
    "EpisodeError",
    "Gaussians",
    "Intrinsics",
    "PARAMETERS",
    "Render",
    "Run",
    "RunFolderError",
    "SH_C0",
    "ViewFisher",
    "ViewInformation",
    "bench_results",
    "eig",
    "find_binary",
    "localisation_cost",
    "render",
    "results",
    "run",
    "view_fisher",
    "view_information",
]

__version__ = "0.1.0"
