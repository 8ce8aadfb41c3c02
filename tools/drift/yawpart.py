#!/usr/bin/env python3
"""How much of the raw error at step k a pure yaw error explains: the estimate's heading error
eyaw_k applied as a rotation of the whole path about the start, e_yaw = (Rz(eyaw_k) - I)(p_true_k - p_true_0).
The remainder is a translation the yaw does not explain. usage: yawpart.py RUN_DIR [...]"""
import sys, os
import numpy as np
sys.path.insert(0, os.path.dirname(__file__))
from drift import analyse
for run in sys.argv[1:]:
    d = analyse(run); e = d['pe_w'] - d['pt']; pt = d['pt']
    print(f"== {run}")
    print("  step | |e| cm | yaw err deg | dist from start m | |e_yaw| cm | |e - e_yaw| cm")
    for k in list(range(100, len(e), 200)) + [len(e) - 1]:
        a = np.radians(d['eyaw'][k]); Rz = np.array([[np.cos(a), -np.sin(a), 0], [np.sin(a), np.cos(a), 0], [0, 0, 1]])
        ey = (Rz - np.eye(3)) @ (pt[k] - pt[0])
        print(f"  {k:5d} | {100*np.linalg.norm(e[k]):5.1f} | {d['eyaw'][k]:+5.2f} | {np.linalg.norm(pt[k,:2]-pt[0,:2]):5.2f} | {100*np.linalg.norm(ey):5.1f} | {100*np.linalg.norm(e[k]-ey):5.1f}")
    # over all steps
    E = []; 
    for k in range(len(e)):
        a = np.radians(d['eyaw'][k]); Rz = np.array([[np.cos(a), -np.sin(a), 0], [np.sin(a), np.cos(a), 0], [0, 0, 1]])
        E.append(e[k] - (Rz - np.eye(3)) @ (pt[k] - pt[0]))
    E = np.array(E)
    print(f"  RMS over all steps: |e| {100*np.sqrt(np.mean(np.sum(e**2,1))):.1f} cm, after removing the yaw part {100*np.sqrt(np.mean(np.sum(E**2,1))):.1f} cm")
