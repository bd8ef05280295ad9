"""silhouette: multiplicity against a NumPy loop, leaks of the non-deterministic
variants, lit masks of every variant against the reference, the visibility test."""

import dataclasses
import functools

import jax.numpy as jnp
import numpy as np
import pytest

import shadowlab as sl
from shadowlab.engines.silhouette_bins import cone_facets
from shadowlab.geometry.caster_culling import front_face_culled
from shadowlab.geometry.clip_visibility import side_visible
from shadowlab.methods.silhouette import record_multiplicity, triangle_signs
from shadowlab.scene.procedural import default_view, grazing_sheet
from shadowlab.scene.view import hard_light

RES = (32, 32)


@functools.lru_cache(maxsize=None)
def _frame(name, directional=False):
    params = {"soup": {"count": 120}, "sphere_grid": {"n": 2, "triangles_per_sphere": 200},
              "gate": {"trees": 3, "leaves_per_tree": 40, "bars": 4},
              "atrium": {"bays": 4, "segments": 12, "banners": 12}}[name]
    scene = sl.load_scene(name, **params)
    view = default_view(name, scene, **params)
    light = view.light
    if directional:
        to = np.asarray(scene.bounds).mean(axis=0) - np.asarray(light.position)
        light = sl.DirectionalLight(direction=to)
    gbuf = sl.render_gbuffer(scene, view.camera.replace(resolution=RES))
    return scene, gbuf, light


def _multiplicity(scene, light_h, mode, dtype, eye=np.zeros(3)):
    adj = scene.adjacency("object", 2, dtype)
    verts = (adj.positions.astype(np.float64) - eye).astype(dtype)
    lrel = np.append(light_h[:3] - light_h[3] * eye, light_h[3]).astype(dtype)
    srt = np.sort(adj.faces, axis=1)
    s, _ = triangle_signs(*(jnp.asarray(verts[srt[:, k]]) for k in range(3)), jnp.asarray(lrel))
    s = np.where(adj.kept, np.asarray(s), 0).astype(np.int32)
    return adj, record_multiplicity(adj, s, verts, lrel, mode)


def _imbalanced_vertices(adj, m):
    """Vertices where the silhouette is not a cycle: sum of m over edges ending there
    minus edges starting there (edges oriented lo -> hi) is not 0."""
    ev = adj.record_vertices
    bal = np.zeros(len(adj.positions), np.int64)
    np.add.at(bal, ev[:, 1], m)
    np.add.at(bal, ev[:, 0], -m)
    return int(np.count_nonzero(bal))


def test_multiplicity_equals_a_numpy_loop():
    """m per record = (#opposite vertices on one side of the plane (A, B, L)) - (#on the
    other), each side from a float64 determinant in a plain loop."""
    scene, _, light = _frame("soup")
    lh = light.homogeneous
    adj, m = _multiplicity(scene, lh, "sorted", np.float64)
    p = adj.positions
    expect = np.zeros(len(m), np.int64)
    clear = np.ones(len(m), bool)          # every slot's sign far above rounding
    for r in range(len(m)):
        a, b = p[adj.record_vertices[r]]
        for o in adj.opposite[r][adj.opposite[r] >= 0]:
            rows = np.stack([b - a, p[o] - a, lh[:3] - lh[3] * a])
            det = np.linalg.det(rows)
            expect[r] += int(np.sign(det))
            clear[r] &= abs(det) > 1e-9 * np.prod(np.linalg.norm(rows, axis=1))
    # the soup builds (near) degenerate and edge-on triangles on purpose; where a sign is
    # within rounding the two computations may differ, everywhere else they agree
    assert clear.mean() > 0.9
    assert np.array_equal(m[clear], expect[clear])
    assert _imbalanced_vertices(adj, m) == 0
    assert np.abs(m).max() >= 2                      # non-manifold edges are exercised


def test_only_the_sorted_multiplicity_is_watertight_under_a_grazing_light():
    """Light in the sheet's plane, float32: the per-slot variants disagree between a
    triangle's edges, so the silhouette is not closed (a leak); the sorted rule is."""
    scene = grazing_sheet()
    lh = np.array([-5.0, 1.0, 1.5, 1.0])
    counts = {mode: _imbalanced_vertices(*_multiplicity(scene, lh, mode, np.float32))
              for mode in ("sorted", "unsorted", "planes")}
    assert counts["sorted"] == 0
    assert counts["unsorted"] > 0 and counts["planes"] > 0, counts


def test_the_leaks_show_in_the_image():
    """The same sheet seen from the world origin (eye-relative = world coordinates):
    the sorted rule matches the reference, the per-slot rules leak on the wall."""
    scene = grazing_sheet()
    cam = sl.Camera(eye=(0.0, 0.0, 0.0), target=(6.0, 1.0, 1.5), up=(0, 1, 0),
                    fov_y_deg=70.0, near=0.05, far=100.0, resolution=(64, 64))
    gbuf = sl.render_gbuffer(scene, cam)
    light = sl.PointLight(position=(-2.0, 1.0, 0.3))
    truth = sl.reference_shadows(scene, gbuf, light)
    wrong = {}
    for mode in ("sorted", "planes"):
        res = sl.compute_shadows(scene, gbuf, light, method="silhouette", multiplicity=mode,
                                 degenerate="paper", chunk=4)
        wrong[mode] = int(((res.lit != truth) & gbuf.valid).sum())
    assert wrong["sorted"] == 0 and wrong["planes"] > 0, wrong


VARIANTS = [
    {"stencil": "zfail", "front_cap": "infinity"},
    {"manifold": "off", "adjacency": "scene", "max_opposite": 1},     # the general path
    {"cull_sides": "exact", "stencil": "zfail"},
]     # the default configuration is covered by tests/test_conformance.py


@pytest.mark.parametrize("opts", VARIANTS, ids=lambda o: "-".join(map(str, o.values())) or "default")
def test_variants_equal_the_reference_on_soup(opts, precision):
    scene, gbuf, light = _frame("soup")
    truth = sl.reference_shadows(scene, gbuf, light)
    res = sl.compute_shadows(scene, gbuf, light, method="silhouette", precision=precision,
                             chunk=4, **opts)
    assert int(((res.lit != truth) & gbuf.valid).sum()) == 0
    assert res.counters["negative_stencil"] == 0
    if opts.get("stencil") == "zfail":
        assert res.counters["cap_triangles"] == 2 * res.counters["casters"]


@pytest.mark.parametrize("manifold", ["off", "closed"])
@pytest.mark.parametrize("stencil", ["zpass", "zfail"])
def test_directional_light_and_closed_meshes(stencil, manifold, precision):
    scene, gbuf, light = _frame("sphere_grid", directional=True)
    truth = sl.reference_shadows(scene, gbuf, light)
    res = sl.compute_shadows(scene, gbuf, light, method="silhouette", precision=precision,
                             stencil=stencil, manifold=manifold, chunk=4)
    assert 0 < int((~truth & gbuf.valid).sum())
    assert int(((res.lit != truth) & gbuf.valid).sum()) == 0
    c = res.counters
    if manifold == "off":
        # closed spheres: silhouette edges have |m| = 2, the ground's open edges |m| = 1
        assert c["side_quads"] > c["silhouette_edges"]
        assert c["front_face_culled"] == 0
    else:
        # only the light-facing half casts: every silhouette edge has |m| = 1
        assert c["side_quads"] == c["silhouette_edges"]
        assert c["front_face_culled"] > 0
    assert c["cap_triangles"] == (c["casters"] if stencil == "zfail" else 0)


def test_manifold_fast_path_halves_the_closed_sides():
    """The default (manifold="closed") against the paper's general path: the same lit
    mask with the closed spheres' light-averted triangles dropped (the shared rule)."""
    scene, gbuf, light = _frame("sphere_grid")
    full = sl.compute_shadows(scene, gbuf, light, method="silhouette", manifold="off")
    fast = sl.compute_shadows(scene, gbuf, light, method="silhouette")
    assert fast.options["manifold"] == "closed"
    assert np.array_equal(full.lit, fast.lit)
    dropped = full.counters["casters"] - fast.counters["casters"]
    assert dropped == fast.counters["front_face_culled"] > 0
    assert dropped <= int(front_face_culled(scene, hard_light(light).homogeneous).sum())
    assert fast.counters["side_quads"] < full.counters["side_quads"]
    assert fast.counters["stencil_updates"] < full.counters["stencil_updates"]
    assert sl.compute_shadows(scene, gbuf, light, method="silhouette",
                              preset="paper").options["manifold"] == "off"


def test_exact_culling_keeps_the_result_and_the_paper_test_culls_visible_sides():
    """Random side quads with edges far outside the view: a side that a view ray
    crosses (a 24x24 grid of pixel rays, checked in float64) is never culled by the
    exact test; the paper's Algorithms 3-6 cull some of them."""
    cam = sl.Camera(eye=(0., 0., 0.), target=(0., 0., -1.), up=(0, 1, 0), fov_y_deg=60.0,
                    near=0.1, far=100.0, resolution=(16, 16))
    rng = np.random.default_rng(3)
    n = 1500

    def far(r):
        d = rng.normal(size=(n, 3))
        return d / np.linalg.norm(d, axis=1, keepdims=True) * r

    a, b = far(rng.uniform(20, 60, (n, 1))), far(rng.uniform(20, 60, (n, 1)))
    lp = far(rng.uniform(5, 60, (n, 1)))
    _, rays = cam.replace(resolution=(24, 24)).primary_rays()
    rays = rays.reshape(-1, 3)
    crossed = np.zeros(n, bool)
    for i in range(n):
        sa, sb = np.cross(lp[i], a[i]) @ rays.T, np.cross(lp[i], b[i]) @ rays.T
        pi1 = np.cross(a[i], b[i]) @ rays.T
        rho = np.cross(lp[i] - a[i], b[i] - a[i]) @ rays.T
        pi3 = -(lp[i] @ np.cross(a[i], b[i]))
        crossed[i] = np.any(((sa >= 0) != (sb >= 0)) & ((pi1 >= 0) == (rho >= 0))
                            & ((rho >= 0) == (pi3 >= 0)))
    vis = {(mode, diag): np.array([side_visible(a[i:i + 1], b[i:i + 1], np.append(lp[i], 1.0),
                                                cam, mode, diag)[0] for i in range(n)])
           for mode, diag in (("paper", "paper"), ("paper", "plane"), ("exact", "paper"))}
    assert crossed.sum() > 100
    assert not np.any(crossed & ~vis["exact", "paper"])
    assert np.any(~vis["exact", "paper"])                    # and it does cull something
    # the paper's diagonal (the normal transformed as a vector) culls crossed sides that
    # the plane's own normal keeps; what the corrected diagonal still culls is the
    # near/far-plane defect
    wrong_diag = np.sum(crossed & ~vis["paper", "paper"])
    right_diag = np.sum(crossed & ~vis["paper", "plane"])
    assert wrong_diag > right_diag > 0


def test_culling_on_a_scene_changes_nothing():
    scene, gbuf, light = _frame("gate")
    off = sl.compute_shadows(scene, gbuf, light, method="silhouette")
    on = sl.compute_shadows(scene, gbuf, light, method="silhouette", cull_sides="exact")
    assert np.array_equal(off.lit, on.lit)
    assert on.counters["culled_sides"] > 0
    assert on.counters["stencil_updates"] == off.counters["stencil_updates"]


def test_paper_preset_runs_and_reports_the_bias_difference():
    scene, gbuf, light = _frame("gate")
    res = sl.compute_shadows(scene, gbuf, light, method="silhouette", preset="paper",
                             stencil="zfail")
    assert res.options["preset"] == "paper"
    assert res.counters["cap_triangles"] > 0
    assert res.lit.shape == gbuf.valid.shape


BIN_CASES = [
    ("sphere_grid", {}),
    ("sphere_grid", {"stencil": "zfail"}),                          # front and back caps
    ("soup", {"stencil": "zfail", "front_cap": "infinity"}),        # caps at infinity
    ("sheet", {"stencil": "zfail", "degenerate": "paper"}),         # eye inside the scene
    ("sheet", {}),              # ZPASS from inside the scene (its fins clipped at depth)
    # eye and light inside: sides and back caps reach behind the eye plane (cut by
    # their cones to the samples' box)
    ("atrium", {"stencil": "zfail"}),
]


@pytest.mark.parametrize("name,opts", BIN_CASES, ids=str)
def test_screen_bins_equal_the_full_passes_per_sample(name, opts, precision):
    """bins="screen" (each sample tests the sides and caps of its screen cell) gives the
    same per-pixel cap crossings, stencil updates and lit mask as testing all of them."""
    if name == "sheet":
        scene = grazing_sheet()
        cam = sl.Camera(eye=(0.0, 0.0, 0.0), target=(6.0, 1.0, 1.5), up=(0, 1, 0),
                        fov_y_deg=70.0, near=0.05, far=100.0, resolution=RES)
        gbuf, light = sl.render_gbuffer(scene, cam), sl.PointLight(position=(-2.0, 1.0, 0.3))
    else:
        scene, gbuf, light = _frame(name)
    res = {b: sl.compute_shadows(scene, gbuf, light, method="silhouette", precision=precision,
                                 bins=b, chunk=4, **opts) for b in ("off", "screen")}
    off, on = res["off"].counters, res["screen"].counters
    for key in off:
        if key not in ("side_tests", "cap_tests", "clipped_sides"):
            assert np.array_equal(np.asarray(off[key]), np.asarray(on[key])), key
    assert np.array_equal(res["off"].lit, res["screen"].lit)
    assert on["side_tests"] < off["side_tests"]
    if name == "sheet" and "stencil" not in opts:
        # ZPASS from inside the scene: the few caps before q reach every cell
        assert on["cap_tests"] <= off["cap_tests"]
    else:
        assert on["cap_tests"] < off["cap_tests"]
    if opts.get("stencil") == "zfail":
        assert np.count_nonzero(on["cap_crossings_per_pixel"]) > 0     # caps were crossed


def test_cone_facets_hold_the_cone_and_cut_what_lies_outside():
    """Every non-negative combination of the generators satisfies every facet; a
    direction outside a pointed cone (a combination with a negative weight, tested
    exactly in float64 against the generators' own plane signs) fails one."""
    rng = np.random.default_rng(7)
    for g in (3, 4):
        gen = rng.normal(size=(400, g, 3)) + [0.0, 0.0, 1.5]   # pointed and not
        normals, valid = cone_facets(gen)
        inside = np.einsum("kg,kgd->kd", rng.uniform(0, 1, (400, g)), gen)
        dots = np.einsum("kpd,kd->kp", normals, inside)
        assert np.all(~valid | (dots >= -1e-9 * np.linalg.norm(inside, axis=1)[:, None]))
        if g == 3:             # a simplicial cone: outside iff a barycentric weight < 0
            w = rng.uniform(-1, 1, (400, 3))
            d = np.einsum("kg,kgd->kd", w, gen)
            out = (w < -1e-3).any(axis=1) & (np.abs(np.linalg.det(gen)) > 1e-2)
            dots = np.einsum("kpd,kd->kp", normals, d)
            assert np.all(valid[np.abs(np.linalg.det(gen)) > 1e-2])
            assert np.all((dots < 0).any(axis=1)[out])


@functools.lru_cache(maxsize=None)
def _terrain_window():
    """The default terrain view at 128x128, valid pixels cut to rows 24-31, cols 112-127."""
    scene = sl.load_scene("terrain")
    view = default_view("terrain", scene)
    gbuf = sl.render_gbuffer(scene, view.camera.replace(resolution=(128, 128)))
    window = np.zeros_like(gbuf.valid)
    window[24:32, 112:128] = True
    return scene, dataclasses.replace(gbuf, valid=gbuf.valid & window), view.light


def test_terrain_side_test_is_well_conditioned_near_a_crease(precision):
    """Pixel (28, 119) of the default terrain at 128x128 is lit; its cut point q lies
    2e-3 world units off the side of a crease edge 1.4 units away. The edge test pi2 in
    the expanded form D + q'.r (|D| ~ 25) took the wrong sign there in float32 and
    counted that side alone (a false shadow of stencil 2); relative to A it is exact."""
    scene, gbuf, light = _terrain_window()
    truth = sl.reference_shadows(scene, gbuf, light)
    res = sl.compute_shadows(scene, gbuf, light, method="silhouette", precision=precision)
    assert truth[28, 119] and gbuf.valid[28, 119]
    assert res.lit[28, 119] and res.counters["stencil_updates_per_pixel"][28, 119] == 0
    assert int(((res.lit != truth) & gbuf.valid).sum()) == 0
    assert int((~truth & gbuf.valid).sum()) > 0          # the window holds shadow too


def _closed_mesh_crossings(vertices, faces, q, dtype):
    """(signed count, crossings) [Q] of the eye rays lambda q' (lambda > 0, eye at the
    origin) with a closed mesh, through the method's cap predicates in ``dtype``: each
    crossed triangle adds sgn(n_T . q'), so a closed surface sums to 0."""
    import jax

    with jax.enable_x64(dtype == "float64"):
        return _crossings_in(vertices.astype(dtype), faces, q.astype(dtype))


def _crossings_in(v, faces, q):
    import jax.numpy as jnp

    from shadowlab.engines.silhouette_stencil import (cap_kernel, cap_table, edge_table,
                                                      vertex_terms)
    from shadowlab.methods.silhouette import triangle_signs

    dtype = v.dtype
    light = np.asarray([0.0, 50.0, 0.0, 1.0], dtype)          # not used by the front caps
    srt = np.sort(faces, axis=1)
    # +1 where sorting is an even permutation of the face's winding: s_T sgn(n_T . q')
    # with n_T from the sorted vertices is then sgn(n_face . q')
    order = np.argsort(faces, axis=1)
    parity = np.where((order[:, 1] - order[:, 0]) % 3 == 1, 1, -1).astype(np.int32)
    edges = np.concatenate([srt[:, [0, 1]], srt[:, [1, 2]], srt[:, [0, 2]]])
    uniq, inv = np.unique(edges, axis=0, return_inverse=True)
    inv = inv.ravel()
    vt = vertex_terms(jnp.asarray(v), jnp.asarray(light))
    table = np.asarray(edge_table(jnp.asarray(v[uniq[:, 0]]), jnp.asarray(v[uniq[:, 1]]),
                                  vt[uniq[:, 0]], vt[uniq[:, 1]], jnp.asarray(light)))
    _, terms = triangle_signs(*(jnp.asarray(v[srt[:, k]]) for k in range(3)),
                              jnp.asarray(light))
    rows = cap_table(table, inv.reshape(3, -1).T, np.asarray(terms), "eye_ray", False)
    chunk = 8
    t = len(faces)
    cap = -(-t // chunk) * chunk
    pad = lambda x: np.concatenate([x, np.zeros((cap - t, *x.shape[1:]), x.dtype)])  # noqa: E731
    run = cap_kernel(chunk, "eye_ray", False)
    count, hits = run(jnp.asarray(q), jnp.asarray(pad(rows)), jnp.asarray(pad(parity)),
                      jnp.asarray(0, jnp.int32))
    return np.asarray(count), np.asarray(hits)


@pytest.mark.parametrize("centre", [(11.3, -24.2, -30.7), (25.0, -7.0, -30.0)])
def test_caps_of_a_small_far_mesh_are_watertight_near_its_vertices(centre, precision):
    """A closed icosphere 3 cm edges across, 40 units from the eye: view rays aimed
    within 1e-5 radians of its vertices must cross it an even number of times with
    signs summing to 0. Two float32 faults broke this (both seen as false shadows with
    negative stencils on a 1M-triangle sphere grid): the edge rows' A' x B' formed
    directly (products of 40 x 40 cancelling to 40 x 0.03, each edge's plane off by up
    to 7 mm, so the wedges of a vertex's fan overlapped or left gaps: thousands of these
    rays failed), and the (lo, hi) edge's bit taken as ``<= 0`` rather than the
    complement of ``>= 0`` (a dot product of exactly 0 put the ray inside both
    triangles of that edge or neither: 10 to 20 of them). Rays are aimed only at
    vertices whose surface faces the eye (|cos| > 0.3): within float32 rounding of the
    mesh's own silhouette an edge-on triangle's side cannot be decided in float32."""
    import trimesh

    ico = trimesh.creation.icosphere(subdivisions=3, radius=0.15)
    verts = ico.vertices + np.asarray(centre)
    facing = np.abs((ico.vertex_normals * verts).sum(1)) / np.linalg.norm(verts, axis=1)
    aims = np.repeat(verts[facing > 0.3], 24, axis=0)
    dirs = aims / np.linalg.norm(aims, axis=1, keepdims=True)
    dirs = dirs + np.random.default_rng(5).normal(scale=1e-5, size=dirs.shape)
    q = dirs * 60.0                                             # beyond the mesh
    count, hits = _closed_mesh_crossings(verts, ico.faces, q, precision)
    assert (hits > 0).sum() > len(q) // 2                     # most rays do hit it
    assert np.all(count == 0), np.flatnonzero(count)[:10]
    assert np.all(hits % 2 == 0)


def test_eye_inside_a_closed_objects_shadow_with_and_without_culling(precision):
    """The camera under a sphere, in its shadow: ZPASS starts at the eye's count, which
    counts the culled casters' volumes no more (1 for the sphere instead of 2); both
    paths give the reference's lit mask."""
    scene = sl.load_scene("sphere_grid", n=2, triangles_per_sphere=200)
    light = sl.PointLight(position=(2.0, 11.25, -1.0))
    eye = np.array([1.5, 0.25, -1.5])               # under sphere_1_0 (centre 1.5, 1.5, -1.5)
    cam = sl.Camera(eye=eye, target=eye + [6.0, -0.1, 0.5], up=(0, 1, 0), fov_y_deg=70.0,
                    near=0.01, far=100.0, resolution=(40, 40))
    gbuf = sl.render_gbuffer(scene, cam)
    truth = sl.reference_shadows(scene, gbuf, light)
    assert 0 < int((~truth & gbuf.valid).sum()) and int((truth & gbuf.valid).sum()) > 0
    runs = {m: sl.compute_shadows(scene, gbuf, light, method="silhouette", manifold=m,
                                  precision=precision) for m in ("closed", "off")}
    for m, res in runs.items():
        assert int(((res.lit != truth) & gbuf.valid).sum()) == 0, m
        assert res.counters["negative_stencil"] == 0, m
    assert runs["closed"].counters["eye_in_volumes"] == 1
    assert runs["off"].counters["eye_in_volumes"] == 2
