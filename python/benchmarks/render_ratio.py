"""Python against Rust: `activemap.render` of 100k Gaussians at 800x800 (the renderer
benchmark's scene and camera, `activemap bench splat`) timed from Python, and the Rust
`activemap_splat::render` call alone timed inside Rust on the same Gaussians, interleaved in the
same process. Prints the medians and their ratio (goal: Python/Rust <= 1.1).

    python python/benchmarks/render_ratio.py [--gaussians 100000] [--size 800] [--repeats 7]
"""

from __future__ import annotations

import argparse
import statistics
import time

import numpy as np

import activemap
from activemap import _native


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--gaussians", type=int, default=100_000)
    parser.add_argument("--size", type=int, default=800)
    parser.add_argument("--repeats", type=int, default=7)
    args = parser.parse_args()

    g = activemap.Gaussians(**_native.bench_scene(args.gaussians))
    k = activemap.Intrinsics.from_hfov(args.size, args.size, 90)
    pose = np.eye(4)
    activemap.render(g, pose, k)  # warm-up (thread pool, page faults)
    py_times, rust_times, py_cpu, rust_cpu = [], [], [], []

    def python_call() -> None:
        c, t = time.process_time(), time.perf_counter()
        out = activemap.render(g, pose, k)
        py_times.append(time.perf_counter() - t)
        py_cpu.append(time.process_time() - c)
        del out

    def rust_call() -> None:
        # CPU time of the whole native call (it also gathers the arrays, as the Python path
        # does); wall time of the render alone, measured inside Rust.
        c = time.process_time()
        rust_times.extend(_native.rust_render_seconds(
            g.means, g.sh_dc, g.rotations, g.opacity_logits, g.log_scales, pose, k.astuple(), 1
        ))
        rust_cpu.append(time.process_time() - c)

    # Interleaved, the order alternating, so load from elsewhere falls on both alike.
    for i in range(args.repeats):
        for call in (python_call, rust_call) if i % 2 == 0 else (rust_call, python_call):
            call()
    py, rust = statistics.median(py_times), statistics.median(rust_times)
    pairs = statistics.median(p / r for p, r in zip(py_times, rust_times))
    print(
        f"render {args.gaussians} Gaussians at {args.size}x{args.size}, {args.repeats} pairs: "
        f"Python median {py * 1e3:.1f} ms (min {min(py_times) * 1e3:.1f}), Rust median "
        f"{rust * 1e3:.1f} ms (min {min(rust_times) * 1e3:.1f}); ratio of medians {py / rust:.3f}, "
        f"of minima {min(py_times) / min(rust_times):.3f}, median of pair ratios {pairs:.3f}; "
        f"CPU time (all threads, less sensitive to other load) Python {statistics.median(py_cpu) * 1e3:.1f} ms, "
        f"native call {statistics.median(rust_cpu) * 1e3:.1f} ms, ratio "
        f"{statistics.median(py_cpu) / statistics.median(rust_cpu):.3f}"
    )

if __name__ == "__main__":
    main()
