"""Table 1 from Python, notebook style (plain Python, no Jupyter): run the smoke suite with
`activemap bench results`, load its table and each cell's run folder, and plot them.

    python python/examples/table1.py [--suite benchmarks/smoke.yaml] [--out runs/smoke] [--png table1.png]

Run from the repository root (the suite's method names resolve against it). A second run with the
same --out resumes: finished cells are not rerun. Needs the `activemap` binary (ACTIVEMAP_BIN,
PATH, or the checkout's target/) and matplotlib.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import matplotlib

matplotlib.use("Agg")  # files only, no display needed
import matplotlib.pyplot as plt  # noqa: E402

import activemap  # noqa: E402

# %% Settings
parser = argparse.ArgumentParser(description="Run a suite, load its table, plot it.")
parser.add_argument("--suite", default="benchmarks/smoke.yaml")
parser.add_argument("--out", default="runs/smoke")
parser.add_argument("--png", default="table1.png")
parser.add_argument("--jobs", type=int, default=None)
args = parser.parse_args()

# %% Run (or resume) the suite and load the table: one row per method over all scenes, then per
# method and scene; `<metric>` is the mean over seeds, `<metric>_std` the spread.
table = activemap.bench_results(args.suite, args.out, jobs=args.jobs)
overall = table[table["scene"] == "all"].set_index("method")
print(overall[["complete", "cells", "psnr_db", "depth_mae_m", "completeness_pct", "coverage_2d_pct"]])

# %% Each cell's run folder: coverage over the steps (runs/<suite>/<method>/<scene>/seed<n>/).
curves = {}
for summary in sorted(Path(args.out).glob("*/*/seed*/summary.json")):
    run = activemap.Run(summary.parent)
    cov = run.coverage()
    if cov is not None:
        method, scene, seed = summary.parent.parts[-3:]
        curves[f"{method} {scene} {seed}"] = cov

# %% Plot: the Table 1 metrics per method (mean ± spread over seeds) and the coverage curves.
metrics = [("psnr_db", "PSNR (dB) ↑"), ("depth_mae_m", "depth MAE (m) ↓"),
           ("completeness_pct", "completeness (%) ↑"), ("coverage_2d_pct", "2D coverage (%) ↑")]
fig, axes = plt.subplots(1, len(metrics) + 1, figsize=(4 * (len(metrics) + 1), 3.6))
for ax, (key, label) in zip(axes, metrics):
    std = overall.get(f"{key}_std")
    ax.bar(overall.index, overall[key], yerr=None if std is None else std.fillna(0), capsize=4,
           color=["tab:blue", "tab:orange", "tab:green", "tab:red"][: len(overall)])
    ax.set_title(label)
for name, cov in curves.items():
    axes[-1].plot(cov["step"], 100 * cov["coverage"], label=name)
axes[-1].set_title("2D coverage over steps (%)")
axes[-1].set_xlabel("step")
axes[-1].legend(fontsize=7)
fig.suptitle(f"{args.suite}: {', '.join(overall.index)}")
fig.tight_layout()
fig.savefig(args.png, dpi=120)
print(f"wrote {args.png}")
