#!/usr/bin/env python3
"""Decompose the world-frame error e_k = p_est_k - p_true_k (raw, first-pose anchored) into
contributions summed over steps:  e_k - e_(k-1) = (R_est - R_true)_(k-1) dp_true  [attitude-induced]
                                              + R_est_(k-1) (dp_est - dp_true)  [local translation error]
local error split into camera z (along heading), x (lateral), y (vertical), and by step kind
(forward / turn in place). Also: the fastest-growing 25-step windows of |e| with the robot's
motion there and tracker log lines nearby.
usage: decompose.py RUN_DIR [--windows N]"""
import sys, os
import numpy as np
sys.path.insert(0, os.path.dirname(__file__))
from drift import load, events, analyse

run = sys.argv[1]
nw = int(sys.argv[sys.argv.index('--windows') + 1]) if '--windows' in sys.argv else 8
te, pe, Re = load(os.path.join(run, 'trajectory_est.tum'))
tt, pt, Rt = load(os.path.join(run, 'trajectory_true.tum'))
n = min(len(te), len(tt)); pe, Re, pt, Rt = pe[:n], Re[:n], pt[:n], Rt[:n]
A = Rt[0] @ Re[0].T; pe = pe @ A.T + (pt[0] - A @ pe[0]); Re = np.einsum('ij,njk->nik', A, Re)
e = pe - pt
dpt = np.einsum('nji,nj->ni', Rt[:-1], pt[1:] - pt[:-1])
dpe = np.einsum('nji,nj->ni', Re[:-1], pe[1:] - pe[:-1])
att = np.einsum('nij,nj->ni', Re[:-1] - Rt[:-1], dpt)
loc = np.einsum('nij,nj->ni', Re[:-1], dpe - dpt)
assert np.allclose(np.cumsum(att + loc, 0), e[1:], atol=1e-6)
mv = np.linalg.norm(dpt, axis=1); fwd = mv > 0.02
parts = {
    'attitude-induced (yaw/tilt x distance)': att,
    'local, along heading (cam z)': np.einsum('nij,nj->ni', Re[:-1][:, :, [2]], (dpe - dpt)[:, [2]]),
    'local, lateral (cam x)': np.einsum('nij,nj->ni', Re[:-1][:, :, [0]], (dpe - dpt)[:, [0]]),
    'local, vertical (cam y)': np.einsum('nij,nj->ni', Re[:-1][:, :, [1]], (dpe - dpt)[:, [1]]),
    'local, on forward steps': loc * fwd[:, None],
    'local, on turn-in-place steps': loc * (~fwd)[:, None],
}
print(f"== {run}")
print("contribution to the error vector (cm, world x y z) and its projection on the final error direction")
u = e[-1] / np.linalg.norm(e[-1])
for ck in [200, 500, 1000, n - 1]:
    uk = e[ck] / max(np.linalg.norm(e[ck]), 1e-9)
    print(f" step {ck}: |e| = {100*np.linalg.norm(e[ck]):.1f} cm")
    for name, c in parts.items():
        s = c[:ck].sum(0)
        print(f"   {name:40s} |sum| {100*np.linalg.norm(s):6.1f}  along e_k {100*s@uk:6.1f}")
# fastest-growing windows
W = 25
en = np.linalg.norm(e, axis=1)
g = en[W:] - en[:-W]
ev = events(run)
order = np.argsort(-g)
picked = []
for i in order:
    if all(abs(i - j) > W for j in picked): picked.append(i)
    if len(picked) >= nw: break
yawt = np.degrees(np.unwrap(np.arctan2(Rt[:, 1, 2], Rt[:, 0, 2])))
print(f"fastest-growing {W}-step windows of |e|:")
for i in sorted(picked):
    a, b = i, i + W
    nf = fwd[a:b].sum(); turned = abs(yawt[b] - yawt[a])
    evs = [(f, m) for f in sorted(ev) if a - 5 <= f <= b + 2 for m in ev[f]]
    print(f" steps {a}-{b}: |e| {100*en[a]:.1f} -> {100*en[b]:.1f} cm; {nf} forward steps, {b-a-nf} turn steps (net turn {turned:.0f} deg); "
          f"local err sum {100*np.linalg.norm(loc[a:b].sum(0)):.1f} cm, attitude {100*np.linalg.norm(att[a:b].sum(0)):.1f} cm; log: {evs[:4]}{' ...' if len(evs)>4 else ''}")
