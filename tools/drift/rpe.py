#!/usr/bin/env python3
"""Per-step relative motion error (what accumulates into drift), split by step kind.
usage: rpe.py RUN_DIR [RUN_DIR...]
For each step k-1 -> k: true and estimated relative motion in the previous camera's frame
(camera: x right, y down, z forward). Kinds: forward (true move > 2 cm), turn (|true dyaw| > 2 deg, no move), still.
Reports: forward-step ratio est/true along the heading, lateral error, yaw error per step, spurious
translation during turns, vertical (camera y) error, and their sums (the drift budget)."""
import sys, os, re
import numpy as np
sys.path.insert(0, os.path.dirname(__file__))
from drift import load, events, wrap

def rel(p, R):
    dp = np.einsum('nji,nj->ni', R[:-1], p[1:] - p[:-1])  # R_{k-1}^T (p_k - p_{k-1})
    dR = np.einsum('nji,njk->nik', R[:-1], R[1:])
    # yaw about camera y axis (vertical): rotation of forward axis in x-z plane
    f = dR[:, :, 2]
    dyaw = np.degrees(np.arctan2(f[:, 0], f[:, 2]))
    return dp, dyaw

def main(run, quiet=False):
    te, pe, Re = load(os.path.join(run, 'trajectory_est.tum'))
    tt, pt, Rt = load(os.path.join(run, 'trajectory_true.tum'))
    n = min(len(te), len(tt))
    dpe, dye = rel(pe[:n], Re[:n]); dpt, dyt = rel(pt[:n], Rt[:n])
    ev = events(run)
    lost = np.zeros(n, bool)
    # lost runs from log: "tracking lost" at frame a ... "regained" at frame b => a..b-1 lost
    start = None
    for f in sorted(ev):
        for m in ev[f]:
            if m.startswith('tracking lost'): start = f
            elif m.startswith('tracking regained') and start is not None:
                lost[start:f] = True; start = None
    if start is not None: lost[start:] = True
    lostk = lost[1:] | lost[:-1]
    mv = np.linalg.norm(dpt, axis=1)
    fwd = mv > 0.02; turn = (~fwd) & (np.abs(dyt) > 2); still = ~fwd & ~turn
    e = dpe - dpt
    print(f"== {run}")
    print(f"steps: forward {fwd.sum()}, turn {turn.sum()}, still {still.sum()}; steps touching lost frames {lostk.sum()}")
    for name, m in [('forward', fwd), ('turn', turn), ('still', still)]:
        for tag, mm in [('tracked', m & ~lostk), ('lost', m & lostk)]:
            if mm.sum() == 0: continue
            print(f" {name:7s} {tag:7s} n={mm.sum():4d}: sum err x(right) {100*e[mm,0].sum():7.1f} cm, y(down) {100*e[mm,1].sum():6.1f}, z(fwd) {100*e[mm,2].sum():7.1f} cm;"
                  f" mean |err| {1000*np.linalg.norm(e[mm],axis=1).mean():5.1f} mm; yaw err sum {(dye-dyt)[mm].sum():6.2f} deg, mean {(dye-dyt)[mm].mean():+.3f}, rms {np.sqrt(((dye-dyt)[mm]**2).mean()):.3f}")
    mm = fwd & ~lostk
    ratio = dpe[mm, 2] / dpt[mm, 2]
    print(f" forward tracked: est/true along z median {np.median(ratio):.3f}, mean {ratio.mean():.3f}; true mean {100*dpt[mm,2].mean():.2f} cm, est mean {100*dpe[mm,2].mean():.2f} cm")
    mm = turn & ~lostk
    print(f" turn tracked: est/true yaw mean {np.mean(dye[mm]/dyt[mm]):.4f}; spurious translation mean {1000*np.linalg.norm(dpe[mm],axis=1).mean():.1f} mm/step, mean vector (x,y,z) mm {np.round(1000*dpe[mm].mean(0),2)}")
    return dict(dpe=dpe, dpt=dpt, dye=dye, dyt=dyt, fwd=fwd, turn=turn, lostk=lostk)

if __name__ == '__main__':
    for r in sys.argv[1:]: main(r)
