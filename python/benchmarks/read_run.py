"""Time reading a whole run folder into numpy and pandas: summary, metrics, both trajectories,
the map, coverage, Fisher replans, timings and LLM exchanges (goal for a 2000-step run: < 1 s).

    python python/benchmarks/read_run.py RUN_FOLDER [--repeats 5]
"""

from __future__ import annotations

import argparse
import statistics
import time

import activemap


def read_all(path: str) -> dict:
    run = activemap.Run(path)
    return {
        "summary": run.summary,
        "metrics": run.metrics,
        "trajectory_est": run.trajectory_est,
        "trajectory_true": run.trajectory_true,
        "map": run.map(),
        "coverage": run.coverage(),
        "fisher": run.fisher(),
        "timings": run.timings(),
        "llm": run.llm_exchanges(),
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("run")
    parser.add_argument("--repeats", type=int, default=5)
    args = parser.parse_args()
    times = []
    for _ in range(args.repeats):
        t = time.perf_counter()
        d = read_all(args.run)
        times.append(time.perf_counter() - t)
    print(
        f"{args.run}: {d['summary']['steps']} steps, {len(d['map'])} Gaussians, "
        f"{len(d['coverage']) if d['coverage'] is not None else 0} coverage rows; "
        f"read in {statistics.median(times) * 1e3:.1f} ms (median of {args.repeats}, "
        f"first {times[0] * 1e3:.1f} ms)"
    )


if __name__ == "__main__":
    main()
