"""The light raster's count pass A/B (docs/shadow_map.md, "Row spans"), three settings
of ``shadowlab.structures.light_raster``, for the methods that rasterize in light space:
``before``: binary searches, whole box rows, power-of-two fragment capacities (the code
before the change); ``rank``: the key rank table and 2 capacities per octave, whole box
rows; ``shipped``: both plus the row spans (``NARROW_MIN_COLUMNS``,
``NARROW_DENSE_COLUMNS``). In turn, in one
process, after a warm-up call of each, with a check that the lit masks and every scalar
counter are identical. Times: the whole compute_shadows call and its stages (medians),
with the candidate and covered fragment counts of each raster call of the frame.
usage: python docs/repro/raster_spans_ab.py RES ROUNDS OUT.json METHODS scene[:k=v,..]...
(METHODS: comma-separated, e.g. izb,shadow_map)
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

res, rounds, out, methods = int(sys.argv[1]), int(sys.argv[2]), sys.argv[3], sys.argv[4]
SHIPPED = (lr.key_rank, lr.FRAGMENT_BUCKET_STEPS, lr.NARROW_MIN_COLUMNS,
           lr.NARROW_DENSE_COLUMNS)
NO_SPANS = 1 << 62
SETTINGS = {"before": (lambda keys, size: None, 1, NO_SPANS, NO_SPANS),
            "rank": (SHIPPED[0], SHIPPED[1], NO_SPANS, NO_SPANS), "shipped": SHIPPED}
OPTIONS = {"izb": {"verify": False}}

calls = []
real_raster = lr.raster


def counting_raster(setups, keys, resolution, mode, *args, **kw):
    fr = real_raster(setups, keys, resolution, mode, *args, **kw)
    calls.append({"mode": mode, "candidates": int(fr.candidates),
                  "covered": int(np.asarray(fr.covered).sum())})
    return fr


lr.raster = counting_raster
rows = []
for spec in sys.argv[5:]:
    scene, view, gbuf = frame(spec, res)
    for m in methods.split(","):
        def run(setting):
            (lr.key_rank, lr.FRAGMENT_BUCKET_STEPS, lr.NARROW_MIN_COLUMNS,
             lr.NARROW_DENSE_COLUMNS) = SETTINGS[setting]
            calls.clear()
            t0 = time.perf_counter()
            r = sl.compute_shadows(scene, gbuf, view.light, method=m, **OPTIONS.get(m, {}))
            return r, time.perf_counter() - t0, list(calls)

        row = {"scene": spec, "triangles": scene.num_triangles, "method": m,
               "load_start": os.getloadavg()[0]}
        first = {}
        for setting in SETTINGS:
            run(setting)                                   # compile
            r, _, raster_calls = run(setting)
            first[setting] = r
            row[setting] = {"rasters": raster_calls, "ms": [], "stages": {}}
        a = first["before"]
        scalars = [k for k, v in a.counters.items() if np.isscalar(v)]
        row["identical"] = all(bool(np.array_equal(a.lit, b.lit) and all(
            a.counters[k] == b.counters[k] for k in scalars)) for b in first.values())
        for i in range(rounds):
            for setting in (SETTINGS if i % 2 == 0 else list(SETTINGS)[::-1]):
                r, dt, _ = run(setting)
                row[setting]["ms"].append(round(1e3 * dt, 1))
                for stage, sec in r.timings.items():
                    row[setting]["stages"].setdefault(stage, []).append(1e3 * sec)
        for setting in SETTINGS:
            d = row[setting]
            d["median_ms"] = statistics.median(d["ms"])
            d["stages"] = {k: round(statistics.median(v), 1) for k, v in d["stages"].items()
                           if not k.endswith("_compile")}
        for setting in ("rank", "shipped"):
            row[f"{setting}_over_before"] = (row[setting]["median_ms"]
                                             / row["before"]["median_ms"])
        row["load_end"] = os.getloadavg()[0]
        rows.append(row)
        print(f"{spec} {m}: " + ", ".join(f"{k} {row[k]['median_ms']:.0f} ms"
                                          for k in SETTINGS)
              + f" (shipped x{row['shipped_over_before']:.3f}), identical {row['identical']}",
              flush=True)
(lr.key_rank, lr.FRAGMENT_BUCKET_STEPS, lr.NARROW_MIN_COLUMNS,
 lr.NARROW_DENSE_COLUMNS) = SHIPPED
lr.raster = real_raster
with open(out, "w") as f:
    json.dump({"resolution": res, "rounds": rounds, "rows": rows}, f, indent=1)
