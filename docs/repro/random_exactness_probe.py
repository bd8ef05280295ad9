"""Randomized exactness probe: every exact method on every procedural generator, under
random lights, near and far from the world origin, against the float64 truth.

For each generator (small parameters), each light kind and each offset magnitude, the
scene, camera and light are moved by a random offset of that magnitude; the exact
methods run with ``cull_casters="off"`` in float32 and float64 and with
``cull_casters="all"`` in float32, and every mismatch against ``reference.truth64``
that ``reference.boundary`` cannot explain is reported (the Embree reference too).

Light kinds: the generator's default light; a point light above the scene at 0.4-1.5
diagonals from its centre; a low point light inside the content box (between the
objects); a directional light from a random upper direction.

    python docs/repro/random_exactness_probe.py [--seed 1234] [--res 48]
        [--offsets 0 1e5] [--scenes props soup ...] [--methods brute_force psv ...]
        [--part 0 --parts 2]   # split the jobs over processes
        [--out probe.json]

It found the degenerate-soup orientation defect of the shared triangle setup
(docs/exactness.md): 2026-12-07, seed 1234, 48x48, offsets 0 and 1e5, 72 jobs in two
processes (``--part 0 --parts 2`` and ``--part 1 --parts 2``, about 13 minutes on 2
cores): 10 failing (method, cull, precision) runs, all on one job (`soup`, high point
light, offset 1e5, float32); after the fix 0 failing runs and 0 for the reference.
"""

from __future__ import annotations

import argparse
import json
import sys

import numpy as np

import shadowlab as sl
from shadowlab.methods import registry
from shadowlab.reference import truth64
from shadowlab.reference.boundary import unexplained_mismatches
from shadowlab.scene import procedural

SCENES = {
    "sphere_grid": {"n": 3, "triangles_per_sphere": 200},
    "gate": {"trees": 2, "leaves_per_tree": 40},
    "fuzzy": {"triangles": 2000},
    "terrain": {"size": 24},
    "blobs": {},
    "soup": {"count": 300},
    "atrium": {"bays": 2},
    "city": {"blocks": 2, "posts": 3},
    "props": {"count": 8, "triangles": 3000},
}
LIGHTS = ("default", "point_far", "point_inside", "directional")
SLOW = ("zpass", "zfail")          # the stencil baselines: per-pixel loops, left out by default


def jobs(seed: int, offsets, scenes):
    """[(scene, light kind, offset magnitude, job seed)] in a fixed order."""
    rng = np.random.default_rng(seed)
    out = []
    for name in scenes:
        for kind in LIGHTS:
            for off in offsets:
                out.append((name, kind, float(off), int(rng.integers(1 << 30))))
    return out


def frame(name: str, kind: str, magnitude: float, seed: int, res: int):
    """(scene, camera, light) of one job, moved by a random offset of ``magnitude``."""
    rng = np.random.default_rng(seed)
    params = SCENES[name]
    scene = procedural.make(name, **params)
    view = procedural.default_view(name, scene, **params)
    lo, hi = scene.vertices.min(0), scene.vertices.max(0)
    centre, diag = 0.5 * (lo + hi), float(np.linalg.norm(hi - lo))
    off = (np.zeros(3) if magnitude == 0 else
           rng.choice([-1.0, 1.0], 3) * magnitude * rng.uniform(0.3, 1.0, 3))
    moved = sl.Scene(scene.vertices + off, scene.faces, scene.object_id, scene.object_names,
                     f"{name}+offset")
    cam = view.camera.replace(eye=view.camera.eye + off, target=view.camera.target + off,
                              resolution=(res, res))
    if kind == "default":
        light = view.light
        if isinstance(light, sl.PointLight):
            light = sl.PointLight(light.position + off)
    elif kind == "point_far":
        u = rng.normal(size=3)
        u[1] = abs(u[1]) + 0.2
        light = sl.PointLight(centre + off + u / np.linalg.norm(u) * diag * rng.uniform(0.4, 1.5))
    elif kind == "point_inside":
        p = lo + (hi - lo) * rng.uniform(0.1, 0.9, 3)
        p[1] = lo[1] + (hi[1] - lo[1]) * rng.uniform(0.05, 0.4)
        light = sl.PointLight(p + off)
    else:
        u = rng.normal(size=3)
        u[1] = abs(u[1]) + 0.1
        light = sl.DirectionalLight(-u / np.linalg.norm(u))
    return moved, cam, light


def run_job(job, res: int, methods) -> dict:
    name, kind, magnitude, seed = job
    scene, cam, light = frame(name, kind, magnitude, seed, res)
    gbuf = sl.render_gbuffer(scene, cam)
    truth = truth64.gbuffer_shadows(scene, gbuf, light)
    ref = sl.reference_shadows(scene, gbuf, light)
    row = {"scene": name, "light": kind, "offset": magnitude, "seed": seed,
           "valid": int(gbuf.valid.sum()), "lit": int(truth.sum()),
           "reference": len(unexplained_mismatches(scene, gbuf, light, ref, truth)),
           "failures": failing_runs(scene, gbuf, light, truth, methods)}
    return row


def failing_runs(scene, gbuf, light, truth, methods) -> list[dict]:
    """Each method with ``cull_casters`` off (float32 and float64) and ``all``
    (float32): the runs with mismatches against ``truth`` that ``reference.boundary``
    cannot explain, or that raised (a crash is a finding too)."""
    out = []
    for m in methods:
        for cull, precision in (("off", "float32"), ("off", "float64"), ("all", "float32")):
            run = {"method": m, "cull": cull, "precision": precision}
            try:
                lit = np.asarray(sl.compute_shadows(scene, gbuf, light, method=m,
                                                    precision=precision,
                                                    cull_casters=cull).lit)
                n = len(unexplained_mismatches(scene, gbuf, light, lit, truth))
                if n:
                    out.append(dict(run, unexplained=n, mismatches=int((lit != truth).sum())))
            except Exception as exc:
                out.append(dict(run, error=f"{type(exc).__name__}: {exc}"[:300]))
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--seed", type=int, default=1234)
    ap.add_argument("--res", type=int, default=48)
    ap.add_argument("--offsets", type=float, nargs="+", default=[0.0, 1e5])
    ap.add_argument("--scenes", nargs="+", default=list(SCENES), choices=list(SCENES))
    ap.add_argument("--methods", nargs="+", default=None)
    ap.add_argument("--part", type=int, default=0)
    ap.add_argument("--parts", type=int, default=1)
    ap.add_argument("--out", default=None)
    a = ap.parse_args(argv)
    methods = probe_methods(a.methods)
    rows = []
    for job in jobs(a.seed, a.offsets, a.scenes)[a.part::a.parts]:
        row = run_job(job, a.res, methods)
        rows.append(row)
        report(row, f"{row['scene']:12s} {row['light']:13s} offset {row['offset']:g}: "
                    f"valid {row['valid']}")
    return finish(rows, a.out)


def probe_methods(requested: list[str] | None) -> list[str]:
    """The methods a probe runs: those requested, else every exact one but ``SLOW``."""
    return requested or [n for n in registry.names()
                         if registry.get(n).exact and n not in SLOW]


def report(row: dict, head: str) -> None:
    """Print a job's line (``head``, then its reference mismatches and failing runs,
    flagged when either is nonzero) and one line per failing run."""
    flag = "" if not row["failures"] and not row["reference"] else "  <-- FAIL"
    print(f"{head}, reference {row['reference']}, failing runs {len(row['failures'])}"
          f"{flag}", flush=True)
    for f in row["failures"]:
        print("    ", f, flush=True)


def finish(rows: list[dict], out: str | None) -> int:
    """Write the rows to ``out`` (JSON; None: nowhere); the exit status: 1 if any run
    failed or the Embree reference had unexplained mismatches, else 0."""
    if out:
        with open(out, "w") as fh:
            json.dump(rows, fh, indent=1)
    return int(any(r["failures"] or r["reference"] for r in rows))


if __name__ == "__main__":
    sys.exit(main())
