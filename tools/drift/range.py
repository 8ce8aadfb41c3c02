#!/usr/bin/env python3
"""Per forward step: the along-heading error (est - true, mm) against the distance to the room's
wall straight ahead (ray from the true camera along its heading to the box of the room, taken as
the true trajectory's extent padded by 0.3 m: a proxy, the room is not read from the scene).
usage: range.py RUN_DIR [...]"""
import sys, os, io, contextlib
import numpy as np
sys.path.insert(0, os.path.dirname(__file__))
from rpe import main
from drift import load
for run in sys.argv[1:]:
    with contextlib.redirect_stdout(io.StringIO()): r = main(run)
    _, pt, Rt = load(os.path.join(run, 'trajectory_true.tum'))
    lo = pt[:, :2].min(0) - 0.3; hi = pt[:, :2].max(0) + 0.3
    f = Rt[:-1, :2, 2]; p = pt[:-1, :2]
    with np.errstate(divide='ignore', invalid='ignore'):
        tx = np.where(f[:, 0] > 0, (hi[0] - p[:, 0]) / f[:, 0], (lo[0] - p[:, 0]) / f[:, 0])
        ty = np.where(f[:, 1] > 0, (hi[1] - p[:, 1]) / f[:, 1], (lo[1] - p[:, 1]) / f[:, 1])
    dist = np.minimum(np.abs(tx), np.abs(ty))
    m = r['fwd'] & ~r['lostk']
    dz = 1000 * (r['dpe'][:, 2] - r['dpt'][:, 2])
    print(f"== {run} (room box {lo.round(1)}..{hi.round(1)})")
    for a, b in [(0, 2), (2, 4), (4, 6), (6, 8), (8, 20)]:
        mm = m & (dist >= a) & (dist < b)
        if mm.sum() >= 5:
            print(f"  wall ahead {a}-{b} m: n={mm.sum():4d}  along-heading error mean {dz[mm].mean():+6.2f} mm, median {np.median(dz[mm]):+6.2f} mm (of {1000*r['dpt'][mm,2].mean():.1f}), rms {np.sqrt((dz[mm]**2).mean()):5.2f}")
