#!/usr/bin/env python3
"""Where the error vector moves: sum over steps of |e_k - e_(k-1)| (world, raw) and of the signed
growth d|e|, split by what the step was: forward tracked, turn-in-place tracked, inside a lost run
(motion check / depth residual: the estimate is the commanded prediction), relocalisation frame;
and by phase (before / after the first refine goal). usage: budget.py RUN_DIR [...]"""
import sys, os
import numpy as np
sys.path.insert(0, os.path.dirname(__file__))
from drift import analyse, events, refine_step
for run in sys.argv[1:]:
    d = analyse(run); e = d['pe_w'] - d['pt']; n = len(e)
    de = np.linalg.norm(np.diff(e, axis=0), axis=1)           # step k-1 -> k, index k-1
    dn = np.diff(np.linalg.norm(e, axis=1))
    fwd = d['dstep'][1:] > 0.02
    ev = events(run)
    lost = np.zeros(n, bool); reloc = np.zeros(n, bool); start = None
    for f in sorted(ev):
        for m in ev[f]:
            if m.startswith('tracking lost'): start = f
            elif m.startswith('tracking regained') and start is not None: lost[start:f] = True; start = None
            if m.startswith('relocalised'): reloc[f] = True
    if start is not None: lost[start:] = True
    L = lost[1:]; Rl = reloc[1:]
    r = refine_step(run) or n
    phase = np.arange(1, n) >= r
    print(f"== {run}  (refine from step {r})")
    print("  kind                | steps | sum |de| cm | sum d|e| cm | before refine: steps, sum d|e| | after: steps, sum d|e|")
    for name, m in [('forward, tracked', fwd & ~L & ~Rl), ('turn, tracked', ~fwd & ~L & ~Rl), ('in a lost run', L & ~Rl), ('relocalisation', Rl)]:
        print(f"  {name:19s} | {m.sum():5d} | {100*de[m].sum():8.1f} | {100*dn[m].sum():+8.1f} | {(m&~phase).sum():5d}, {100*dn[m&~phase].sum():+7.1f} | {(m&phase).sum():5d}, {100*dn[m&phase].sum():+7.1f}")
