#!/usr/bin/env python3
"""For steps k in [A, B]: the earlier steps j < k - GAP whose true pose lies within 0.75 m and 30 deg
of step k's (what the tracker's older-reference rule would select if the estimate were right), and
the error vector e_j they carried, against e_k. If e_k converges to e_j, the drift in [A, B] is the
estimate being pulled onto older references of the place. usage: pull.py RUN_DIR A B [STEP]"""
import sys, os
import numpy as np
sys.path.insert(0, os.path.dirname(__file__))
from drift import analyse
run, A, B = sys.argv[1], int(sys.argv[2]), int(sys.argv[3]); S = int(sys.argv[4]) if len(sys.argv) > 4 else 3
GAP = 30
d = analyse(run); e = d['pe_w'] - d['pt']; pt = d['pt']; yaw = np.degrees(d['yaw_t'])
for k in range(A, B + 1, S):
    dist = np.linalg.norm(pt[:k-GAP, :2] - pt[k, :2], axis=1)
    da = np.abs((yaw[:k-GAP] - yaw[k] + 180) % 360 - 180)
    ok = np.where((dist < 0.75) & (da < 30))[0]
    if len(ok):
        ej = e[ok][:, :2]
        print(f" {k}: e_k = ({100*e[k,0]:+.1f}, {100*e[k,1]:+.1f}) cm; {len(ok)} earlier steps of the place (steps {ok.min()}-{ok.max()}), their e: mean ({100*ej[:,0].mean():+.1f}, {100*ej[:,1].mean():+.1f}), spread {100*ej.std(0).round(3)}")
    else:
        print(f" {k}: e_k = ({100*e[k,0]:+.1f}, {100*e[k,1]:+.1f}) cm; no earlier step of the place")
