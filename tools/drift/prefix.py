#!/usr/bin/env python3
"""ATE as the evaluator's checkpoints compute it (Umeyama SE(3) over the prefix 0..k, RMSE)
against the raw error (first-pose anchored) at step k and its RMS over 0..k.
usage: prefix.py RUN_DIR [...]"""
import sys, os
import numpy as np
sys.path.insert(0, os.path.dirname(__file__))
from drift import analyse, umeyama
for run in sys.argv[1:]:
    d = analyse(run); pe, pt = d['pe_w'], d['pt']
    print(f"== {run}")
    print("  step | prefix-aligned ATE cm | raw RMS 0..k cm | raw |e_k| cm | |e_k - e_200| cm")
    for k in [200, 400, 600, 800, 1000, 1200, 1400, 1600, 1800, 2000]:
        R, t = umeyama(pe[:k+1], pt[:k+1])
        ate = np.sqrt(np.mean(np.sum((pe[:k+1] @ R.T + t - pt[:k+1])**2, 1)))
        e = pe - pt
        print(f"  {k:5d} | {100*ate:6.1f} | {100*np.sqrt(np.mean(d['err'][:k+1]**2)):6.1f} | {100*d['err'][k]:6.1f} | {100*np.linalg.norm(e[k]-e[200]):6.1f}")
