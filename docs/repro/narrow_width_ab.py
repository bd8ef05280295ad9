"""The light raster's narrowing width A/B (docs/shadow_map.md, "Row spans"): for each
value of ``light_raster.NARROW_DENSE_COLUMNS`` (16: every box under 16 columns enumerated
whole, the former rule; 8: the shipped one, boxes from 8 columns narrowed where the keys
are dense), in turn in one process after a warm-up call of each (only a module constant
changes between settings), with a check that the lit masks and every scalar counter are
identical. Times: the whole compute_shadows call at 1024x1024, medians over ROUNDS.
usage: python docs/repro/narrow_width_ab.py WIDTHS ROUNDS OUT.json METHODS scene[:k=v,..]...
e.g. python docs/repro/narrow_width_ab.py 16,8 4 out.json izb,shadow_map fuzzy:triangles=100000
"""
import json
import os
import statistics
import sys
import time

import numpy as np
from _psv_frames import frame

import shadowlab as sl
from shadowlab.structures import light_raster as lr

widths = [int(x) for x in sys.argv[1].split(",")]
rounds, out, methods = int(sys.argv[2]), sys.argv[3], sys.argv[4].split(",")
shipped = lr.NARROW_DENSE_COLUMNS
rows = []
for spec in sys.argv[5:]:
    scene, view, gbuf = frame(spec, 1024)
    for m in methods:
        times, ref = {w: [] for w in widths}, {}
        for w in widths:                    # warm-up, and the results to compare
            lr.NARROW_DENSE_COLUMNS = w
            r = sl.compute_shadows(scene, gbuf, view.light, method=m)
            ref[w] = (np.packbits(r.lit).tobytes(),
                      sorted((k, v) for k, v in r.counters.items() if np.ndim(v) == 0))
        load = os.getloadavg()[0]
        for i in range(rounds):
            for w in (widths if i % 2 == 0 else widths[::-1]):
                lr.NARROW_DENSE_COLUMNS = w
                t = time.perf_counter()
                sl.compute_shadows(scene, gbuf, view.light, method=m)
                times[w].append(time.perf_counter() - t)
        row = {"method": m, "scene": spec, "load_1min_start": load,
               "identical": all(ref[w] == ref[widths[0]] for w in widths),
               "median_ms": {w: round(1e3 * statistics.median(v)) for w, v in times.items()},
               "runs_ms": {w: [round(1e3 * x) for x in v] for w, v in times.items()}}
        rows.append(row)
        print(json.dumps(row), flush=True)
lr.NARROW_DENSE_COLUMNS = shipped
with open(out, "w") as f:
    json.dump({"widths": widths, "rounds": rounds, "rows": rows}, f, indent=1)
