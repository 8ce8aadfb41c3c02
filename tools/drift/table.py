#!/usr/bin/env python3
"""One row per run: ATE (summary.json, aligned), raw error RMS / final / max, aligned final,
yaw error final / max, z error final / max, tilt max, refine start, lost frames, relocalisations,
raw error at the refine start and its growth per metre before and after it.
usage: table.py RUN_DIR [...]"""
import sys, os, json
import numpy as np
sys.path.insert(0, os.path.dirname(__file__))
from drift import analyse, refine_step
print("| run | ATE cm (aligned) | raw RMS / final / max cm | yaw err final / max deg | z err final / max cm | tilt max deg | refine from | raw err at refine start cm | m before / after | lost / reloc |")
print("|---|---|---|---|---|---|---|---|---|---|")
for run in sys.argv[1:]:
    s = json.load(open(os.path.join(run, 'summary.json')))
    d = analyse(run); r = refine_step(run) or len(d['err']) - 1
    path = np.cumsum(d['dstep'])
    name = run.replace('runs/', '').replace('/seed1', '').replace('/fisher_no_motion_check', '').replace('/fisher', '')
    print(f"| {name} | {100*s['ate_m']:.1f} | {100*np.sqrt(np.mean(d['err']**2)):.1f} / {100*d['err'][-1]:.1f} / {100*d['err'].max():.1f} | "
          f"{d['eyaw'][-1]:+.1f} / {np.abs(d['eyaw']).max():.1f} | {100*d['ez'][-1]:+.1f} / {100*np.abs(d['ez']).max():.1f} | {d['tilt'].max():.2f} | "
          f"{r} | {100*d['err'][r]:.1f} | {path[r]:.1f} / {path[-1]-path[r]:.1f} | {s['tracking']['lost_frames']} / {s['tracking']['relocalisations']} |")
