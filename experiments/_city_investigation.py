"""Why does clustered_ptsv need more test-and-sets than ptsv on a city scene?

Not an experiment (the leading underscore keeps it out of ``shadowlab figures``; the
experiment ``clustered_city`` measures the claim on the registered ``city`` scene): an
investigation script, run from the repository root::

    PYTHONPATH=. python experiments/_city_investigation.py [RESOLUTION]

A city built inline (the repository's own ``city`` generator may differ): 64 closed
boxes on a closed ground slab, a wall of thin closed posts between the camera and the
city, a point light high above; default 128 x 128. For each configuration it prints
test-and-sets, leaf visits, tests per leaf visit, and the tests split into pixels of
PTSV's 8 x 4 tiles that span a depth discontinuity (max / min depth > 2) and the rest,
so that the four candidate causes can be told apart:

- the baseline's sample set: PTSV built over light-facing samples (``tree_samples``
  "facing") against the 2011 full depth buffer ("all");
- the leaf test: every sample of the 8 x 8 tile ("tile", the paper) against only the
  samples of the cluster ("cluster");
- key quantisation: automatic z bits against 2 more and 3 fewer;
- tree quality: implicit against explicit bounds (node tests, leaf visits).
"""

from __future__ import annotations

import sys

import numpy as np

import shadowlab as sl
from shadowlab.analysis.metrics import discontinuity_mask
from shadowlab.scene import primitives as prim
from shadowlab.scene.mesh import Scene
from shadowlab.scene.procedural import framed_view
from shadowlab.scene.view import PointLight


def city(blocks: int = 8, posts: int = 40, size: float = 40.0, seed: int = 0) -> Scene:
    """Ground slab, blocks x blocks closed boxes, a wall of thin posts at the front."""
    rng = np.random.default_rng(seed)
    half, cell = size / 2, size / blocks
    ij = np.stack(np.meshgrid(np.arange(blocks), np.arange(blocks), indexing="ij"), -1)
    ij = ij.reshape(-1, 2).astype(float)
    lo = np.stack([-half + cell * (ij[:, 0] + 0.2), np.zeros(len(ij)),
                   -half + cell * (ij[:, 1] + 0.2)], 1)
    hi = lo + np.stack([np.full(len(ij), 0.6 * cell), cell * rng.uniform(0.3, 1.5, len(ij)),
                        np.full(len(ij), 0.6 * cell)], 1)
    t = size / 300
    px = np.linspace(-0.45 * size, 0.45 * size, posts)
    plo = np.stack([px, np.zeros(posts), np.full(posts, 0.62 * size)], 1)
    phi = plo + [t, 0.25 * size, t]
    meshes = [prim.box((-half - 0.2 * size, -size / 40, -half), (half + 0.2 * size, 0.0,
                                                                  0.75 * size)),
              prim.boxes(lo, hi), prim.boxes(plo, phi)]
    v, f = prim.merge(meshes)
    counts = [len(m[1]) for m in meshes]
    oid = np.concatenate([np.zeros(counts[0], int), 1 + np.repeat(np.arange(len(lo)), 12),
                          1 + len(lo) + np.repeat(np.arange(posts), 12)])
    names = ("ground", *(f"building{i}" for i in range(len(lo))),
             *(f"post{i}" for i in range(posts)))
    return Scene(v, np.asarray(f, np.int32), oid.astype(np.int32), names, "city_inline")


CONFIGS = [
    ("ptsv", "ptsv", {}),
    ("ptsv 2011 build", "ptsv", {"tree_samples": "all"}),
    ("clustered", "clustered_ptsv", {}),
    ("clustered leaf=cluster", "clustered_ptsv", {"leaf_samples": "cluster"}),
    ("clustered z+2", "clustered_ptsv", {"z_bits": -2}),
    ("clustered z-3", "clustered_ptsv", {"z_bits": -3}),
    ("clustered leaf=cluster z+2", "clustered_ptsv", {"leaf_samples": "cluster",
                                                      "z_bits": -2}),
    ("clustered implicit", "clustered_ptsv", {"bounds": "implicit"}),
    ("clustered ffc facing", "clustered_ptsv", {"front_face_culling": True,
                                                "cull_side": "facing"}),
    ("ptsv ffc facing", "ptsv", {"front_face_culling": True, "cull_side": "facing"}),
]


def main(res: int = 128) -> None:
    from shadowlab.structures.cluster_hierarchy import cluster_layout

    scene = city()
    size = 40.0
    view = framed_view(scene, (0.3 * size, 0.45 * size, 1.05 * size), (0.0, 0.0, 0.0),
                       PointLight((0.15 * size, 2.0 * size, 0.1 * size)),
                       resolution=(res, res))
    gbuf = sl.render_gbuffer(scene, view.camera)
    truth = sl.reference_shadows(scene, gbuf, view.light)
    steep = discontinuity_mask(gbuf)
    auto = cluster_layout(view.camera).bits[2]
    print(f"{scene.num_triangles} triangles, {res}x{res}, {int(gbuf.valid.sum())} valid, "
          f"{int(steep.sum())} at discontinuities; auto z bits {auto}")
    print(f"{'configuration':<28} {'tests':>9} {'ratio':>6} {'leafvis':>8} {'t/leaf':>7} "
          f"{'nodetests':>10} {'at disc.':>9} {'elsewhere':>9} {'mism':>5} {'clus/tile':>9}")
    h, w = gbuf.shape
    occ = np.zeros((-(-h // 8), -(-w // 8)), bool)
    yy, xx = np.nonzero(gbuf.valid)
    occ[yy // 8, xx // 8] = True
    base = None
    for label, method, opts in CONFIGS:
        opts = dict(opts)
        if opts.get("z_bits", 0) < 0:
            opts["z_bits"] = auto + (2 if opts["z_bits"] == -2 else -3)
        r = sl.compute_shadows(scene, gbuf, view.light, method=method, **opts)
        c = r.counters
        tp = c["tests_per_pixel"]
        base = base or c["tests"]
        mism = int(np.count_nonzero((r.lit != truth) & gbuf.valid))
        print(f"{label:<28} {c['tests']:>9} {c['tests'] / base:>6.2f} {c['leaf_visits']:>8} "
              f"{c['tests'] / max(c['leaf_visits'], 1):>7.1f} {c['node_tests']:>10} "
              f"{tp[steep].sum():>9} {tp[gbuf.valid & ~steep].sum():>9} {mism:>5} "
              f"{c['clusters'] / occ.sum() if method == 'clustered_ptsv' else 0:>9.2f}")


if __name__ == "__main__":
    main(int(sys.argv[1]) if len(sys.argv) > 1 else 128)
