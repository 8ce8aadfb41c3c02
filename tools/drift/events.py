#!/usr/bin/env python3
"""Error before/after each tracker log event (relocalisations, lost runs): do the jumps move the
estimate towards the truth (a correction) or away? usage: events.py RUN_DIR"""
import sys, os, re
import numpy as np
sys.path.insert(0, os.path.dirname(__file__))
from drift import analyse, events
run = sys.argv[1]
d = analyse(run); e = d['pe_w'] - d['pt']; en = np.linalg.norm(e, axis=1)
ev = events(run)
print(f"== {run}")
tot_rel = 0
for f in sorted(ev):
    for m in ev[f]:
        if m.startswith('relocalised') or m.startswith('tracking lost'):
            a, b = max(f - 1, 0), min(f + (0 if m.startswith('relocalised') else 0), len(en) - 1)
            # lost: from frame before the run to the frame the run ends (regained)
            if m.startswith('tracking lost'):
                ends = [g for g in sorted(ev) if g > f and any(x.startswith('tracking regained') for x in ev[g])]
                b = ends[0] if ends else len(en) - 1
                kind = 'lost run'
            else:
                kind = 'reloc'
            jump = np.linalg.norm(e[b] - e[a])
            print(f" {kind:8s} frames {a}->{b}: |e| {100*en[a]:5.1f} -> {100*en[b]:5.1f} cm (change of error vector {100*jump:5.1f} cm)  | {m[:90]}")
