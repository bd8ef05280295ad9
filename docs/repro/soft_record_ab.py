"""soft_tiled's record test A/B (docs/soft_tiled.md): record="exact" (the per-pixel quick
reject) against record="sphere" (bounding sphere against the pixel's light cone) and
record="both" (the quick reject and the sphere test), on the
bench's soft cases at a given resolution: warm medians of 5 runs, the variants
interleaved, of the whole compute_shadows call and of its eval stage in one process, the pair counters, and whether the visibility
is bit-identical.
usage: python docs/repro/soft_record_ab.py RES OUT.json [case-name-prefix ...]"""
import json, statistics, sys, time
import numpy as np
import shadowlab as sl
from shadowlab.config.loading import load_config
from shadowlab.core.machine import machine_record, machine_state
from shadowlab.harness.bench import default_cases

res, out = int(sys.argv[1]), sys.argv[2]
names = sys.argv[3:] or ["soft-terrain-1024", "soft-fuzzy-1024", "soft-spheres-1024"]
cases = {c["name"]: c for c in default_cases("full")}
VARIANTS = ("exact", "sphere", "both")
REPEATS = 5
KEYS = ("tests", "recorded_pairs", "rasterized_triangles", "raster_lanes")
rows = []
for name in names:
    over = [o for o in cases[name]["overrides"] if not o.startswith("camera.resolution")]
    config = load_config(None, over + [f"camera.resolution=[{res},{res}]"])
    scene = config.build_scene()
    view = config.views(scene)[0]
    gbuf = sl.render_gbuffer(scene, view.camera)
    row = {"case": name, "resolution": res, "triangles": scene.num_triangles}
    before = machine_state()
    lits, calls, walls, evals = {}, {}, {v: [] for v in VARIANTS}, {v: [] for v in VARIANTS}
    for record in VARIANTS:                               # first calls: compile
        calls[record] = (lambda rec: lambda: sl.compute_shadows(
            scene, gbuf, view.light, method="soft_tiled", record=rec))(record)
        r = calls[record]()
        row[record] = {"compile_seconds_first_call":
                       sum(v for k, v in r.timings.items() if k.endswith("_compile"))}
    for _ in range(REPEATS):                              # warm runs, interleaved
        for record in VARIANTS:
            t0 = time.perf_counter(); r = calls[record](); walls[record].append(time.perf_counter() - t0)
            evals[record].append(r.timings["eval"])
            lits[record] = r.lit
            row[record].update({k: int(r.counters[k]) for k in KEYS})
    for record in VARIANTS:
        row[record].update(seconds=statistics.median(walls[record]),
                           eval_seconds=statistics.median(evals[record]),
                           eval_runs=evals[record])
    row["identical"] = all(bool(np.array_equal(lits["exact"], lits[k])) for k in ("sphere", "both"))
    row["machine"] = machine_record(before, machine_state())
    rows.append(row)
    print(json.dumps(row), flush=True)
json.dump({"rows": rows}, open(out, "w"), indent=1)
