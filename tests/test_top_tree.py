"""TOP tree: parallel build == sequential build node for node, depth, distances, stats."""

import dataclasses

import numpy as np
import pytest

import shadowlab as sl
from shadowlab.methods import psv as psvm
from shadowlab.structures import top_tree as tt
from shadowlab.core.frame import precision_mode, view_samples
from shadowlab.scene.procedural import default_view


def _brute_distance(p, tri, k=60):
    u, v = np.meshgrid(np.linspace(0, 1, k), np.linspace(0, 1, k))
    m = (u + v) <= 1
    u, v = u[m], v[m]
    pts = (tri[:, None, 0] * (1 - u - v)[None, :, None] + tri[:, None, 1] * u[None, :, None]
           + tri[:, None, 2] * v[None, :, None])
    return np.linalg.norm(pts - p, axis=-1).min(axis=1)


def test_point_triangle_distance_against_sampling():
    rng = np.random.default_rng(1)
    tri = rng.normal(size=(200, 3, 3))
    p = rng.normal(size=3)
    d = tt.point_triangle_distance(p, tri)
    approx = _brute_distance(p, tri)
    assert np.all(d <= approx + 1e-12)
    assert np.all(d >= approx - 0.05 * np.linalg.norm(tri[:, 1] - tri[:, 0], axis=1).max())
    # A point right above a triangle's interior: distance is the height.
    t = np.array([[[0, 0, 0], [1, 0, 0], [0, 1, 0]]], float)
    assert tt.point_triangle_distance(np.array([0.2, 0.2, 3.0]), t)[0] == pytest.approx(3.0)
    assert tt.point_triangle_distance(np.array([2.0, 0.0, 0.0]), t)[0] == pytest.approx(1.0)


def _input(name, params, precision, order, seed=0, ulps=64):
    scene = sl.load_scene(name, **params)
    view = default_view(name, scene, **params)
    cam = view.camera.replace(resolution=(16, 16))
    gbuf = sl.render_gbuffer(scene, cam)
    samples = view_samples(gbuf, view.light)
    return scene, view, cam, samples


def _trees(name, params, precision, order, wedge="conservative", ulps=64):
    scene, view, cam, samples = _input(name, params, precision, order)
    out = []
    with precision_mode(precision) as dtype:
        for build in ("parallel", "sequential"):
            tree, _, _ = psvm.build_tree(scene, view.light, cam, samples, dtype=dtype,
                                         shadow_eps=1e-5, bias="receiver", order=order, seed=3,
                                         wedge=wedge, classify_ulps=ulps, build=build)
            out.append(tree)
    return scene, view.light, out


@pytest.mark.parametrize("dtype", [np.float32, np.float64])
def test_light_key_against_a_plain_loop(dtype):
    """Point light: the distance to the light, bit for bit the norm of the difference
    (the same squares summed in the same order); directional: -dot(towards light, p)."""
    rng = np.random.default_rng(3)
    pts = (rng.normal(size=(200, 3)) * 50 + 1e3).astype(dtype)
    for light_h in (np.array([3.0, -2.0, 40.0, 1.0]), np.array([0.3, 0.9, 0.3, 0.0])):
        got = tt.light_key(pts, light_h)
        assert got.dtype == np.float64
        if light_h[3]:
            np.testing.assert_array_equal(got, np.linalg.norm(pts - light_h[:3], axis=-1))
        for p, k in zip(pts.astype(np.float64), got):
            if light_h[3]:
                d = [p[i] - light_h[i] for i in range(3)]
                assert k == np.sqrt((d[0] * d[0] + d[1] * d[1]) + d[2] * d[2])
            else:
                assert k == pytest.approx(-sum(p[i] * light_h[i] for i in range(3)), rel=1e-12)


@pytest.mark.parametrize("name,params,order,wedge,ulps", [
    ("soup", {"count": 60}, "random", "conservative", 64),
    ("sphere_grid", {"n": 2, "triangles_per_sphere": 128}, "mesh", "vertex", 64),
    ("sphere_grid", {"n": 2, "triangles_per_sphere": 128}, "distance", "conservative", 0),
    ("gate", {"trees": 2, "leaves_per_tree": 40, "bars": 3}, "random", "off", 64),
    ("soup", {"count": 60}, "random", "signed", 64),
    ("sphere_grid", {"n": 2, "triangles_per_sphere": 128}, "mesh", "signed", 64),
])
def test_parallel_build_equals_sequential(name, params, order, wedge, ulps, precision):
    scene, light, (par, seq) = _trees(name, params, precision, order, wedge, ulps)
    assert par.count > 100
    assert par.same_as(seq) == []
    st = par.stats()
    assert st["tree_nodes"] == 4 * st["merged_triangles"]
    assert st["merged_triangles"] + st["dropped_triangles"] == par.count
    assert par.rounds >= 1 and st["tree_depth"] >= 4
    # Every merged volume is reachable exactly once from the root through child links.
    links = np.concatenate([par.pos[par.pos >= 0], par.inter[par.inter >= 0], [par.root]])
    merged = np.flatnonzero(par.status == tt.STATUS_MERGED)
    assert np.array_equal(np.sort(links), 4 * merged)


@pytest.mark.parametrize("name,params", [
    ("soup", {"count": 60}), ("sphere_grid", {"n": 2, "triangles_per_sphere": 128})])
def test_signed_wedge_bounds_every_volume_of_the_subtree(name, params, precision):
    """wedge="signed": for an edge node, plane(p) / dist(p, light) lies in [wedge_lo,
    wedge] for points p of every shadow volume in its intersection subtree (checked in
    float64 on points L + t (x - L), x on the triangle, t >= 1, found by a plain walk of
    the subtree), and the interval lies inside the symmetric bound of the same tree."""
    scene, light, (tree, _) = _trees(name, params, precision, "random", "signed")
    _, _, (sym, _) = _trees(name, params, precision, "random", "conservative")
    assert tree.same_as(sym) == ["wedge", "wedge_lo"]         # same tree, other bounds
    light_h = sl.scene.view.hard_light(light).homogeneous
    assert light_h[3] != 0
    L = light_h[:3]
    tris = scene.triangles[tree.tri[: tree.count]]
    bary = np.array([[1, 0, 0], [0, 1, 0], [0, 0, 1], [1 / 3, 1 / 3, 1 / 3], [0.5, 0.5, 0],
                     [0, 0.5, 0.5], [0.5, 0, 0.5], [0.7, 0.2, 0.1]])
    t = np.array([1.0, 1.5, 4.0, 50.0])
    checked = 0
    edges = [e for e in range(tree.plane.shape[0]) if (e & 3) != 3 and tree.inter[e] >= 0]
    for e in edges:
        todo, vols = [int(tree.inter[e])], []
        while todo:                                   # the intersection subtree's volumes
            v = todo.pop() >> 2
            vols.append(v)
            todo += [int(c) for c in (*tree.pos[4 * v: 4 * v + 4],
                                      *tree.inter[4 * v: 4 * v + 4]) if c >= 0]
        x = np.einsum("kj,vjc->vkc", bary, tris[vols])                 # [V, 8, 3]
        p = L + t[:, None, None, None] * (x[None] - L)                  # [4, V, 8, 3]
        plane = tree.plane[e].astype(np.float64)
        ratio = (p @ plane[:3] + plane[3]) / np.linalg.norm(p - L, axis=-1)
        # rounding of the stored (working-precision) bound, per end: a few ulps of it,
        # plus the float32 plane's offset error over the nearest volume's distance
        ulp = np.finfo(tree.plane.dtype).eps
        near = np.linalg.norm(tris[vols] - L, axis=-1).min()
        slack_hi = 8 * ulp * abs(tree.wedge[e]) + 8 * ulp * (1 + np.abs(plane[3]) / near)
        slack_lo = 8 * ulp * abs(tree.wedge_lo[e]) + 8 * ulp * (1 + np.abs(plane[3]) / near)
        assert ratio.max() <= tree.wedge[e] + slack_hi, e
        assert ratio.min() >= tree.wedge_lo[e] - slack_lo, e
        assert tree.wedge_lo[e] <= 0 <= tree.wedge[e]
        assert -sym.wedge[e] <= tree.wedge_lo[e] and tree.wedge[e] <= sym.wedge[e]
        checked += len(vols)
    assert len(edges) > 20 and checked > 100
    # The interval is narrower than the symmetric bound where one side is short.
    width = np.array([tree.wedge[e] - tree.wedge_lo[e] for e in edges])
    assert np.mean(width) < 0.95 * 2 * np.mean(sym.wedge[edges])
    # nodes without an intersection child hold the empty interval
    empty = (tree.inter < 0)
    assert np.all(tree.wedge[empty] == -np.inf) and np.all(tree.wedge_lo[empty] == np.inf)


def test_depth_and_ancestor_against_a_plain_loop(precision):
    scene, light, (par, _) = _trees("gate", {"trees": 2, "leaves_per_tree": 40, "bars": 3},
                                    precision, "random")
    # Re-descend every inserted triangle through the final tree with a plain loop.
    dt = par.plane.dtype.type
    light_h = sl.scene.view.hard_light(light).homogeneous
    tris = scene.triangles[par.tri[: par.count]]
    keys = tt.triangle_key(tris, light_h)
    expect = np.full(par.capacity, np.inf)
    for r in range(par.count):
        verts = tris[r].astype(dt)
        node, last, path = par.root, -1, []
        while node >= 0 and node != 4 * r:
            path.append(node >> 2)
            vals = np.array([((v[0] * par.plane[node, 0] + v[1] * par.plane[node, 1])
                              + v[2] * par.plane[node, 2]) + par.plane[node, 3] for v in verts])
            cap = (node & 3) == 3
            code = int(tt._classify(np, None, vals, cap, dt(par.margin),
                                    dt(tt_cap_extra(scene))))
            if code == 1:
                if cap:
                    assert par.status[r] == tt.STATUS_DROPPED
                    break
                node += 1
                continue
            if code == 2:
                last = node
            node = int((par.inter if code == 2 else par.pos)[node])
        if par.status[r] == tt.STATUS_MERGED:
            assert node == 4 * r
            assert par.anc[r] == last
            assert par.level[r] == len(path)
            path.append(r)
        for sv in path:
            expect[sv] = min(expect[sv], keys[r])
    merged = par.status == tt.STATUS_MERGED
    # Stored depth = exact minimum key rounded down by the margin, never above it.
    exact = expect[merged] - par.margin
    assert np.all(par.depth[merged] <= exact)
    assert np.allclose(par.depth[merged], exact, rtol=1e-5, atol=4 * par.margin + 1e-6)


def tt_cap_extra(scene):
    from shadowlab.core.frame import cap_bias
    return cap_bias(scene, 1e-5)


def test_insertion_orders():
    key = np.array([3.0, 1.0, 2.0, 1.0])
    assert list(tt.insertion_order(4, "distance", 0, key)) == [1, 3, 2, 0]
    assert list(tt.insertion_order(4, "mesh", 0)) == [0, 1, 2, 3]
    a = tt.insertion_order(50, "random", 7)
    assert np.array_equal(a, tt.insertion_order(50, "random", 7))
    assert sorted(a) == list(range(50))
    with pytest.raises(ValueError):
        tt.insertion_order(3, "bogus", 0)


def _plain_breadth_first(tree):
    """Volume ids breadth-first from the root with a queue, one node link at a time."""
    import collections
    order, queue = [], collections.deque([tree.root // 4] if tree.root >= 0 else [])
    while queue:
        v = queue.popleft()
        order.append(v)
        for node in range(4 * v, 4 * v + 4):
            for links in (tree.pos, tree.inter):
                if links[node] >= 0:
                    queue.append(int(links[node]) // 4)
    return order


@pytest.mark.parametrize("name,params", [
    ("soup", {"count": 60}),
    ("gate", {"trees": 2, "leaves_per_tree": 40, "bars": 3}),
])
def test_breadth_first_renumbering_keeps_the_tree(name, params, precision):
    """The breadth-first order equals a plain queue's, the renumbered tree has the same
    fields per volume under the new ids (links mapped), and renumbering back restores
    the tree field for field."""
    _, _, (tree, _) = _trees(name, params, precision, "random", "signed")
    assert tree.wedge_lo is not None
    vols = tt.breadth_first_volumes(tree)
    plain = _plain_breadth_first(tree)
    merged = np.flatnonzero(tree.status == tt.STATUS_MERGED)
    assert list(vols[: len(plain)]) == plain and len(plain) == len(merged) > 50
    assert sorted(vols.tolist()) == list(range(tree.capacity))
    assert list(vols[len(plain):]) == sorted(set(range(tree.capacity)) - set(plain))
    new = tree.renumbered(vols)
    new_id = np.argsort(vols)
    assert new.root == 0 and tree.root == 4 * vols[0]

    def mapped(link):
        return np.where(link >= 0, 4 * new_id[link // 4] + link % 4, -1)

    for v in range(tree.capacity):               # per volume, a plain loop
        w = new_id[v]
        for f in ("depth", "level", "status", "tri", "bound"):
            assert getattr(new, f)[w] == getattr(tree, f)[v], f
        assert new.anc[w] == mapped(tree.anc[v])
        for q in range(4):
            old, now = 4 * v + q, 4 * w + q
            assert np.array_equal(new.plane[now], tree.plane[old])
            assert new.wedge[now] == tree.wedge[old]
            assert new.wedge_lo[now] == tree.wedge_lo[old]
            assert new.pos[now] == mapped(tree.pos[old])
            assert new.inter[now] == mapped(tree.inter[old])
    assert new.stats() == tree.stats()
    back = new.renumbered(np.argsort(vols))
    assert back.same_as(tree) == [] and np.array_equal(back.bound, tree.bound)
    with pytest.raises(ValueError, match="permutation"):
        tree.renumbered(np.zeros(tree.capacity, np.int64))


def test_breadth_first_of_an_empty_tree_and_a_corrupt_one():
    _, _, (tree, _) = _trees("soup", {"count": 60}, "float32", "random")
    empty = dataclasses.replace(tree, root=-1)
    assert np.array_equal(tt.breadth_first_volumes(empty), np.arange(tree.capacity))
    assert empty.renumbered(np.arange(tree.capacity)[::-1]).root == -1
    child = int(tree.pos[tree.pos >= 0][0])
    twice = tree.inter.copy()
    twice[tree.root] = child                    # a second parent link to one volume
    with pytest.raises(RuntimeError, match="reached twice"):
        tt.breadth_first_volumes(dataclasses.replace(tree, inter=twice))
