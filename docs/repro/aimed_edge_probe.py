"""Exactness probe for ill-conditioned edge planes: triangles with an edge aimed at the
light.

An edge plane's normal is ``(b - a) x (L - a)``. When the edge a-b points (almost) at a
point light L, or runs (almost) parallel to a directional light, the two factors are
nearly parallel and the normal is a small difference of large products, so its direction
carries a relative error of about ulp / delta (delta: the angle between the edge and the
direction to the light). This probe builds such triangles on purpose and checks every
exact method against the float64 truth.

Scene: a 20 x 20 ground quad and ``--triangles`` random triangles 0.5-5 units above it.
Each has an edge a-b whose direction is the direction from the light to a (either
sense), turned by an angle delta, log-uniform in [1e-8, 1e-2], and exactly 0 for a fifth
of them (the light then lies in the triangle's plane); its third corner lies 5-100 % of
the edge's length off the edge, in a random direction. Lights: a point light 8-14 units
above the middle, and a directional light from a random upper direction. Each job runs
at offset 0 and at a random offset of magnitude 1e5. Methods: every exact method except
the stencil baselines, with ``cull_casters`` off (float32 and float64) and ``all``
(float32); mismatches against ``reference.truth64`` that ``reference.boundary`` cannot
explain are failures (the Embree reference is checked too).

    python docs/repro/aimed_edge_probe.py [--seeds 0 8] [--res 64] [--triangles 150]
        [--out probe.json]

Results are in docs/exactness.md ("Edges aimed at the light").
"""

from __future__ import annotations

import argparse
import sys

import jax.numpy as jnp
import numpy as np

import shadowlab as sl
from random_exactness_probe import (failing_runs, finish, probe_methods,  # this folder
                                    report)
from shadowlab.geometry.triangle_setup import shadow_volume_planes
from shadowlab.reference import truth64
from shadowlab.reference.boundary import unexplained_mismatches
from shadowlab.scene.view import hard_light

OFFSETS = (0.0, 1e5)


def _unit(x):
    return x / np.linalg.norm(x, axis=-1, keepdims=True)


def _across(u, rng):
    """Random unit vectors [N, 3] perpendicular to the unit rows of u [N, 3]."""
    r = rng.normal(size=u.shape)
    r -= (r * u).sum(-1, keepdims=True) * u
    return _unit(r)


def aimed_scene(seed: int, kind: str, triangles: int):
    """(vertices [V, 3], faces [F, 3], object ids [F], light, deltas [triangles]) at the
    world origin; ``kind`` "point" or "directional"."""
    rng = np.random.default_rng(seed)
    size = 10.0
    ground_v = np.array([[-size, 0, -size], [size, 0, -size], [size, 0, size],
                         [-size, 0, size]])
    ground_f = np.array([[0, 2, 1], [0, 3, 2]])
    centre = np.array([rng.uniform(-3, 3), rng.uniform(8, 14), rng.uniform(-3, 3)])
    towards = _unit(np.array([rng.uniform(-0.5, 0.5), 1.0, rng.uniform(-0.5, 0.5)]))
    a = np.column_stack([rng.uniform(-6, 6, triangles), rng.uniform(0.5, 5, triangles),
                         rng.uniform(-6, 6, triangles)])
    u = _unit(a - centre) if kind == "point" else np.repeat(-towards[None], triangles, 0)
    u *= rng.choice([-1.0, 1.0], (triangles, 1))
    delta = 10 ** rng.uniform(-8, -2, triangles)
    delta[rng.random(triangles) < 0.2] = 0.0
    u = _unit(u + delta[:, None] * _across(u, rng))
    length = rng.uniform(0.3, 2.0, triangles)
    b = a + length[:, None] * u
    c = (a + rng.uniform(0, 1, (triangles, 1)) * length[:, None] * u
         + (length * rng.uniform(0.05, 1.0, triangles))[:, None] * _across(u, rng))
    verts = np.concatenate([ground_v, np.stack([a, b, c], 1).reshape(-1, 3)])
    faces = np.concatenate([ground_f, 4 + np.arange(3 * triangles).reshape(-1, 3)])
    ids = np.concatenate([[0, 0], 1 + np.arange(triangles)])
    light = sl.PointLight(centre) if kind == "point" else sl.DirectionalLight(-towards)
    return verts, faces, ids, light, delta


def kept_in_float32(verts, faces, light, delta, lo=1e-6, hi=1e-4) -> tuple[int, int]:
    """(kept, of): how many aimed triangles with delta in [lo, hi) the float32 triangle
    setup keeps (valid volumes built from ill-conditioned edge planes), and how many
    there are (the scene at the world origin, its ground quad first)."""
    tri = jnp.asarray(verts[faces[2:]], jnp.float32)
    _, valid = shadow_volume_planes(tri, jnp.asarray(hard_light(light).homogeneous,
                                                     jnp.float32))
    sel = (delta >= lo) & (delta < hi)
    return int(np.asarray(valid)[sel].sum()), int(sel.sum())


def run_job(seed: int, kind: str, offset: float, res: int, triangles: int, methods) -> dict:
    verts, faces, ids, light, delta = aimed_scene(seed, kind, triangles)
    kept, of = kept_in_float32(verts, faces, light, delta)
    rng = np.random.default_rng(seed + 7)
    off = (np.zeros(3) if offset == 0 else
           rng.choice([-1.0, 1.0], 3) * offset * rng.uniform(0.3, 1.0, 3))
    scene = sl.Scene(verts + off, faces, ids, tuple(f"o{i}" for i in range(ids.max() + 1)),
                     "aimed_edges")
    if kind == "point":
        light = sl.PointLight(light.position + off)
    cam = sl.Camera(eye=off + (0.0, 16.0, 14.0), target=off, fov_y_deg=55, near=0.5,
                    far=100.0, resolution=(res, res))
    gbuf = sl.render_gbuffer(scene, cam)
    truth = truth64.gbuffer_shadows(scene, gbuf, light)
    ref = sl.reference_shadows(scene, gbuf, light)
    row = {"seed": seed, "light": kind, "offset": offset, "valid": int(gbuf.valid.sum()),
           "ill_conditioned_kept_f32": [kept, of],
           "shadowed": int((~truth & gbuf.valid).sum()),
           "reference": len(unexplained_mismatches(scene, gbuf, light, ref, truth)),
           "failures": failing_runs(scene, gbuf, light, truth, methods)}
    return row


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--seeds", type=int, nargs=2, default=[0, 8], metavar=("FIRST", "END"))
    ap.add_argument("--res", type=int, default=64)
    ap.add_argument("--triangles", type=int, default=150)
    ap.add_argument("--methods", nargs="+", default=None)
    ap.add_argument("--out", default=None)
    a = ap.parse_args(argv)
    methods = probe_methods(a.methods)
    rows = []
    for seed in range(*a.seeds):
        for kind in ("point", "directional"):
            for offset in OFFSETS:
                row = run_job(seed, kind, offset, a.res, a.triangles, methods)
                rows.append(row)
                report(row, f"seed {seed} {kind:11s} offset {offset:g}: valid "
                            f"{row['valid']}, shadowed {row['shadowed']}")
    kept = np.array([r["ill_conditioned_kept_f32"] for r in rows
                     if r["offset"] == OFFSETS[0]]).sum(0)
    print(f"aimed triangles with delta in [1e-6, 1e-4) kept by the float32 setup: "
          f"{kept[0]} of {kept[1]}")
    return finish(rows, a.out)


if __name__ == "__main__":
    sys.exit(main())
