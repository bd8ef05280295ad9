"""The shared caster culling stage (geometry.caster_culling) against independent checks:
a NumPy segment-triangle test for the hull, and the Embree references (hard and soft)
computed with and without the culled triangles."""

import numpy as np
import pytest
from hypothesis import given, settings, strategies as st

import shadowlab as sl
from shadowlab.core.frame import localize
from shadowlab.geometry import caster_culling as cc
from shadowlab.scene import procedural
from shadowlab.scene.view import DirectionalLight, PointLight, SphereLight


def _segment_hits(a, b, tri):
    """bool [S, T]: segment a[s] -> b[s] meets triangle tri[t] (Moller-Trumbore, float64)."""
    d = b - a
    e1, e2 = tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]
    p = np.cross(d[:, None], e2[None])
    det = np.einsum("stk,tk->st", p, e1)
    inv = np.where(np.abs(det) > 1e-14, 1.0 / np.where(det == 0, 1, det), 0.0)
    s = a[:, None] - tri[None, :, 0]
    u = np.einsum("stk,stk->st", s, p) * inv
    q = np.cross(s, e1[None])
    v = np.einsum("sk,stk->st", d, q) * inv
    t = np.einsum("stk,tk->st", q, e2) * inv
    return (inv != 0) & (u >= 0) & (v >= 0) & (u + v <= 1) & (t >= 0) & (t <= 1)


def test_hull_planes_of_a_cube_are_its_six_faces():
    corners = cc._box_corners(np.zeros(3), np.ones(3))
    planes = cc.hull_planes(corners, tol=1e-9)
    assert len(planes) == 6
    assert np.all(corners @ planes[:, :3].T - planes[:, 3] <= 1e-9)
    assert np.all(np.array([0.5, 0.5, 0.5]) @ planes[:, :3].T - planes[:, 3] < 0)


@settings(max_examples=25, deadline=None)
@given(seed=st.integers(0, 10_000), kind=st.sampled_from(["point", "directional", "sphere",
                                                          "sun"]))
def test_culled_triangles_meet_no_shadow_ray_of_any_point_of_the_box(seed, kind):
    rng = np.random.default_rng(seed)
    lo, hi = np.sort(rng.uniform(-1, 1, (2, 3)), axis=0)
    lo[1] = hi[1] = 0.0                          # receivers on a plane (a flat box)
    tri = rng.uniform(-3, 3, (300, 3, 3))
    light = {"point": PointLight(rng.uniform(-2, 2, 3) + [0, 3, 0]),
             "directional": DirectionalLight(rng.normal(size=3) - [0, 2, 0]),
             "sphere": SphereLight(position=rng.uniform(-2, 2, 3) + [0, 3, 0], radius=0.5),
             "sun": SphereLight(direction=rng.normal(size=3) - [0, 3, 0],
                                angular_radius_deg=5.0)}[kind]
    reach = 20.0
    soft = kind in ("sphere", "sun")
    planes = cc.hull_planes(cc.hull_points(lo, hi, light, reach, soft), tol=1e-9)
    out = cc.outside_hull(tri, planes, 1e-9)
    # shadow rays of random receivers to random points of the light (within reach)
    p = rng.uniform(lo, hi, (400, 3))
    if kind == "point":
        ends = np.broadcast_to(light.position, p.shape)
    elif kind == "directional":
        ends = p - reach * light.direction
    elif kind == "sphere":
        w = rng.normal(size=p.shape)
        ends = light.position + 0.5 * w / np.linalg.norm(w, axis=1, keepdims=True)
    else:
        towards = -light.direction
        u, v = cc._orthonormal(towards)
        r = np.tan(np.radians(5.0)) * np.sqrt(rng.uniform(0, 1, len(p)))
        a = rng.uniform(0, 2 * np.pi, len(p))
        dirs = towards + r[:, None] * (np.cos(a)[:, None] * u + np.sin(a)[:, None] * v)
        ends = p + reach * dirs / np.linalg.norm(dirs, axis=1, keepdims=True)
    hits = _segment_hits(p, np.asarray(ends, float), tri)
    assert not hits[:, out].any()
    assert out.any() and hits[:, ~out].any()     # the test is not vacuous


@pytest.mark.parametrize("name", ["city", "sphere_grid", "terrain", "gate", "atrium"])
def test_references_do_not_change_without_the_culled_triangles(name):
    """Embree's hard and soft references on the kept triangles equal those on the whole
    scene: the culled ones shadow nothing."""
    scene = procedural.make(name)
    view = procedural.default_view(name, scene)
    gbuf = sl.render_gbuffer(scene, view.camera.replace(resolution=(32, 32)))
    light = view.light
    if getattr(light, "position", None) is not None:
        hard = sl.PointLight(light.position)
        area = sl.SphereLight(position=np.asarray(hard.position), radius=0.05 * scene.diagonal)
    else:                                        # terrain's sun: a directional light
        hard, area = sl.DirectionalLight(direction=light.direction), light
    culled = 0
    for lt, soft in ((hard, False), (area, True)):
        local = localize(scene, gbuf, lt)
        cull = cc.cull_casters(local.scene, local.gbuf, local.light,
                               "hull" if soft else "all", soft=soft)
        kept = cc.subset_scene(local.scene, cull.keep)
        assert kept.diagonal == local.scene.diagonal
        culled += cull.culled
        if soft:
            a = sl.soft_reference(local.scene, local.gbuf, local.light, rays_per_pixel=16)
            b = sl.soft_reference(kept, local.gbuf, local.light, rays_per_pixel=16)
        else:
            a = sl.reference_shadows(local.scene, local.gbuf, local.light)
            b = sl.reference_shadows(kept, local.gbuf, local.light)
        np.testing.assert_array_equal(a, b)
    assert culled > 0


def test_off_keeps_everything_and_a_bad_mode_is_refused():
    scene = procedural.make("gate")
    view = procedural.default_view("gate", scene)
    gbuf = sl.render_gbuffer(scene, view.camera.replace(resolution=(8, 8)))
    assert cc.cull_casters(scene, gbuf, view.light, "off").keep.all()
    with pytest.raises(sl.methods.MethodError, match="cull_casters"):
        sl.compute_shadows(scene, gbuf, view.light, method="brute_force", cull_casters="yes")


def test_the_gbuffer_triangle_ids_follow_the_subset():
    scene = procedural.make("city", blocks=2, posts=3)
    view = procedural.default_view("city", scene, blocks=2, posts=3)
    gbuf = sl.render_gbuffer(scene, view.camera.replace(resolution=(24, 24)))
    keep = np.ones(scene.num_triangles, bool)
    keep[::3] = False
    sub, g = cc.subset_scene(scene, keep), cc.subset_gbuffer(gbuf, keep)
    hit = gbuf.triangle >= 0
    kept_hit = hit & keep[np.clip(gbuf.triangle, 0, None)]
    assert kept_hit.any() and (hit & ~kept_hit).any()
    np.testing.assert_array_equal(sub.faces[g.triangle[kept_hit]], scene.faces[gbuf.triangle[kept_hit]])
    assert np.all(g.triangle[~kept_hit] == -1)


@settings(max_examples=30, deadline=None)
@given(seed=st.integers(0, 10_000), kind=st.sampled_from(["point", "directional"]))
def test_receivers_step_culls_only_triangles_on_no_sample_segment(seed, kind):
    """Triangles behind every sample of their light-space footprint meet no segment from
    the light to a sample (a NumPy segment-triangle test), and the step culls some."""
    rng = np.random.default_rng(seed)
    # receivers on a bumpy floor, casters above and below it
    xz = rng.uniform(-2, 2, (600, 2))
    samples = np.column_stack([xz[:, 0], 0.3 * np.sin(2 * xz[:, 0]) * np.cos(xz[:, 1]),
                               xz[:, 1]])
    centres = rng.uniform([-3, -2, -3], [3, 1.5, 3], (400, 3))
    tri = centres[:, None] + rng.normal(scale=rng.uniform(0.02, 0.6, (400, 1, 1)),
                                        size=(400, 3, 3))
    if kind == "point":
        light_h = np.append(rng.uniform(-3, 3, 3) + [0, 5, 0], 1.0)
        ends = np.broadcast_to(light_h[:3], samples.shape)
    else:
        towards = rng.normal(size=3) + [0, 3, 0]
        light_h = np.append(towards / np.linalg.norm(towards), 0.0)
        ends = samples + 50.0 * light_h[:3]
    culled = cc.behind_receivers(tri, samples, light_h, diag=8.0, cells=16)
    hits = _segment_hits(samples, np.asarray(ends, float), tri)
    assert not hits[:, culled].any()
    assert culled.any() and hits[:, ~culled].any()     # not vacuous


def test_point_triangle_distance_equals_a_dense_sampling():
    rng = np.random.default_rng(3)
    tri = rng.normal(size=(200, 3, 3))
    p = rng.normal(size=3) * 2
    got = cc._point_triangle_distance(p, tri)
    w = rng.dirichlet(np.ones(3), 20_000)
    pts = np.einsum("kv,tvd->tkd", w, tri)
    dense = np.linalg.norm(pts - p, axis=2).min(axis=1)
    assert np.all(got <= dense + 1e-12)             # a lower bound of every point's distance
    assert np.all(dense - got < 0.05 * (1 + dense))  # and close to the sampled minimum


def test_receivers_directional_grid_keeps_a_triangle_within_float32_of_a_lone_sample():
    """With one sample (a grid of zero extent) a triangle whose edge passes within float32
    rounding of the sample's ray is kept; a grid size that is not a power of two works."""
    p = np.array([[0.3, 0.3, 0.3]])
    tri = np.array([[[0.3 + 1e-9, -1, 1.0], [0.3 + 1e-9, 1, 1.0], [1.3, 0.3, 1.0]]])
    light = np.array([0.0, 0.0, 1.0, 0.0])
    assert not cc.behind_receivers(tri, p, light, 1.0).any()
    far = np.array([[[5.0, 5.0, -1.0], [6.0, 5.0, -1.0], [5.0, 6.0, -1.0]]])  # behind, aside
    assert cc.behind_receivers(far, p, light, 1.0, cells=48).all()


def _lamp_scene(offset):
    """A ground quad, a closed box standing on it and a closed icosphere shade around
    (0, 1, 0); every coordinate moved by ``offset``."""
    import trimesh

    from shadowlab.scene.mesh import Scene

    shade = trimesh.creation.icosphere(subdivisions=2, radius=0.3)
    shade.apply_translation([0, 1, 0])
    box = trimesh.creation.box(extents=[0.6, 0.8, 0.6])
    box.apply_translation([1.2, 0.4, 0.3])
    ground = (np.array([[-4, 0, -4], [4, 0, -4], [4, 0, 4], [-4, 0, 4.0]]),
              np.array([[0, 2, 1], [0, 3, 2]]))
    parts = [(shade.vertices, shade.faces), (box.vertices, box.faces), ground]
    verts, faces, oid, base = [], [], [], 0
    for k, (v, f) in enumerate(parts):
        verts.append(np.asarray(v, float) + offset)
        faces.append(np.asarray(f) + base)
        oid.append(np.full(len(f), k))
        base += len(v)
    return Scene(np.vstack(verts), np.vstack(faces), np.concatenate(oid),
                 ("shade", "box", "ground"))


def test_light_outside_objects_against_known_positions():
    scene = _lamp_scene(np.zeros(3))
    closed = np.array([o.closed for o in scene.report().objects])
    assert closed.tolist() == [True, True, False]
    corner = scene.vertices[scene.faces[scene.object_id == 1]].reshape(-1, 3).max(axis=0)
    on_face = np.array([1.2, 0.4, 0.6])                    # the box's +z face
    cases = {"inside the shade": ([0, 1.05, 0.02], [False, True, False]),
             "inside the box": ([1.1, 0.3, 0.35], [True, False, False]),
             "on a face of the box": (on_face, [True, False, False]),
             "at a corner of the box": (corner, [True, False, False]),
             "just outside the box": (on_face + [0, 0, 1e-3], [True, True, False]),
             "far away": ([0, 30, 0], [True, True, False])}
    for name, (p, want) in cases.items():
        got = cc.light_outside_objects(scene, np.append(p, 1.0), closed)
        assert got.tolist() == want, name
    got = cc.light_outside_objects(scene, np.array([0.3, -1.0, 0.1, 0.0]), closed)
    assert got.tolist() == [True, True, False]                # a directional light


@pytest.mark.parametrize("precision", ["float32", "float64"])
@pytest.mark.parametrize("offset", [0.0, 1e4])
def test_a_closed_object_around_the_light_is_not_averted_culled(precision, offset):
    """A point light inside a closed shade: every sample outside it is in its shadow.
    Before the light-inside rule, the averted step dropped the whole shade (all its
    triangles face away from a light inside) and every method lit the ground."""
    o = np.array([offset, 0.0, -offset])
    scene = _lamp_scene(o)
    gbuf = sl.render_gbuffer(scene, sl.Camera(eye=o + [0, 4, 6], target=o + [0, 0.5, 0],
                                              resolution=(32, 32)))
    light = sl.PointLight(position=o + [0.05, 1.02, -0.03])
    truth = sl.reference_shadows(scene, gbuf, light)
    assert gbuf.valid.sum() > 400 and not truth[gbuf.valid].any()   # all in the shade's shadow
    light_h = np.append(light.position, 1.0)
    assert cc.front_face_culled(scene, light_h, "averted")[scene.object_id == 1].any()
    assert not cc.front_face_culled(scene, light_h, "averted")[scene.object_id == 0].any()
    runs = [("brute_force", {"cull_casters": "hull_averted"}),
            ("clustered_ptsv", {"front_face_culling": True}),
            ("clustered_ptsv", {"front_face_culling": True, "cull_side": "facing"}),
            ("silhouette", {})]                              # manifold="closed"
    for method, options in runs:
        res = sl.compute_shadows(scene, gbuf, light, method=method, precision=precision,
                                 **options)
        lit = np.asarray(res.lit)
        assert not lit[gbuf.valid].any(), (method, options)
    # with the light outside the shade the box's averted triangles are still dropped
    outside = sl.PointLight(position=o + [0.5, 3.0, 0.5])
    res = sl.compute_shadows(scene, gbuf, outside, method="brute_force", precision=precision,
                             cull_casters="hull_averted")
    assert res.counters["culled_casters_averted"] > 0
    np.testing.assert_array_equal(np.asarray(res.lit)[gbuf.valid],
                                  sl.reference_shadows(scene, gbuf, outside)[gbuf.valid])


@pytest.mark.parametrize("name", ["sphere_grid", "blobs", "gate"])
def test_front_face_culled_matches_a_per_triangle_loop_and_ignores_winding(name):
    """The cached column form of the averted / facing test against a plain per-triangle
    loop (np.cross and np.dot of each triangle, the object's orientation from its
    signed volume), for a point and a directional light; flipping every triangle's
    winding flips the object's orientation too, so the culled set is unchanged."""
    scene = sl.load_scene(name)
    view = procedural.default_view(name, scene)
    lo, hi = scene.bounds
    lights = [np.append(view.light.position, 1.0), np.array([0.3, 1.0, -0.2, 0.0]),
              np.append(hi + 0.5 * (hi - lo), 1.0)]
    tri = scene.triangles
    vol = np.zeros(scene.num_objects)
    for t, o in zip(tri, scene.object_id):
        vol[o] += float(np.dot(t[0], np.cross(t[1], t[2])))
    orient = np.where(vol < 0, -1.0, 1.0)
    closed = np.array([o.closed for o in scene.report().objects])
    flipped = sl.Scene(scene.vertices, scene.faces[:, ::-1].copy(), scene.object_id,
                       scene.object_names)
    pick = np.random.default_rng(0).choice(scene.num_triangles, 300, replace=False)
    for light_h in lights:
        outside = cc.light_outside_objects(scene, light_h, closed)
        for side in cc.CULL_SIDES:
            got = cc.front_face_culled(scene, light_h, side)
            assert np.array_equal(got, cc.front_face_culled(flipped, light_h, side))
            for i in pick:
                o = scene.object_id[i]
                t = tri[i]
                facing = float(np.dot(np.cross(t[1] - t[0], t[2] - t[0]),
                                      light_h[:3] - light_h[3] * t[0])) * orient[o]
                want = bool(closed[o] and outside[o]
                            and (facing > 0 if side == "facing" else facing < 0))
                assert got[i] == want, (name, side, i, facing)
        assert cc.front_face_culled(scene, light_h, "averted").any() == bool(
            (closed & outside).any())


def test_cross_columns_is_numpy_cross_bit_for_bit():
    from shadowlab.core.numerics import cross_columns
    rng = np.random.default_rng(3)
    for dtype in (np.float32, np.float64):
        a = (rng.normal(size=(5000, 3)) * 10.0 ** rng.uniform(-3, 6, (5000, 1))).astype(dtype)
        b = rng.normal(size=(5000, 3)).astype(dtype)
        got = np.stack(cross_columns(list(a.T), list(b.T)), axis=1)
        assert got.dtype == dtype
        np.testing.assert_array_equal(got, np.cross(a, b))


def test_without_culled_faces_keeps_order_bounds_and_one_triangle(monkeypatch):
    """The methods' own face culling: the kept triangles in their order, the scene's
    bounds, the count dropped; and a scene never loses its last triangle."""
    scene = procedural.make("sphere_grid", n=2, triangles_per_sphere=80)
    light_h = np.array([0.3, 5.0, 0.2, 1.0])
    drop = cc.front_face_culled(scene, light_h, "averted")
    sub, count = cc.without_culled_faces(scene, light_h, "averted")
    assert count == int(drop.sum()) > 0
    np.testing.assert_array_equal(sub.triangles, scene.triangles[~drop])
    np.testing.assert_array_equal(sub.bounds, scene.bounds)
    monkeypatch.setattr(cc, "front_face_culled",
                        lambda s, lh, side="averted": np.ones(s.num_triangles, bool))
    last, count = cc.without_culled_faces(scene, light_h)
    assert last.num_triangles == 1 and count == scene.num_triangles - 1
    np.testing.assert_array_equal(last.triangles[0], scene.triangles[0])
