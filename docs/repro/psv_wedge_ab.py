"""The PSV wedge A/B (docs/psv.md, "Signed wedge"): ``wedge="conservative"`` against
``wedge="signed"`` in one process, alternating blocks (each block: one call that builds
and keeps the tree, then REPEATS timed calls reusing it), with the node visits of both
and a check that the lit masks are identical.
usage: python docs/repro/psv_wedge_ab.py RES PAIRS OUT.json scene[:n=..,k=..]..."""
import json, os, statistics, sys, time
import numpy as np
import shadowlab as sl
from _psv_frames import method_rows

res, pairs, out = int(sys.argv[1]), int(sys.argv[2]), sys.argv[3]
METHODS = ["psv", "d_psv", "d_stackless", "d_hybrid"]
LABELS = ("conservative", "signed")
REPEATS = 3
rows = []
for scene, view, gbuf, m, row in method_rows(sys.argv[4:], res, METHODS):
    got = {w: {"query_ms": [], "total_ms": []} for w in LABELS}
    lit = {}
    for i in range(pairs):
        for w in LABELS if i % 2 == 0 else LABELS[::-1]:
            f = lambda: sl.compute_shadows(scene, gbuf, view.light, method=m, wedge=w,
                                           reuse_tree=True)
            r = f()                                   # builds and keeps the tree
            for _ in range(REPEATS):
                t0 = time.perf_counter()
                r = f()
                got[w]["total_ms"].append(1e3 * (time.perf_counter() - t0))
                got[w]["query_ms"].append(1e3 * (r.timings["query"]
                                                 + r.timings.get("query_compact", 0.0)))
            got[w]["visited_nodes"] = int(r.counters["visited_nodes"])
            lit[w] = r.lit
    for w in LABELS:
        row[w] = {"query_ms": statistics.median(got[w]["query_ms"]),
                  "total_ms": statistics.median(got[w]["total_ms"]),
                  "query_ms_all": [round(x, 1) for x in got[w]["query_ms"]],
                  "visited_nodes": got[w]["visited_nodes"]}
    row["lit_identical"] = bool(np.array_equal(lit["conservative"], lit["signed"]))
    row["query_ratio"] = row["signed"]["query_ms"] / row["conservative"]["query_ms"]
    row["visit_ratio"] = row["signed"]["visited_nodes"] / row["conservative"]["visited_nodes"]
    row["load_end"] = os.getloadavg()[0]
    rows.append(row)
    print(json.dumps({k: v for k, v in row.items() if k not in LABELS}), flush=True)
json.dump({"resolution": res, "pairs": pairs, "repeats": REPEATS, "rows": rows},
          open(out, "w"), indent=1)
