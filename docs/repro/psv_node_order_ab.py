"""The PSV query's node order A/B (docs/psv.md, "Node order"): one TOP tree as built
(volume ids = insertion ranks) and the same tree renumbered breadth-first, queried in
alternation in one process (so the machine's drift hits both alike), with a check that
every output of the query (shadow, visits, stack use, overflows, switches) is identical.
usage: python docs/repro/psv_node_order_ab.py RES PAIRS OUT.json scene[:n=..,k=..]...
"""
import json, os, statistics, sys, time

import numpy as np

import shadowlab as sl
from shadowlab.core.frame import localize, view_samples
from shadowlab.methods import psv as psvm
from shadowlab.methods.registry import call_options
from shadowlab.scene.procedural import default_view
from shadowlab.scene.view import hard_light
from shadowlab.structures import top_tree as tt

res, pairs, out = int(sys.argv[1]), int(sys.argv[2]), sys.argv[3]
QUERIES = {"psv": ("stack", False), "d_psv": ("stack", True),
           "d_stackless": ("stackless", True), "d_hybrid": ("hybrid", True)}
rows = []
for spec in sys.argv[4:]:
    name, _, params = spec.partition(":")
    kw = {k: int(v) for k, v in (p.split("=") for p in params.split(",") if p)}
    scene = sl.load_scene(name, **kw)
    view = default_view(name, scene)
    gbuf = sl.render_gbuffer(scene, view.camera.replace(resolution=(res, res)))
    local = localize(scene, gbuf, view.light, "light")       # as the methods (frame "light")
    o = call_options("psv", {})
    samples = view_samples(local.gbuf, local.light)
    light_h = hard_light(local.light).homogeneous
    built, scale, _ = psvm.build_tree(
        local.scene, local.light, local.gbuf.camera, samples, dtype=np.float32,
        shadow_eps=o["shadow_eps"], bias=o["bias"], order=o["order"], seed=o["seed"],
        wedge=o["wedge"], classify_ulps=o["classify_ulps"], face_culling=o["face_culling"])
    t0 = time.perf_counter()
    volumes = tt.breadth_first_volumes(built)
    t1 = time.perf_counter()
    bfs = built.renumbered(volumes)
    t2 = time.perf_counter()
    key = tt.light_key(samples.position, light_h)
    pts = samples.position.astype(np.float32)
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
