"""The PSV query's lane order A/B (docs/psv.md): ``lane_tile`` 1 (row-major samples)
against square pixel tiles, warm medians of the whole compute_shadows call and of its
query stage in one process, with a check that the lit mask and every per-pixel counter
are identical.
usage: python docs/repro/psv_lane_tile_ab.py RES OUT.json TILES scene[:n=..,k=..]...
(TILES: comma-separated sides, the first the baseline, e.g. 1,8,16)"""
import json, os, statistics, sys, time
import numpy as np
import shadowlab as sl
from _psv_frames import method_rows

res, out, tiles = int(sys.argv[1]), sys.argv[2], [int(t) for t in sys.argv[3].split(",")]
METHODS = ["psv", "d_psv", "d_stackless", "d_hybrid"]
REPEATS = 3
rows = []
for scene, view, gbuf, m, row in method_rows(sys.argv[4:], res, METHODS):
    first = None
    for t in tiles:
        f = lambda: sl.compute_shadows(scene, gbuf, view.light, method=m, lane_tile=t)
        r = f()
        total, query = [], []
        for _ in range(REPEATS):
            t0 = time.perf_counter()
            r = f()
            total.append(time.perf_counter() - t0)
            query.append(r.timings["query"] + r.timings.get("query_compact", 0.0))
        same = None
        if first is None:
            first = r
        else:
            same = bool(np.array_equal(r.lit, first.lit) and all(
                np.array_equal(np.asarray(r.counters[k]), np.asarray(first.counters[k]))
                for k in first.counters if k.endswith("_per_pixel") or k == "visited_nodes"))
        row[f"tile{t}"] = {"ms": 1e3 * statistics.median(total),
                           "query_ms": 1e3 * statistics.median(query),
                           "identical": same}
    row["load_end"] = os.getloadavg()[0]
    rows.append(row)
    print(json.dumps(row), flush=True)
json.dump({"resolution": res, "tiles": tiles, "repeats": REPEATS, "rows": rows},
          open(out, "w"), indent=1)
