#!/usr/bin/env python3
"""Does the estimate get pinned at revisits? For each step k, the earliest earlier step j
(k - j >= GAP) whose TRUE pose is within DIST m and ANG deg of step k's. If old references pinned
the estimate, the error vector e_k = p_est_k - p_true_k would repeat e_j (error is a function of
place). Prints |e_k - e_j| against |e_k| and against |e_k - e_{k-GAP}|.
usage: revisit.py RUN_DIR [...]"""
import sys, os
import numpy as np
sys.path.insert(0, os.path.dirname(__file__))
from drift import analyse
GAP, DIST, ANG = 100, 0.15, 15.0
for run in sys.argv[1:]:
    d = analyse(run)
    e = d['pe_w'] - d['pt']; pt = d['pt']; yaw = np.degrees(d['yaw_t']); n = len(pt)
    rows = []
    for k in range(GAP, n):
        dist = np.linalg.norm(pt[:k-GAP+1, :2] - pt[k, :2], axis=1)
        da = np.abs((yaw[:k-GAP+1] - yaw[k] + 180) % 360 - 180)
        ok = np.where((dist < DIST) & (da < ANG))[0]
        if len(ok): rows.append((k, ok[0], np.linalg.norm(e[k]), np.linalg.norm(e[k] - e[ok[0]]), np.linalg.norm(e[k] - e[k-GAP])))
    r = np.array(rows)
    print(f"== {run}: {len(r)} of {n-GAP} steps revisit an earlier pose (>= {GAP} steps before, {DIST} m, {ANG} deg)")
    print(f"  median |e_k| {100*np.median(r[:,2]):.1f} cm; median |e_k - e_first_visit| {100*np.median(r[:,3]):.1f} cm; median |e_k - e_(k-{GAP})| {100*np.median(r[:,4]):.1f} cm")
    for lo, hi in [(0, 500), (500, 1000), (1000, 1500), (1500, 2001)]:
        m = (r[:,0] >= lo) & (r[:,0] < hi)
        if m.sum(): print(f"  steps {lo}-{hi}: n={m.sum():4d} median |e_k| {100*np.median(r[m,2]):5.1f}, |e_k-e_first| {100*np.median(r[m,3]):5.1f}, first visit at step median {np.median(r[m,1]):.0f}")
