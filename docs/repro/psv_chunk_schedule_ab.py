"""The PSV query's chunk schedule A/B (docs/psv.md, "Chunk schedule"): the same TOP tree
(renumbered breadth-first, as the bench's static runs keep it) queried with
``schedule="fixed"`` (32 visits per chunk) and ``"adaptive"`` in
alternation in one process (so the machine's drift hits both alike), with a check that
every output but the chunk count (shadow, visits, stack use, overflows, switches) is
identical. Times: the whole query call, and its chunk kernels and checks/compactions.
usage: python docs/repro/psv_chunk_schedule_ab.py RES PAIRS OUT.json scene[:n=..,k=..]...
"""
import json, os, statistics, sys, time

import numpy as np

from _psv_frames import QUERIES, frame, query_inputs
from shadowlab.core.timing import StageTimer
from shadowlab.methods import psv as psvm
from shadowlab.methods.registry import call_options
from shadowlab.structures import top_tree as tt

res, pairs, out = int(sys.argv[1]), int(sys.argv[2]), sys.argv[3]
SCHEDULES = ("fixed", "adaptive")
rows = []
for spec in sys.argv[4:]:
    scene, view, gbuf = frame(spec, res)
    q = query_inputs(scene, view, gbuf)
    q["tree"] = q["tree"].renumbered(tt.breadth_first_volumes(q["tree"]))
    for m, (query, depth) in QUERIES.items():
        stack = call_options(m, {}).get("stack_size", 0)

        def run(schedule):
            timer = StageTimer()
            got = psvm.run_query(q["tree"], q["points"], q["scale"], q["key"], q["light_h"],
                                 query=query, depth_test=depth, wedge=q["o"]["wedge"],
                                 stack_size=stack, schedule=schedule, timer=timer)
            return got, timer.times

        first = {s: run(s)[0] for s in SCHEDULES}                 # compile, check
        same = all(np.array_equal(first["fixed"][k], first["adaptive"][k])
                   for k in first["fixed"] if k != "chunks")
        times = {s: {"call": [], "query": [], "query_compact": []} for s in SCHEDULES}
        load = os.getloadavg()[0]
        for _ in range(pairs):
            for s in SCHEDULES:
                t = time.perf_counter()
                _, stages = run(s)
                times[s]["call"].append(time.perf_counter() - t)
                for k in ("query", "query_compact"):
                    times[s][k].append(stages.get(k, 0.0))
        med = {s: {k: 1e3 * statistics.median(v) for k, v in t.items()}
               for s, t in times.items()}
        row = {"scene": spec, "triangles": scene.num_triangles, "method": m,
               "load_start": load, "load_end": os.getloadavg()[0], "identical": same,
               "chunks": {s: int(first[s]["chunks"]) for s in SCHEDULES},
               "call_ms": {s: [round(1e3 * x, 1) for x in times[s]["call"]]
                           for s in SCHEDULES},
               "median_ms": {s: {k: round(v, 1) for k, v in d.items()} for s, d in med.items()},
               "ratio_of_medians": med["adaptive"]["call"] / med["fixed"]["call"]}
        rows.append(row)
        print(f"{spec} {m}: fixed {med['fixed']['call']:.0f} ms ({row['chunks']['fixed']} "
              f"chunks), adaptive {med['adaptive']['call']:.0f} ms "
              f"({row['chunks']['adaptive']}) x{row['ratio_of_medians']:.3f}, "
              f"identical {same}", flush=True)
with open(out, "w") as f:
    json.dump({"resolution": res, "pairs": pairs, "rows": rows}, f, indent=1)
