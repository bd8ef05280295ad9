"""The worked examples of Mora et al. 2016 on a small constructed TOP tree.

Fig. 3: a point closer to the light than every occluder is lit; PSV has to walk down
the tree to prove it, the depth test stops at the root volume. Fig. 4: the stackless
query answers like the stack query by jumping back along ancestor links; the hybrid
query with a full short stack switches to it and otherwise visits exactly the nodes
of D-PSV. Every answer is checked against a plain segment-triangle loop.
"""

import numpy as np
import pytest

from shadowlab.core.frame import Samples, precision_mode
from shadowlab.methods import psv as psvm
from shadowlab.scene.mesh import Scene
from shadowlab.scene.view import Camera, PointLight
from shadowlab.structures import top_tree as tt

LIGHT = PointLight((0.0, 10.0, 0.0))


def _occluders(n=24, seed=1):
    """n small, nearly horizontal triangles scattered in a slab below the light."""
    rng = np.random.default_rng(seed)
    c = np.stack([rng.uniform(-3, 3, n), rng.uniform(-5, 0, n), rng.uniform(-3, 3, n)], 1)
    tri = c[:, None, :] + rng.uniform(-0.8, 0.8, (n, 3, 3)) * np.array([1.0, 0.1, 1.0])
    return Scene(tri.reshape(-1, 3), np.arange(3 * n, dtype=np.int32).reshape(n, 3),
                 np.zeros(n, np.int32))


def _blocked(tri, p, light):
    """bool [P]: the open segment p -> light crosses a triangle (Moller-Trumbore)."""
    out = np.zeros(len(p), bool)
    for a, b, c in tri:
        e1, e2 = b - a, c - a
        d = light - p                                    # [P, 3], t in (0, 1)
        h = np.cross(d, e2)
        det = h @ e1
        ok = np.abs(det) > 1e-12
        inv = np.where(ok, 1.0 / np.where(ok, det, 1.0), 0.0)
        s = p - a
        u = np.einsum("ij,ij->i", s, h) * inv
        q = np.cross(s, e1)
        v = np.einsum("ij,ij->i", d, q) * inv
        t = (q @ e2) * inv
        out |= ok & (u >= 0) & (v >= 0) & (u + v <= 1) & (t > 1e-9) & (t < 1 - 1e-9)
    return out


def _queries(scene, pts, **kinds):
    light_h = LIGHT.homogeneous
    samples = Samples(np.arange(len(pts)), pts, np.tile([0.0, 1.0, 0.0], (len(pts), 1)),
                      (1, len(pts)))
    cam = Camera((0, 0, 20), (0, 0, 0), (0, 1, 0), 50.0, 0.1, 100.0, (len(pts), 1))
    with precision_mode("float32") as dt:
        tree, scale, _ = psvm.build_tree(scene, LIGHT, cam, samples, dtype=dt, shadow_eps=1e-5,
                                         bias="receiver", order="random", seed=0,
                                         wedge="conservative", classify_ulps=64)
        key = tt.light_key(pts, light_h).astype(dt)
        return tree, {name: psvm.run_query(tree, pts.astype(dt), scale.astype(dt), key, light_h,
                                           query=q, depth_test=d, wedge="conservative",
                                           stack_size=k)
                      for name, (q, d, k) in kinds.items()}


def test_fig3_point_in_front():
    scene = _occluders()
    rng = np.random.default_rng(2)
    pts = np.stack([rng.uniform(-1, 1, 16), rng.uniform(1.0, 4.0, 16),
                    rng.uniform(-1, 1, 16)], 1)         # above every occluder
    tree, r = _queries(scene, pts, psv=("stack", False, 32), d_psv=("stack", True, 32))
    assert tree.stats()["merged_triangles"] == scene.num_triangles
    assert not _blocked(scene.triangles, pts, np.asarray(LIGHT.position)).any()
    for q in r.values():
        assert not q["shadow"].any()
    # The depth test stops at the root volume: its subtree holds every occluder, all
    # farther from the light than the point. PSV descends anyway.
    assert np.all(r["d_psv"]["visited"] == 1), r["d_psv"]["visited"]
    assert np.all(r["psv"]["visited"] >= 1) and r["psv"]["visited"].mean() > 3


@pytest.mark.parametrize("seed", [1, 5])
def test_fig4_stackless_path(seed):
    scene = _occluders(seed=seed)
    rng = np.random.default_rng(seed + 10)
    pts = np.stack([rng.uniform(-3, 3, 200), rng.uniform(-6, 2, 200),
                    rng.uniform(-3, 3, 200)], 1)
    truth = _blocked(scene.triangles, pts, np.asarray(LIGHT.position))
    tree, r = _queries(scene, pts, stack=("stack", False, 32), d_psv=("stack", True, 32),
                       stackless=("stackless", False, 0), d_stackless=("stackless", True, 0),
                       hybrid=("hybrid", True, 1))
    assert tree.stats()["intersection_triangles"] > 0      # ancestor links are exercised
    assert truth.any() and (~truth).any()
    for name, q in r.items():
        assert np.array_equal(q["shadow"], truth), name
        assert np.all(q["overflows"] == 0), name
    hyb, dps = r["hybrid"], r["d_psv"]
    assert hyb["switches"].sum() > 0                        # a one-entry stack fills
    same = hyb["switches"] == 0
    assert same.any()
    np.testing.assert_array_equal(hyb["visited"][same], dps["visited"][same])
    # the depth test never adds visits, with or without a stack
    assert np.all(dps["visited"] <= r["stack"]["visited"])
    assert np.all(r["d_stackless"]["visited"] <= r["stackless"]["visited"])


def test_sec4_1_node_memory():
    """Sec. 3.6 / 4.1: four nodes of 32 bytes per triangle, depth and ancestor links at
    no extra memory. Here: 4 nodes per merged triangle, each one 32-byte row (float32:
    plane a, b, c, d, wedge, extra, pos, inter); the depth sits in the otherwise unused
    ``extra`` slot of a volume's first node (no memory), the ancestor link is one int32
    per volume (4 bytes per triangle, 1 per node: the paper packs it into unused bits)."""
    scene = _occluders()
    pts = np.zeros((4, 3))
    tree, _ = _queries(scene, pts)
    merged = tree.stats()["merged_triangles"]
    assert merged == scene.num_triangles and tree.stats()["tree_nodes"] == 4 * merged
    volumes = tree.plane.shape[0] // 4          # the arrays' capacity (a static bucket)
    assert tree.plane.shape[0] == 4 * volumes and volumes >= merged
    rows, anc = psvm.node_arrays(tree, rows=True)
    assert rows.shape == (4 * volumes, 8) and rows.dtype == np.float32
    assert rows.nbytes == 32 * rows.shape[0]                           # 32 bytes per node
    np.testing.assert_array_equal(rows[0::4, 5], tree.depth)          # depth: no extra array
    assert anc.shape == (volumes,) and anc.dtype.itemsize == 4         # +4 bytes per volume
