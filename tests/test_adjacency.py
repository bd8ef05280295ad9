"""Edge adjacency (shadowlab.scene.adjacency) against a plain dict-based loop."""

import numpy as np
import pytest
import trimesh
from hypothesis import given, settings, strategies as st

from shadowlab.scene import Scene, make
from shadowlab.scene.adjacency import Adjacency, AdjacencyReport, build_adjacency


def reference(scene, scope="object", k=2, dtype=np.float64):
    """One Python loop over the triangles, with dicts; returns the same content as
    Adjacency: welded faces, kept, and {edge: [(triangle, opposite, sign), ...]}."""
    v = scene.vertices.astype(dtype)
    faces = scene.faces.tolist()
    oid = scene.object_id.tolist()

    def key(t, i):
        x, y, z = (float(c) + 0.0 for c in v[i])  # + 0.0: -0.0 becomes 0.0
        return (oid[t], x, y, z) if scope == "object" else (x, y, z)

    keys = sorted({key(t, i) for t, f in enumerate(faces) for i in f})
    index = {kk: n for n, kk in enumerate(keys)}
    welded = [[index[key(t, i)] for i in f] for t, f in enumerate(faces)]
    pos = [kk[-3:] for kk in keys]
    kept, edges = [], {}
    for t, (a, b, c) in enumerate(welded):
        pa, pb, pc = pos[a], pos[b], pos[c]
        u = [pb[j] - pa[j] for j in range(3)]
        w = [pc[j] - pa[j] for j in range(3)]
        cross = (u[1] * w[2] - u[2] * w[1], u[2] * w[0] - u[0] * w[2], u[0] * w[1] - u[1] * w[0])
        ok = len({a, b, c}) == 3 and any(x != 0 for x in cross)
        kept.append(ok)
        if not ok:
            continue
        for p, q, o in ((a, b, c), (b, c, a), (c, a, b)):
            edges.setdefault((min(p, q), max(p, q)), []).append((t, o, 1 if p < q else -1))
    records = []
    for e in sorted(edges):
        lst = edges[e]
        for s in range(0, len(lst), k):
            records.append((e, lst[s:s + k]))
    return dict(welded=welded, pos=pos, kept=kept, edges=edges, records=records)


def classify(entries):
    if len(entries) == 1:
        return "open"
    if len(entries) == 2 and entries[0][2] != entries[1][2]:
        return "manifold"
    return "nonmanifold"


def check_against_reference(scene, scope="object", k=2, dtype=np.float64):
    adj = build_adjacency(scene, scope, k, dtype)
    ref = reference(scene, scope, k, dtype)
    assert adj.faces.tolist() == ref["welded"]
    assert adj.positions.dtype == np.dtype(dtype)
    assert [tuple(map(float, p)) for p in adj.positions] == ref["pos"]
    assert adj.kept.tolist() == ref["kept"]
    assert [tuple(e) for e in adj.edge_vertices.tolist()] == sorted(ref["edges"])
    assert adj.edge_count.tolist() == [len(ref["edges"][e]) for e in sorted(ref["edges"])]
    for e, (lo, hi) in enumerate(adj.edge_vertices.tolist()):
        s, t = adj.edge_offsets[e], adj.edge_offsets[e + 1]
        got = list(zip(adj.entry_triangle[s:t].tolist(), adj.entry_opposite[s:t].tolist(),
                       adj.entry_sign[s:t].tolist()))
        assert got == ref["edges"][(lo, hi)]
    assert len(adj.record_edge) == len(ref["records"])
    assert adj.triangle.shape == adj.opposite.shape == adj.sign.shape == (len(ref["records"]), k)
    for r, (e, slots) in enumerate(ref["records"]):
        assert tuple(adj.record_vertices[r].tolist()) == e
        n = len(slots)
        assert adj.triangle[r, :n].tolist() == [x[0] for x in slots]
        assert adj.opposite[r, :n].tolist() == [x[1] for x in slots]
        assert adj.sign[r, :n].tolist() == [x[2] for x in slots]
        assert (adj.triangle[r, n:] == -1).all() and (adj.opposite[r, n:] == -1).all()
        assert (adj.sign[r, n:] == 0).all()
    for e in range(len(adj.edge_count)):
        recs = range(adj.edge_first_record[e], adj.edge_first_record[e + 1])
        assert all(adj.record_edge[r] == e for r in recs)
    kinds = [classify(ref["edges"][e]) for e in sorted(ref["edges"])]
    rep = adj.report
    assert rep.edges == len(ref["edges"]) and rep.records == len(ref["records"])
    assert rep.open_edges == kinds.count("open")
    assert rep.manifold_edges == kinds.count("manifold")
    assert rep.nonmanifold_edges == kinds.count("nonmanifold")
    assert rep.split_edges == sum(len(x) > k for x in ref["edges"].values())
    assert rep.degenerate_triangles == ref["kept"].count(False)
    assert rep.vertices == len(ref["pos"]) and rep.triangles == scene.num_triangles
    assert adj.edge_class.tolist() == [{"open": 1, "manifold": 2, "nonmanifold": 3}[x]
                                       for x in kinds]
    return adj


def soup(v, f, oid=None):
    f = np.asarray(f)
    return Scene(np.asarray(v, float), f, np.zeros(len(f)) if oid is None else oid)


def test_cube_12_triangles_18_manifold_edges():
    box = trimesh.creation.box(extents=(1, 2, 3))
    for scene in (soup(box.vertices, box.faces),
                  # the same cube as an unindexed soup: welding restores the sharing
                  soup(box.vertices[box.faces].reshape(-1, 3), np.arange(36).reshape(12, 3))):
        adj = check_against_reference(scene)
        rep = adj.report
        assert (rep.triangles, rep.vertices, rep.edges, rep.records) == (12, 8, 18, 18)
        assert rep.manifold_edges == 18 and rep.open_edges == rep.nonmanifold_edges == 0
        assert rep.degenerate_triangles == rep.split_edges == 0


def test_closed_icosphere_has_3f_over_2_manifold_edges():
    ico = trimesh.creation.icosphere(subdivisions=2)
    adj = check_against_reference(soup(ico.vertices, ico.faces))
    f = len(ico.faces)
    assert adj.report.edges == 3 * f // 2 == adj.report.manifold_edges
    # every manifold edge: two slots with opposite windings in its single record
    assert (adj.sign.sum(axis=1) == 0).all() and (adj.sign != 0).all()


def test_open_quad():
    adj = check_against_reference(soup([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0]],
                                       [[0, 1, 2], [0, 2, 3]]))
    assert (adj.report.edges, adj.report.open_edges, adj.report.manifold_edges) == (5, 4, 1)


def test_book_of_three_triangles_splits_into_two_records():
    v = [[0, 0, 0], [0, 0, 1], [1, 0, 0], [0, 1, 0], [-1, -1, 0]]
    f = [[0, 1, 2], [1, 0, 3], [0, 1, 4]]
    adj = check_against_reference(soup(v, f), k=2)
    rep = adj.report
    assert rep.nonmanifold_edges == 1 and rep.split_edges == 1
    assert rep.edges == 7 and rep.records == 8 and rep.open_edges == 6
    spine = np.flatnonzero(adj.edge_count == 3)[0]
    recs = np.flatnonzero(adj.record_edge == spine)
    assert len(recs) == 2
    assert adj.triangle[recs].tolist() == [[0, 1], [2, -1]]
    # welded (0,0,0) < (0,0,1): triangle 0 goes 0 -> 1 (+1), 1 goes 1 -> 0 (-1), 2: +1
    assert adj.sign[recs].tolist() == [[1, -1], [1, 0]]
    assert len(check_against_reference(soup(v, f), k=3).record_edge) == 7


def test_t_junction_edges_stay_open():
    # upper triangle's edge (0,0)-(2,0) meets two lower edges split at (1,0)
    v = [[0, 0, 0], [2, 0, 0], [1, 1, 0], [1, 0, 0], [0, -1, 0], [2, -1, 0]]
    f = [[0, 1, 2], [0, 4, 3], [3, 5, 1], [3, 4, 5]]
    adj = check_against_reference(soup(v, f))
    w = {tuple(map(float, p)): i for i, p in enumerate(adj.positions)}
    edges = [tuple(e) for e in adj.edge_vertices.tolist()]
    for a, b in (((0, 0), (2, 0)), ((0, 0), (1, 0)), ((1, 0), (2, 0))):
        e = tuple(sorted((w[(*map(float, a), 0.0)], w[(*map(float, b), 0.0)])))
        assert adj.edge_count[edges.index(e)] == 1  # the three collinear edges stay open
    assert (adj.report.edges, adj.report.open_edges, adj.report.manifold_edges) == (10, 8, 2)


def test_duplicate_coincident_triangles_and_opposite_windings():
    v = [[0, 0, 0], [1, 0, 0], [0, 1, 0]]
    same = check_against_reference(soup(v, [[0, 1, 2], [1, 2, 0]]))
    assert same.report.nonmanifold_edges == 3 and same.report.manifold_edges == 0
    flipped = check_against_reference(soup(v, [[0, 1, 2], [0, 2, 1]]))
    assert flipped.report.manifold_edges == 3 and flipped.report.nonmanifold_edges == 0


def test_degenerate_triangles_are_skipped():
    v = [[0, 0, 0], [1, 0, 0], [0, 1, 0], [2, 0, 0], [1, 0, 0]]
    # repeated welded vertex (indices 1 and 4 coincide), a zero-area collinear triangle
    adj = check_against_reference(soup(v, [[0, 1, 2], [1, 4, 2], [0, 1, 3]]))
    assert adj.kept.tolist() == [True, False, False]
    assert adj.report.degenerate_triangles == 2 and adj.report.edges == 3


def test_minus_zero_welds_with_zero_and_float32_welds_more():
    v = [[0, 0, 0], [1, 0, 0], [0, 1, 0], [-0.0, -0.0, 0], [0, -1, 0],
         [1 + 1e-12, 0, 0]]
    f = [[0, 1, 2], [3, 4, 5]]
    a64 = check_against_reference(soup(v, f), dtype=np.float64)
    assert a64.report.vertices == 5 and a64.report.manifold_edges == 0
    a32 = check_against_reference(soup(v, f), dtype=np.float32)
    assert a32.report.vertices == 4 and a32.report.manifold_edges == 1


def test_scope_object_keeps_objects_apart():
    v = [[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0]]
    scene = soup(v, [[0, 1, 2], [0, 2, 3]], oid=np.array([0, 1]))
    obj = check_against_reference(scene, scope="object")
    assert obj.report.open_edges == 6 and obj.report.vertices == 6
    assert sorted(obj.vertex_object.tolist()) == [0, 0, 0, 1, 1, 1]
    whole = check_against_reference(scene, scope="scene")
    assert whole.report.manifold_edges == 1 and whole.report.vertices == 4
    assert (whole.vertex_object == -1).all()


# Small random soups: few distinct positions (so welding, repeats, zero-area and
# non-manifold edges are common), random objects, every parameter.
# x, y on a small grid (collinear triples are frequent), z in two planes of which one
# is off 1.0 by 2^-30 (merged in float32 only).
xy = st.sampled_from([0.0, -0.0, 1.0, 2.0])
zs = st.sampled_from([0.0, 1.0, 1.0 + 2.0 ** -30])


@st.composite
def random_soups(draw):
    n = draw(st.integers(3, 9))
    v = draw(st.lists(st.tuples(xy, xy, zs), min_size=n, max_size=n))
    m = draw(st.integers(1, 14))
    idx = st.integers(0, n - 1)
    f = draw(st.lists(st.tuples(idx, idx, idx), min_size=m, max_size=m))
    oid = draw(st.lists(st.integers(0, 1), min_size=m, max_size=m))
    return Scene(np.array(v, float), np.array(f), np.array(oid))


@settings(max_examples=120, deadline=None)
@given(random_soups(), st.sampled_from(["object", "scene"]), st.integers(1, 3),
       st.sampled_from([np.float32, np.float64]))
def test_random_soups_match_the_loop(scene, scope, k, dtype):
    check_against_reference(scene, scope, k, dtype)


@pytest.mark.parametrize("name", ["gate", "soup"])
@pytest.mark.parametrize("scope", ["object", "scene"])
def test_procedural_scene_counts_add_up(name, scope):
    scene = make(name)
    adj = scene.adjacency(scope=scope)
    rep = adj.report
    assert rep.open_edges + rep.manifold_edges + rep.nonmanifold_edges == rep.edges > 0
    kept = int(adj.kept.sum())
    assert kept == rep.triangles - rep.degenerate_triangles
    assert len(adj.entry_triangle) == 3 * kept == int(adj.edge_count.sum())
    assert np.bincount(adj.entry_triangle, minlength=rep.triangles)[adj.kept].tolist() \
        == [3] * kept
    assert rep.records == int((-(-adj.edge_count // 2)).sum()) == len(adj.record_edge)
    assert rep.split_edges == int((adj.edge_count > 2).sum())
    assert (adj.triangle >= 0).sum() == 3 * kept
    # entries reference their edge: the opposite vertex is the triangle's third corner
    f = adj.faces[adj.entry_triangle]
    lo_hi = np.repeat(adj.edge_vertices, adj.edge_count, axis=0)
    corners = np.sort(np.concatenate([lo_hi, adj.entry_opposite[:, None]], axis=1), axis=1)
    assert (corners == np.sort(f, axis=1)).all()
    if name == "soup":
        assert rep.degenerate_triangles > 0 and rep.nonmanifold_edges > 0 and rep.split_edges > 0


def test_cached_per_parameters_and_read_only():
    scene = make("gate")
    a = scene.adjacency()
    assert isinstance(a, Adjacency) and isinstance(a.report, AdjacencyReport)
    assert scene.adjacency("object", 2, np.float64) is a
    assert scene.adjacency(scope="scene") is not a
    assert scene.adjacency(max_opposite=3).report.max_opposite == 3
    assert scene.adjacency(dtype=np.float32).positions.dtype == np.float32
    with pytest.raises(ValueError):
        a.sign[0, 0] = 0
    for bad in (dict(scope="world"), dict(max_opposite=0), dict(max_opposite=1.5),
                dict(dtype=np.int32)):
        with pytest.raises(ValueError):
            scene.adjacency(**bad)
