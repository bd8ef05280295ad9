"""The PSV query's tile loop A/B (docs/psv.md, "The stack stays in place across tiles"):
the same TOP tree (renumbered breadth-first, as the bench's static runs keep it) queried
with ``psv.STACK_IN_PLACE`` off (each tile's slice of the stack copied out of the buffer
and written back per chunk) and on (the tile's lanes address the whole buffer at their
tile's offset), in alternation in one process, with a check that every output is
identical. Times: the query's chunk kernels.
usage: python docs/repro/psv_stack_in_place_ab.py RES PAIRS OUT.json METHODS scene[:k=v,..]...
(METHODS: comma-separated among psv, d_psv, d_hybrid; d_stackless keeps no stack)
"""
import json, os, statistics, sys

import numpy as np

from _psv_frames import QUERIES, frame, keep_kernels_per_flag, query_inputs
from shadowlab.core.timing import StageTimer
from shadowlab.methods import psv as psvm
from shadowlab.methods.registry import call_options
from shadowlab.structures import top_tree as tt

res, pairs, out, methods = int(sys.argv[1]), int(sys.argv[2]), sys.argv[3], sys.argv[4]
if "d_stackless" in methods.split(","):
    sys.exit("d_stackless keeps no stack; choose among psv, d_psv, d_hybrid")
default = psvm.STACK_IN_PLACE
keep_kernels_per_flag(lambda: psvm.STACK_IN_PLACE)
rows = []
for spec in sys.argv[5:]:
    scene, view, gbuf = frame(spec, res)
    q = query_inputs(scene, view, gbuf)
    q["tree"] = q["tree"].renumbered(tt.breadth_first_volumes(q["tree"]))
    for m in methods.split(","):
        query, depth = QUERIES[m]
        stack = call_options(m, {}).get("stack_size", 0)

        def run(in_place):
            psvm.STACK_IN_PLACE = in_place
            timer = StageTimer()
            got = psvm.run_query(q["tree"], q["points"], q["scale"], q["key"], q["light_h"],
                                 query=query, depth_test=depth, wedge=q["o"]["wedge"],
                                 stack_size=stack, timer=timer)
            return got, timer.times["query"]

        first = {flag: run(flag)[0] for flag in (False, True)}          # compile, check
        same = all(np.array_equal(first[False][k], first[True][k]) for k in first[False])
        times = {False: [], True: []}
        load = os.getloadavg()[0]
        for _ in range(pairs):
            for flag in (False, True):
                times[flag].append(run(flag)[1])
        row = {"scene": spec, "triangles": scene.num_triangles, "method": m,
               "load_start": load, "load_end": os.getloadavg()[0], "identical": same,
               "sliced_ms": [round(1e3 * x, 1) for x in times[False]],
               "in_place_ms": [round(1e3 * x, 1) for x in times[True]],
               "ratio_of_medians": statistics.median(times[True])
               / statistics.median(times[False])}
        rows.append(row)
        print(f"{spec} {m}: sliced {1e3 * statistics.median(times[False]):.0f} ms, in place "
              f"{1e3 * statistics.median(times[True]):.0f} ms (x{row['ratio_of_medians']:.3f}),"
              f" identical {same}", flush=True)
psvm.STACK_IN_PLACE = default
with open(out, "w") as f:
    json.dump({"resolution": res, "pairs": pairs, "rows": rows}, f, indent=1)
