"""The PSV query's node order A/B (docs/psv.md, "Node order"): one TOP tree as built
(volume ids = insertion ranks) and the same tree renumbered breadth-first, queried in
alternation in one process (so the machine's drift hits both alike), with a check that
every output of the query (shadow, visits, stack use, overflows, switches) is identical.
usage: python docs/repro/psv_node_order_ab.py RES PAIRS OUT.json scene[:n=..,k=..]...
"""
import json, os, statistics, sys, time

import numpy as np

from _psv_frames import QUERIES, frame, query_inputs
from shadowlab.methods import psv as psvm
from shadowlab.methods.registry import call_options
from shadowlab.structures import top_tree as tt

res, pairs, out = int(sys.argv[1]), int(sys.argv[2]), sys.argv[3]
rows = []
for spec in sys.argv[4:]:
    scene, view, gbuf = frame(spec, res)
    q = query_inputs(scene, view, gbuf)
    built, o = q["tree"], q["o"]
    scale, key, pts, light_h = q["scale"], q["key"], q["points"], q["light_h"]
    t0 = time.perf_counter()
    volumes = tt.breadth_first_volumes(built)
    t1 = time.perf_counter()
    bfs = built.renumbered(volumes)
    t2 = time.perf_counter()
    for m, (query, depth) in QUERIES.items():
        stack = call_options(m, {}).get("stack_size", 0)

        def run(tree):
            return psvm.run_query(tree, pts, scale, key, light_h, query=query,
                                  depth_test=depth, wedge=o["wedge"], stack_size=stack)

        first = {"build": run(built), "breadth_first": run(bfs)}          # compile, check
        same = all(np.array_equal(first["build"][k], first["breadth_first"][k])
                   for k in first["build"])
        times = {"build": [], "breadth_first": []}
        load = os.getloadavg()[0]
        for _ in range(pairs):
            for label, tree in (("build", built), ("breadth_first", bfs)):
                t = time.perf_counter()
                run(tree)
                times[label].append(time.perf_counter() - t)
        row = {"scene": spec, "triangles": scene.num_triangles, "method": m,
               "casters": int(built.count), "load_start": load, "identical": same,
               "order_ms": 1e3 * (t1 - t0), "renumber_ms": 1e3 * (t2 - t1),
               **{f"{k}_ms": [round(1e3 * x, 1) for x in v] for k, v in times.items()},
               "ratio_of_medians": statistics.median(times["breadth_first"])
               / statistics.median(times["build"])}
        rows.append(row)
        print(f"{spec} {m}: build {1e3 * statistics.median(times['build']):.0f} ms, "
              f"breadth-first {1e3 * statistics.median(times['breadth_first']):.0f} ms "
              f"(x{row['ratio_of_medians']:.3f}), identical {same}", flush=True)
with open(out, "w") as f:
    json.dump(rows, f, indent=1)
