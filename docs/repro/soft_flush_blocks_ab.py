"""A/B of the soft_tiled flush (blocks against waves): visibility and counters hashed,
raster_lanes, first call (compile included, no persistent cache) and warm medians.

Run once per code version, e.g. from a worktree of the older commit with
``PYTHONPATH=<worktree>``:

    python docs/repro/soft_flush_blocks_ab.py RES REPEATS OUT.json
"""

import hashlib
import json
import statistics
import sys
import time

import numpy as np

import shadowlab as sl
from shadowlab.scene.procedural import default_view

CASES = [("fuzzy", {"triangles": 20000}, ("sphere", 0.5)), ("terrain", {}, ("sun", 1.0)),
         ("sphere_grid", {"n": 10, "triangles_per_sphere": 1000}, ("sphere", 2.0)),
         ("gate", {}, ("sphere", 0.5))]


def light_of(scene, view, kind, size):
    if kind == "sphere":
        return sl.SphereLight(position=np.asarray(view.light.position, float), radius=size)
    if view.light.position is not None:
        d = np.asarray(view.light.position, float) - scene.vertices.mean(0)
    else:
        d = -np.asarray(view.light.direction)
    return sl.SphereLight(direction=-d / np.linalg.norm(d), angular_radius_deg=size)


def digest(a) -> str:
    return hashlib.sha1(np.asarray(a).tobytes()).hexdigest()[:12]


def main(res: int, repeats: int, out_path: str) -> None:
    out = {"module": sl.__file__, "resolution": res, "repeats": repeats, "cases": {}}
    for name, params, (kind, size) in CASES:
        scene = sl.load_scene(name, **params)
        view = default_view(name, scene, **params)
        light = light_of(scene, view, kind, size)
        gbuf = sl.render_gbuffer(scene, view.camera.replace(resolution=(res, res)))
        for opts in ({}, {"record": "sphere"}):
            t0 = time.perf_counter()
            r = sl.compute_shadows(scene, gbuf, light, method="soft_tiled", **opts)
            first = time.perf_counter() - t0
            warm = [sl.compute_shadows(scene, gbuf, light, method="soft_tiled", **opts)
                    for _ in range(repeats)]
            key = f"{name} {json.dumps(opts)}"
            out["cases"][key] = {
                "lit": digest(r.lit),
                "counters": {k: digest(v) for k, v in r.counters.items() if k != "raster_lanes"},
                "raster_lanes": int(r.counters["raster_lanes"]),
                "first_seconds": first,
                "eval_median": statistics.median(w.timings["eval"] for w in warm),
                "total_median": statistics.median(w.timings["total"] for w in warm)}
            print(key, out["cases"][key]["raster_lanes"], round(first, 2),
                  round(out["cases"][key]["eval_median"], 3), flush=True)
    with open(out_path, "w") as f:
        json.dump(out, f, indent=1)


if __name__ == "__main__":
    main(int(sys.argv[1]), int(sys.argv[2]), sys.argv[3])
