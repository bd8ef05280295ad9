"""Frontier buckets of the traversal's first frame per scene (clustered_ptsv and ptsv).

For each scene, in this process: one call of each method (the first frame: every try of
the traversal pass is listed), then a second call (the warm frame, one try). Prints the
frontier bucket of every try (``caps``), the peak frontier and the jobs of the frame,
and the seconds of the first call and of the second. Run it with a fresh compilation
cache (``SHADOWLAB_JAX_CACHE=$(mktemp -d)``) so that first calls compile.

usage: python docs/repro/traversal_first_bucket.py RESOLUTION [SCENE[:k=v,...] ...]
  (default: every procedural scene at its default parameters), e.g.
  python docs/repro/traversal_first_bucket.py 1024 sphere_grid:n=10,triangles_per_sphere=1000
"""
import sys
import time

import shadowlab as sl
import shadowlab.engines.traversal as tv
from shadowlab.scene.procedural import GENERATORS, default_view

caps = []
_kernel = tv.pass_kernel


def _logged_kernel(*args):
    caps.append(args[4])                      # pass_kernel(tests, prune, level0, stop, cap, ...)
    return _kernel(*args)


def main(resolution: int, specs: list[str]) -> None:
    tv.pass_kernel = _logged_kernel
    for spec in specs or sorted(GENERATORS):
        name, _, rest = spec.partition(":")
        params = {k: int(v) for k, v in (kv.split("=") for kv in rest.split(",") if kv)}
        scene = sl.load_scene(name, **params)
        view = default_view(name, scene)
        gbuf = sl.render_gbuffer(scene, view.camera.replace(resolution=(resolution,) * 2))
        for method in ("clustered_ptsv", "ptsv"):
            caps.clear()
            t0 = time.perf_counter()
            r = sl.compute_shadows(scene, gbuf, view.light, method=method)
            first = time.perf_counter() - t0
            t0 = time.perf_counter()
            sl.compute_shadows(scene, gbuf, view.light, method=method)
            warm = time.perf_counter() - t0
            print(f"{spec:40s} {method:15s} caps={caps} frontier_max={r.counters['frontier_max']} "
                  f"jobs={r.counters['jobs']} first={first:.2f}s second={1e3 * warm:.0f}ms",
                  flush=True)


if __name__ == "__main__":
    main(int(sys.argv[1]), sys.argv[2:])
