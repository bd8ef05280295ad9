"""The PSV query's visit counter A/B (docs/psv.md, "Visit counts in the state word"):
the same TOP tree (renumbered breadth-first, as the bench's static runs keep it) queried
with the query's ``psv.VISITS_IN_WORD`` entry off (a per-lane counter array, one more
loop output) and on (a finished lane's count in its state word), in alternation in one
process, with a check that every output is identical. Times: the query's chunk kernels.
usage: python docs/repro/psv_visits_ab.py RES PAIRS OUT.json METHODS scene[:n=..,k=..]...
(METHODS: comma-separated, e.g. psv,d_psv,d_stackless; d_hybrid always keeps its array)
"""
import json, os, statistics, sys

import numpy as np

from _psv_frames import QUERIES, frame, keep_kernels_per_flag, query_inputs
from shadowlab.core.timing import StageTimer
from shadowlab.methods import psv as psvm
from shadowlab.methods.registry import call_options
from shadowlab.structures import top_tree as tt

res, pairs, out, methods = int(sys.argv[1]), int(sys.argv[2]), sys.argv[3], sys.argv[4]
# Both variants' kernels are traced once and kept: the flag is read at trace time.
default = dict(psvm.VISITS_IN_WORD)
keep_kernels_per_flag(lambda: tuple(sorted(psvm.VISITS_IN_WORD.items())))
if "d_hybrid" in methods.split(","):
    sys.exit("d_hybrid cannot keep its visit counts in its state words (its stack-only step "
             "idles lanes); choose among psv, d_psv, d_stackless")
rows = []
for spec in sys.argv[5:]:
    scene, view, gbuf = frame(spec, res)
    q = query_inputs(scene, view, gbuf)
    q["tree"] = q["tree"].renumbered(tt.breadth_first_volumes(q["tree"]))
    for m in methods.split(","):
        query, depth = QUERIES[m]
        stack = call_options(m, {}).get("stack_size", 0)

        def run(in_word):
            psvm.VISITS_IN_WORD = dict(default, **{query: in_word})
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
               "array_ms": [round(1e3 * x, 1) for x in times[False]],
               "in_word_ms": [round(1e3 * x, 1) for x in times[True]],
               "ratio_of_medians": statistics.median(times[True])
               / statistics.median(times[False])}
        rows.append(row)
        print(f"{spec} {m}: array {1e3 * statistics.median(times[False]):.0f} ms, in word "
              f"{1e3 * statistics.median(times[True]):.0f} ms (x{row['ratio_of_medians']:.3f}),"
              f" identical {same}", flush=True)
psvm.VISITS_IN_WORD = default
with open(out, "w") as f:
    json.dump({"resolution": res, "pairs": pairs, "rows": rows}, f, indent=1)
