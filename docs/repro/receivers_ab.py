"""The receivers step's time A/B (docs/culling.md): cull_casters "hull_averted" against
"all" (which adds the receivers step), warm medians of 3 of the whole compute_shadows call
in one process, with the culled counts, mismatches against Embree and whether the lit masks
are identical.
usage: python docs/repro/receivers_ab.py RES OUT.json scene..."""
import json, os, statistics, sys, time
import numpy as np
import shadowlab as sl
from shadowlab.scene.procedural import default_view
res, out, scenes = int(sys.argv[1]), sys.argv[2], sys.argv[3:]
METHODS = ["ptsv", "clustered_ptsv", "psv", "d_stackless", "silhouette", "izb"]
rows = []
for name in scenes:
    scene = sl.load_scene(name); view = default_view(name, scene)
    gbuf = sl.render_gbuffer(scene, view.camera.replace(resolution=(res, res)))
    truth = sl.reference_shadows(scene, gbuf, view.light)
    for m in METHODS:
        row = {"scene": name, "triangles": scene.num_triangles, "method": m, "load_start": os.getloadavg()[0]}
        lits = {}
        for mode in ("hull_averted", "all"):
            f = lambda: sl.compute_shadows(scene, gbuf, view.light, method=m, cull_casters=mode)
            r = f(); ts = []
            for _ in range(3):
                t0 = time.perf_counter(); r = f(); ts.append(time.perf_counter() - t0)
            lits[mode] = r.lit
            row[mode] = {"ms": 1e3 * statistics.median(ts), "cull_ms": 1e3 * r.timings.get("cull_casters", 0.0),
                         "culled": [int(r.counters[k]) for k in ("culled_casters_hull", "culled_casters_averted", "culled_casters_receivers")],
                         "mismatches": int(((r.lit != truth) & gbuf.valid).sum())}
        row["identical"] = bool(np.array_equal(lits["hull_averted"], lits["all"]))
        row["load_end"] = os.getloadavg()[0]
        rows.append(row); print(json.dumps(row), flush=True)
json.dump({"resolution": res, "rows": rows}, open(out, "w"), indent=1)
