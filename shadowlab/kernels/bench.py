"""Kernels (Warp, CPU backend) against the JAX versions: run times at 512x512 and 1024x1024.

    python -m shadowlab.kernels.bench [--sizes 512 1024] [--repeats 3] [--out FILE.json]
                                      [--only psv clustered sun_disk]

For each size: the PSV methods on a procedural scene (TOP-tree build and query timed
apart; JAX ``timings`` of ``compute_shadows`` against the kernels' own), clustered_ptsv
(JAX against the faithful 32-lane and the fast warp-per-thread kernel forms), and the
sun-disk bitmask rasterizer on one fragment per pixel with ``triangles`` random
triangles each. Every case runs once cold (compilation, reported apart) and then
``repeats`` times; medians are reported. Results (and whether the two agreed) are
saved as JSON. Warp's CPU backend runs a launch on one core, one thread after the
other; XLA spreads its loops over every core.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import statistics
import time
from pathlib import Path

import numpy as np


def _median(fn, repeats):
    runs = []
    out = None
    for _ in range(repeats):
        t0 = time.perf_counter()
        out = fn()
        runs.append(time.perf_counter() - t0)
    return statistics.median(runs), runs, out


def bench_psv(size: int, repeats: int, scene_name: str = "gate", params=None) -> dict:
    import shadowlab as sl
    from .. import kernels
    from ..scene.procedural import default_view

    params = params or {}
    scene = sl.load_scene(scene_name, **params)
    view = default_view(scene_name, scene, **params)
    gbuf = sl.render_gbuffer(scene, view.camera.replace(resolution=(size, size)))
    out = {"scene": scene.name, "triangles": scene.num_triangles, "size": size,
           "methods": {}}
    for m in kernels.PSV_METHODS:
        t0 = time.perf_counter()
        sl.compute_shadows(scene, gbuf, view.light, method=m)
        jax_cold = time.perf_counter() - t0
        t0 = time.perf_counter()
        kernels.compute_shadows(scene, gbuf, view.light, method=m)
        k_cold = time.perf_counter() - t0
        jr = [sl.compute_shadows(scene, gbuf, view.light, method=m) for _ in range(repeats)]
        kr = [kernels.compute_shadows(scene, gbuf, view.light, method=m)
              for _ in range(repeats)]
        same = bool(np.array_equal(jr[-1].lit, kr[-1].lit) and all(
            np.array_equal(np.asarray(v), np.asarray(jr[-1].counters[k]))
            for k, v in kr[-1].counters.items() if k != "cas_failures"))
        out["methods"][m] = {
            "jax": {s: statistics.median(r.timings.get(s, 0.0) for r in jr)
                    for s in ("build", "query", "total")},
            "kernel": {s: statistics.median(r.timings[s] for r in kr)
                       for s in ("build", "query", "total")},
            "jax_first_call_seconds": jax_cold, "kernel_first_call_seconds": k_cold,
            "visited_nodes_mean": kr[-1].counters["visited_nodes_mean"],
            "equal_lit_and_counters": same,
        }
    return out


def _agreement(j, k, truth, gbuf) -> dict:
    """How a kernel result compares with the JAX result and the reference."""
    differing = [c for c, v in k.counters.items() if c in j.counters
                 and not np.array_equal(np.asarray(v), np.asarray(j.counters[c]))]
    return {"equal_lit_and_counters": bool(np.array_equal(j.lit, k.lit) and not differing),
            "differing_counters": {c: [float(np.sum(k.counters[c])), float(np.sum(
                j.counters[c]))] for c in differing},
            "lit_pixels_differing_from_jax": int(np.count_nonzero(j.lit != k.lit)),
            "valid_pixels_differing_from_reference": int(np.count_nonzero(
                (k.lit != truth) & gbuf.valid))}


def bench_clustered(size: int, repeats: int, scene_name: str = "gate", params=None,
                    forms=("warp", "lanes"), options=None) -> dict:
    """clustered_ptsv (default options unless ``options``): JAX against the two kernel
    forms; stage medians, whether lit masks and counters agreed."""
    import shadowlab as sl
    from . import clustered_ptsv as kc
    from ..scene.procedural import default_view

    params = params or {}
    options = dict(options or {})
    scene = sl.load_scene(scene_name, **params)
    view = default_view(scene_name, scene, **params)
    gbuf = sl.render_gbuffer(scene, view.camera.replace(resolution=(size, size)))
    truth = sl.reference_shadows(scene, gbuf, view.light)
    out = {"scene": scene.name, "triangles": scene.num_triangles, "size": size,
           "options": options, "forms": {}}
    t0 = time.perf_counter()
    sl.compute_shadows(scene, gbuf, view.light, method="clustered_ptsv", **options)
    out["jax_first_call_seconds"] = time.perf_counter() - t0
    jr = [sl.compute_shadows(scene, gbuf, view.light, method="clustered_ptsv", **options)
          for _ in range(repeats)]
    stages = ("samples", "setup", "build", "traverse", "merge", "total")
    out["jax"] = {st: statistics.median(r.timings.get(st, 0.0) for r in jr) for st in stages}
    out["jax_valid_pixels_differing_from_reference"] = int(np.count_nonzero(
        (jr[-1].lit != truth) & gbuf.valid))
    for form in forms:
        t0 = time.perf_counter()
        kc.run(scene, gbuf, view.light, form=form, **options)
        cold = time.perf_counter() - t0
        kr = [kc.run(scene, gbuf, view.light, form=form, **options) for _ in range(repeats)]
        k = kr[-1]
        out["forms"][form] = {
            "kernel": {st: statistics.median(r.timings[st] for r in kr)
                       for st in ("samples", "keys", "setup", "build", "traverse", "merge",
                                  "total")},
            "kernel_first_call_seconds": cold,
            **_agreement(jr[-1], k, truth, gbuf),
            "tests": k.counters["tests"], "node_tests": k.counters["node_tests"],
        }
    return out


def bench_sun_disk(size: int, repeats: int, triangles: int = 8, grid: str = "16x16",
                   projection: str = "paper") -> dict:
    from . import sun_disk as ks

    f = size * size
    rng = np.random.default_rng(0)
    s = rng.uniform(0.05, 0.3, f).astype(np.float32)
    z = rng.uniform(0.2, 3.0, (f, triangles, 3)).astype(np.float32)
    xy = rng.uniform(-1.6, 1.6, (f, triangles, 3, 2)).astype(np.float32) * (
        s[:, None, None, None] * z[..., None])
    d = np.concatenate([xy, z[..., None]], -1)
    n = np.tile(np.float32([0, 0, 1]), (f, 1))
    kw = dict(grid=grid, projection=projection, eps=1e-3)
    t0 = time.perf_counter()
    j = ks.jax_visibility(d, s, n, **kw)
    jax_cold = time.perf_counter() - t0
    t0 = time.perf_counter()
    k = ks.visibility(d, s, n, **kw)
    k_cold = time.perf_counter() - t0
    jt, _, j = _median(lambda: ks.jax_visibility(d, s, n, **kw), repeats)
    kt, _, k = _median(lambda: ks.visibility(d, s, n, **kw), repeats)
    return {"fragments": f, "triangles_per_fragment": triangles, "grid": grid,
            "projection": projection, "jax_seconds": jt, "kernel_seconds": kt,
            "jax_first_call_seconds": jax_cold, "kernel_first_call_seconds": k_cold,
            "equal_words": bool(np.array_equal(j["words"], k["words"]))}


def main(argv=None) -> dict:
    ap = argparse.ArgumentParser(prog="python -m shadowlab.kernels.bench",
                                 description=__doc__.split("\n\n")[0])
    ap.add_argument("--sizes", type=int, nargs="+", default=[512, 1024])
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--scene", default="gate")
    ap.add_argument("--out", default="kernels_bench.json")
    ap.add_argument("--only", nargs="+", choices=("psv", "clustered", "sun_disk"),
                    default=["psv", "clustered", "sun_disk"])
    a = ap.parse_args(argv)
    from ..core.jaxcache import enable_compilation_cache
    from .runtime import init

    enable_compilation_cache()
    init()
    result = {"machine": {"cpus": os.cpu_count(), "platform": platform.platform(),
                          "load_average_at_start": list(os.getloadavg())},
              "repeats": a.repeats, "psv": [], "clustered": [], "sun_disk": []}
    for size in a.sizes:
        if "psv" in a.only:
            result["psv"].append(bench_psv(size, a.repeats, a.scene))
        if "clustered" in a.only:
            result["clustered"].append(bench_clustered(size, a.repeats, a.scene))
        if "sun_disk" in a.only:
            result["sun_disk"].append(bench_sun_disk(size, a.repeats))
        print(json.dumps({"size": size, **{k: result[k][-1] for k in a.only}}, indent=1,
                         default=str))
    result["machine"]["load_average_at_end"] = list(os.getloadavg())
    Path(a.out).write_text(json.dumps(result, indent=1))
    print(f"saved {a.out}")
    return result


if __name__ == "__main__":
    main()
