"""The irregular z-buffer (``izb``) and the shadow map (``shadow_map``).

izb: the lit mask equals the Embree reference (no unexplained mismatch) with and
without the CSM prepass, in float32 and float64, on hard cases for the prepass
(receivers in contact with casters, grazing light, sub-texel triangles, a point light
inside the scene with a cube camera); the prepass never culls a lit sample
(``csm_false_shadows == 0``); counter identities and the orderings that are identities
(corners culls a superset of circle, the corner depth a superset of the slope depth, node
culling never lengthens a list or adds tests). shadow_map: the depth map against rays
cast from the light in a NumPy loop; bias reduces acne.
"""

import functools

import numpy as np
import pytest

import shadowlab as sl
from shadowlab.analysis.metrics import compare_hard
from shadowlab.core.frame import view_samples
from shadowlab.methods import MethodError
from shadowlab.methods import izb as mizb
from shadowlab.reference.boundary import unexplained_mismatches
from shadowlab.scene import Scene
from shadowlab.scene import primitives as prim
from shadowlab.scene.light_camera import box_corners, fit_light_camera
from shadowlab.structures import light_raster as lr

RES = (40, 40)


def _hard_scene():
    """Ground grid, boxes resting on it (contact), one sunk box, a tilted quad, and a
    cloud of sub-texel triangles."""
    rng = np.random.default_rng(7)
    parts = [prim.quad_grid((-4, 4), (-4, 4), 0.0, cells=6)]
    parts.append(prim.boxes(np.array([[-2.0, 0.0, -1.0], [0.5, 0.0, 0.5], [1.5, -0.2, -2.5]]),
                            np.array([[-1.0, 1.0, 0.0], [1.2, 0.4, 1.5], [2.5, 0.6, -1.5]])))
    parts.append((np.array([[-3.0, 1.5, 1.0], [-1.0, 1.2, 1.0], [-1.0, 2.0, 3.0], [-3.0, 2.3, 3.0]]),
                  np.array([[0, 1, 2], [0, 2, 3]])))
    c = rng.uniform((-1, 0.8, -3), (1, 1.6, -1), (300, 3))
    tiny = c[:, None, :] + rng.normal(0, 0.02, (300, 3, 3))
    parts.append((tiny.reshape(-1, 3), np.arange(900).reshape(-1, 3)))
    v, f = prim.merge(parts)
    return Scene(v, f, np.zeros(len(f)), ("hard",), "hard")


LIGHTS = {
    "grazing": sl.DirectionalLight(direction=(1.0, -0.06, 0.3)),
    "steep": sl.DirectionalLight(direction=(-0.3, -1.0, 0.4)),
    "inside": sl.PointLight(position=(0.3, 2.6, -0.4)),
    "above": sl.PointLight(position=(1.0, 9.0, 2.0)),
}


@functools.lru_cache(maxsize=None)
def frame(light_name):
    scene = _hard_scene()
    cam = sl.Camera(eye=(6.0, 7.0, 8.0), target=(0.0, 0.3, -0.5), up=(0, 1, 0), fov_y_deg=50.0,
                    near=0.1, far=100.0, resolution=RES)
    gbuf = sl.render_gbuffer(scene, cam)
    light = LIGHTS[light_name]
    return scene, gbuf, light, sl.reference_shadows(scene, gbuf, light)


def _run(light_name, precision, **options):
    scene, gbuf, light, _ = frame(light_name)
    return sl.compute_shadows(scene, gbuf, light, method="izb", precision=precision, **options)


@pytest.mark.parametrize("light_name", ["grazing", "steep", "inside"])
def test_izb_is_exact_and_the_prepass_conservative(light_name, precision):
    scene, gbuf, light, truth = frame(light_name)
    extra = {"projection": "cube"} if light_name == "inside" else {}
    runs = {}
    for opts in ({"prepass": "none"}, {"prepass": "csm"},
                 {"prepass": "csm", "coverage": "circle", "csm_depth": "slope"}):
        res = _run(light_name, precision, resolution=256, **opts, **extra)
        bad = unexplained_mismatches(scene, gbuf, light, res.lit, truth)
        assert len(bad) == 0, (opts, bad[:5])
        c = res.counters
        assert c["list_nodes"] == c["samples"] - c["csm_culled"]
        assert c["tests"] == int(c["tests_per_pixel"].sum())
        assert c["csm_culled"] == int(c["csm_culled_per_pixel"].sum())
        if opts["prepass"] == "csm":
            assert c["csm_false_shadows"] == 0
        runs[tuple(sorted(opts.items()))] = res
    none, csm, circle = runs.values()
    assert np.array_equal(none.lit, csm.lit) and np.array_equal(none.lit, circle.lit)
    assert csm.counters["tests"] <= none.counters["tests"]
    assert csm.counters["list_length_max"] <= none.counters["list_length_max"]
    assert csm.counters["lit"] < csm.counters["samples"]
    if extra:
        assert csm.counters["light_faces"] == 6
    if light_name != "grazing":
        assert csm.counters["csm_culled"] > 0


def _closed_scene():
    """Ground grid (open), closed boxes resting on it and one sunk into it (contacts: the
    receiver bias puts some segment starts inside a box), and a closed sphere around the
    point ``(0.3, 2.6, -0.4)`` (the light ``inside``)."""
    ground = prim.quad_grid((-4, 4), (-4, 4), 0.0, cells=6)
    boxes = prim.boxes(np.array([[-2.0, 0.0, -1.0], [0.5, 0.0, 0.5], [1.5, -0.2, -2.5]]),
                       np.array([[-1.0, 1.0, 0.0], [1.2, 0.4, 1.5], [2.5, 0.6, -1.5]]))
    sv, sf = prim.uv_sphere(8, 12)
    shade = (sv * 0.5 + np.array([0.3, 2.6, -0.4]), sf)
    parts = [Scene(v, f, np.zeros(len(f)), (name,), name)
             for (v, f), name in zip((ground, boxes, shade), ("ground", "boxes", "shade"))]
    return Scene.concatenate(parts, name="closed")


@pytest.mark.parametrize("light_name", ["grazing", "steep", "inside", "above"])
def test_front_face_culling_keeps_the_lit_mask(light_name, precision):
    """Dropping closed objects' light-averted triangles (the default) gives the lit mask
    and shadowed count of the unculled run, bit for bit; a light inside the closed
    sphere keeps that sphere whole."""
    scene = _closed_scene()
    cam = sl.Camera(eye=(6.0, 7.0, 8.0), target=(0.0, 0.3, -0.5), up=(0, 1, 0), fov_y_deg=50.0,
                    near=0.1, far=100.0, resolution=RES)
    gbuf = sl.render_gbuffer(scene, cam)
    light = LIGHTS[light_name]
    extra = {"projection": "cube"} if light_name == "inside" else {}
    on, off = (sl.compute_shadows(scene, gbuf, light, method="izb", precision=precision,
                                  resolution=256, front_face_culling=c, **extra)
               for c in (True, False))
    assert np.array_equal(on.lit, off.lit)
    assert on.counters["shadowed"] == off.counters["shadowed"] > 0
    assert off.counters["front_face_culled"] == 0
    culled = on.counters["front_face_culled"]
    shade = int((scene.object_id == 2).sum())
    boxes = int((scene.object_id == 1).sum())
    # a box is culled by about half (its averted faces), the sphere by about half
    # unless it holds the light; the open ground never
    assert boxes // 4 <= culled - (0 if light_name == "inside" else shade // 3)
    assert culled <= boxes + (0 if light_name == "inside" else shade)
    assert on.counters["casters"] + culled <= off.counters["casters"]
    # (tests can rise: the averted faces also cover texels of the CSM prepass, which
    # then culls fewer samples)
    truth = sl.reference_shadows(scene, gbuf, light)
    assert len(unexplained_mismatches(scene, gbuf, light, on.lit, truth)) == 0


@pytest.mark.parametrize("light_name", ["grazing", "steep", "inside", "above"])
def test_tight_triangle_boxes_keep_the_lit_mask(light_name, precision, monkeypatch):
    """The outer raster's triangle boxes, padded by BOX_PAD_TAUS x tau (the default),
    against boxes padded by at least 10 texels: the same lit mask and shadowed count,
    and fewer traced fragments (beyond a triangle's box the per-edge outer test still
    passes texels near acute corners, which hold no sample the triangle can shadow)."""
    scene, gbuf, light, truth = frame(light_name)
    extra = {"projection": "cube"} if light_name == "inside" else {}
    tight = _run(light_name, precision, resolution=256, prepass="none", **extra)
    monkeypatch.setattr(mizb, "BOX_PAD_TAUS", 1e4)        # tau >= coverage_margin = 1e-3
    wide = _run(light_name, precision, resolution=256, prepass="none", **extra)
    assert np.array_equal(tight.lit, wide.lit)
    assert tight.counters["shadowed"] == wide.counters["shadowed"] > 0
    assert tight.counters["traced_fragments"] < wide.counters["traced_fragments"]
    assert tight.counters["tests"] < wide.counters["tests"]
    assert len(unexplained_mismatches(scene, gbuf, light, tight.lit, truth)) == 0


def test_prepass_orderings_are_identities():
    """circle culls a subset of corners; the slope depth a subset of the corner depth."""
    for light_name in ("steep", "inside"):
        runs = {}
        for cov in ("corners", "circle"):
            for depth in ("corner", "slope"):
                res = _run(light_name, "float64", resolution=512, coverage=cov, csm_depth=depth)
                runs[cov, depth] = res.counters["csm_culled_per_pixel"].astype(bool)
                assert res.counters["csm_false_shadows"] == 0
        assert runs["corners", "corner"].sum() > 0
        assert not np.any(runs["circle", "corner"] & ~runs["corners", "corner"])
        assert not np.any(runs["corners", "slope"] & ~runs["corners", "corner"])
        assert not np.any(runs["circle", "slope"] & ~runs["circle", "corner"])


@pytest.mark.parametrize("light_name", ["steep", "inside"])
def test_a_finer_csm_culls_more_and_stays_exact(light_name, precision):
    scene, gbuf, light, truth = frame(light_name)
    extra = {"projection": "cube"} if light_name == "inside" else {}
    one = _run(light_name, precision, resolution=256, **extra)
    fine = _run(light_name, precision, resolution=256, csm_scale=4, **extra)
    assert fine.counters["csm_false_shadows"] == 0
    assert len(unexplained_mismatches(scene, gbuf, light, fine.lit, truth)) == 0
    assert np.array_equal(one.lit, fine.lit)
    assert fine.counters["csm_culled"] > one.counters["csm_culled"]
    assert fine.counters["tests"] < one.counters["tests"]


def test_csm_min_area_draws_fewer_casters_and_stays_conservative():
    base = _run("steep", "float32", resolution=512).counters
    prev = base["csm_culled_per_pixel"].astype(bool)
    for area in (2.0, 50.0, 1e9):
        c = _run("steep", "float32", resolution=512, csm_min_area=area).counters
        culled = c["csm_culled_per_pixel"].astype(bool)
        assert c["csm_false_shadows"] == 0 and not np.any(culled & ~prev)
        prev = culled
    assert base["csm_culled"] > 0 and c["csm_culled"] == 0 and c["csm_texels"] == 0


def _threshold_triangles(kind, seed):
    """A light camera (R 64 over [-1, 1]^2 at y = 0) and 600 triangles of a few texels
    around the covering sizes: random shapes and slivers (area above 2 texels, inradius
    well below 1/2)."""
    rng = np.random.default_rng(seed)
    ground = np.stack(np.meshgrid(np.linspace(-1, 1, 5), [0.0], np.linspace(-1, 1, 5)),
                      -1).reshape(-1, 3)
    if kind == "ortho":
        light = sl.DirectionalLight(direction=(0.2, -1.0, 0.1))
        cam = fit_light_camera(light, ground, resolution=64)
    else:
        light = sl.PointLight(position=(0.1, 2.0, 0.2))
        cam = fit_light_camera(light, ground, resolution=64, projection="perspective")
    centre = rng.uniform(-0.8, 0.8, (600, 3)) * (1, 0, 1) + (0, 0.3, 0)
    size = rng.uniform(0.02, 0.12, (600, 1, 1))         # texels are about 0.03 wide
    tri = centre[:, None, :] + size * rng.normal(0, 1, (600, 3, 3))
    d = rng.normal(0, 1, (200, 3)) * (1, 0, 1)
    d *= rng.uniform(0.1, 0.4, (200, 1)) / np.linalg.norm(d, axis=1, keepdims=True)
    side = np.cross(d, (0, 1, 0)) * rng.uniform(0.02, 0.15, (200, 1))
    tri[:200] = np.stack([centre[:200], centre[:200] + d, centre[:200] + side], 1)
    return cam, tri


@pytest.mark.parametrize("kind", ["ortho", "persp"])
def test_casters_the_csm_skips_cover_no_texel(kind):
    """The CSM's caster skip (light-space area below 2 texels, or inradius below the
    inner test's disk plus its margin) against the inner raster over every texel: no
    skipped caster covers one, the inradius equals 2 area / perimeter of the projected
    vertices, and casters within 1.5x of the bound do cover."""
    from shadowlab.methods import izb
    cam, tri = _threshold_triangles(kind, 4)
    face = cam.faces[0]
    st = lr.setup_face(face, tri)
    front = st.front & st.ok
    # the inradius from the projected vertices (texel coordinates)
    _, uv, _, _ = lr.project_points(cam, tri.reshape(-1, 3))
    uv = uv.reshape(-1, 3, 2)
    e = [np.linalg.norm(uv[:, (i + 1) % 3] - uv[:, (i + 2) % 3], axis=1) for i in range(3)]
    a, b = uv[:, 1] - uv[:, 0], uv[:, 2] - uv[:, 0]
    area = 0.5 * np.abs(a[:, 0] * b[:, 1] - a[:, 1] * b[:, 0])
    rin = izb.light_inradius(st)
    np.testing.assert_allclose(rin[front], (2 * area / sum(e))[front], rtol=1e-9)
    assert np.all(rin[~front] == 0)
    ok = np.ones(len(tri), bool)
    for test in lr.INNER_TESTS:
        for tau in (0.0, 0.1):
            covered = np.unique(lr.rasterize(cam, tri, "inner", test, tau)[0])
            drawn, small = izb.csm_casters(st, ok, test, tau)
            assert len(covered) > 20 and small > 100, (test, tau)
            assert np.all(drawn[covered]), (test, tau)
            # thin casters of area >= 2 are skipped by the inradius alone ...
            assert np.sum((izb.light_area(st) >= 2) & ~drawn & front) > 20
            # ... and a bound 1.5x larger would skip covering casters (the check can fail)
            bound = izb.COVERING_RADIUS[test] + tau
            assert rin[covered].min() < 1.5 * bound, (test, tau, rin[covered].min())


@pytest.mark.parametrize("light_name", ["steep", "inside", "above"])
def test_csm_prefilter_culls_what_every_receiver_point_would(light_name, monkeypatch):
    """The CSM computes q only for samples whose own delta lies beyond their texel's
    depth (delta(q) <= delta(p)); the culled set equals the comparison of every sample's
    q (computed here for all of them, as before the prefilter)."""

    seen = {}
    csm, depths = mizb._csm, mizb._csm_depths

    def spy_csm(*args, **kw):
        out = csm(*args, **kw)
        seen["args"], seen["out"] = args, out
        return out

    def spy_depths(*args, **kw):
        out = depths(*args, **kw)
        seen["depth"] = np.asarray(out[0])
        return out

    monkeypatch.setattr(mizb, "_csm", spy_csm)
    monkeypatch.setattr(mizb, "_csm_depths", spy_depths)
    extra = {"projection": "cube"} if light_name == "inside" else {}
    res = _run(light_name, "float32", resolution=256, **extra)
    cam, _, samples, light_h, face, (_, inv), delta_p, m_delta, *_, eps = seen["args"][:13]
    q, reaches = mizb.receiver_points(samples.position, samples.normal, light_h, eps)
    delta_q = np.empty(samples.count)
    for f in np.unique(face):
        sel = face == f
        delta_q[sel] = lr.face_depth(cam.faces[f], cam.faces[f].depth(q[sel]))
    delta_q = np.where(reaches | ~np.isfinite(delta_q), -np.inf, delta_q)
    every = delta_q > seen["depth"][inv] + m_delta
    assert every.sum() > 0 and res.counters["csm_false_shadows"] == 0
    assert np.array_equal(seen["out"][0], every)
    # the prefilter leaves most samples out (the check is not vacuous either way)
    assert np.count_nonzero(delta_p + m_delta > seen["depth"][inv]) < samples.count


def test_izb_refuses_the_prepass_with_the_cap_bias():
    scene, gbuf, light, _ = frame("steep")
    with pytest.raises(MethodError, match="prepass='csm' needs bias='receiver'"):
        sl.compute_shadows(scene, gbuf, light, method="izb", bias="cap")
    res = sl.compute_shadows(scene, gbuf, light, method="izb", bias="cap", prepass="none")
    assert res.counters["csm_false_shadows"] == -1


def _ray_depth_map(cam, tri, keys):
    """Nearest delta hit by the light ray through each texel centre [K] (NumPy loop over
    texels, vectorized over triangles; inf where nothing is hit)."""
    r = cam.resolution[0]
    face = cam.faces[0]
    out = np.full(len(keys), np.inf)
    e1, e2 = tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]
    for k, key in enumerate(keys):
        uv = np.array([[key % r + 0.5, key // r + 0.5]])
        if face.orthographic:
            o, d = face.unproject(uv, np.array([0.0]))[0], face.forward
        else:
            o = face.eye
            d = face.unproject(uv, np.array([1.0]))[0] - o
        pv = np.cross(d, e2)
        det = np.einsum("ij,ij->i", e1, pv)
        with np.errstate(divide="ignore", invalid="ignore"):
            tv = o - tri[:, 0]
            u = np.einsum("ij,ij->i", tv, pv) / det
            qv = np.cross(tv, e1)
            v = (qv @ d) / det
            t = np.einsum("ij,ij->i", e2, qv) / det
        hit = (det != 0) & (u > 0) & (v > 0) & (u + v < 1) & (t > 0)
        if hit.any():
            p = o + t[hit, None] * d
            _, depth = face.project(p)
            out[k] = lr.face_depth(face, depth).min()
    return out


@pytest.mark.parametrize("light_name", ["steep", "above"])
def test_shadow_map_lookup_matches_rays_from_the_light(light_name):
    scene, gbuf, light, truth = frame(light_name)
    res = sl.compute_shadows(scene, gbuf, light, method="shadow_map", resolution=512,
                             bias="none", projection="perspective", precision="float64")
    # rebuild the same light camera and compare each sample with the ray-cast map
    samples = view_samples(gbuf, light)
    cam = fit_light_camera(light, samples.position, casters=box_corners(scene.bounds),
                           resolution=512, projection="auto" if light_name == "steep"
                           else "perspective")
    face, uv, key, delta = lr.project_points(cam, samples.position)
    frac = uv - np.floor(uv)
    # away from texel borders and exact ties: the map is the nearest ray hit
    keep = np.all((frac > 0.02) & (frac < 0.98), axis=1)
    keys, inv = np.unique(key[keep], return_inverse=True)
    dmap = _ray_depth_map(cam, scene.triangles, keys)
    expect = delta[keep] <= dmap[inv]
    tie = np.abs(delta[keep] - dmap[inv]) <= 1e-9 * np.maximum(1, np.abs(delta[keep]))
    got = res.lit.reshape(-1)[samples.index[keep]]
    assert keep.sum() > 100
    assert np.array_equal(got[~tie], expect[~tie])


def test_shadow_map_refuses_a_perspective_face_around_the_light():
    scene, gbuf, light, _ = frame("inside")
    with pytest.raises(MethodError, match="projection='perspective'.*surround the light"):
        sl.compute_shadows(scene, gbuf, light, method="shadow_map", projection="perspective")


def test_shadow_map_bias_reduces_acne():
    scene, gbuf, light, truth = frame("steep")
    errors = {}
    for bias in ("none", "slope", "constant", "normal"):
        res = sl.compute_shadows(scene, gbuf, light, method="shadow_map", resolution=2048,
                                 bias=bias)
        errors[bias] = compare_hard(res.lit, truth, gbuf.valid)
    assert errors["none"]["false_shadow"] > 10 * max(1, errors["slope"]["false_shadow"])
    for bias in ("slope", "constant", "normal"):
        assert errors[bias]["mismatch_fraction"] < 0.1 * errors["none"]["mismatch_fraction"]
    pcf = sl.compute_shadows(scene, gbuf, light, method="shadow_map", resolution=2048, pcf=True)
    assert compare_hard(pcf.lit, truth, gbuf.valid)["mismatch_fraction"] < 0.05


@pytest.mark.parametrize("name", ["gate", "soup", "sphere_grid", "terrain", "fuzzy", "blobs"])
def test_prepass_is_conservative_on_every_procedural_scene(name, precision):
    from shadowlab.scene.procedural import default_view

    params = {"soup": {"count": 60}, "fuzzy": {"triangles": 3000},
              "sphere_grid": {"n": 3, "triangles_per_sphere": 200}}.get(name, {})
    scene = sl.load_scene(name, **params)
    view = default_view(name, scene, **params)
    gbuf = sl.render_gbuffer(scene, view.camera.replace(resolution=(24, 24)))
    truth = sl.reference_shadows(scene, gbuf, view.light)
    res = sl.compute_shadows(scene, gbuf, view.light, method="izb", precision=precision,
                             resolution=1024)
    assert res.counters["csm_false_shadows"] == 0
    assert len(unexplained_mismatches(scene, gbuf, view.light, res.lit, truth)) == 0


def test_chunked_pair_kernel_equals_one_chunk(monkeypatch):
    """Tracing in many chunks of static capacity (the pair count exceeds the chunk; with
    a chunk of 1 pair, rows wider than a chunk run one per call) gives the same lit mask
    and counters as one chunk: nothing is dropped at chunk borders."""

    scene, gbuf, light, truth = frame("steep")
    opts = dict(prepass="none", resolution=256)
    one = sl.compute_shadows(scene, gbuf, light, method="izb", **opts)
    assert one.counters["tests"] > 3 * 128 and one.counters["list_length_max"] > 1
    for chunk in (128, 1):
        monkeypatch.setattr(mizb, "PAIR_CHUNK", chunk)
        many = sl.compute_shadows(scene, gbuf, light, method="izb", **opts)
        assert np.array_equal(one.lit, many.lit)
        assert len(unexplained_mismatches(scene, gbuf, light, many.lit, truth)) == 0
        for k in one.counters:
            assert np.array_equal(np.asarray(one.counters[k]), np.asarray(many.counters[k])), k


def test_row_widths_are_the_lengths_rounded_up_to_powers_of_two():
    length = np.array([1, 2, 3, 4, 5, 8, 9, 1023, 1024, 1025])
    assert mizb.row_widths(length).tolist() == [1, 2, 4, 4, 8, 8, 16, 1024, 1024, 2048]


@pytest.mark.parametrize("precision", ["float32", "float64"])
def test_a_cut_that_reaches_the_light_is_never_culled(precision):
    """A point light just above the ground: the receiver cut of the grazing ground
    samples (eps / n.l) reaches the light, so the reference lights them whatever stands
    in between. The CSM must not cull them behind the wall that fully covers their
    texels (it did: q on the light's plane had an infinite light-space depth; found on
    the full-size izb_passes run)."""
    ground = prim.quad_grid((-6, 6), (-6, 6), 0.0, cells=4)
    wall = (np.array([[3.0, -1.0, -6.0], [3.0, -1.0, 6.0], [3.0, 3.0, 6.0], [3.0, 3.0, -6.0]]),
            np.array([[0, 1, 2], [0, 2, 3]]))
    v, f = prim.merge([ground, wall])
    scene = Scene(v, f, np.zeros(len(f)), ("g",), "reach")
    light = sl.PointLight(position=(5.0, 1e-5, 0.0))
    cam = sl.Camera(eye=(-4.0, 6.0, 0.0), target=(1.0, 0.0, 0.0), up=(0, 1, 0),
                    fov_y_deg=50.0, near=0.1, far=100.0, resolution=(24, 24))
    gbuf = sl.render_gbuffer(scene, cam)
    truth = sl.reference_shadows(scene, gbuf, light)
    res = sl.compute_shadows(scene, gbuf, light, method="izb", prepass="csm",
                             precision=precision, resolution=256)
    assert truth[gbuf.valid].any()                       # lit through the wall by the cut
    assert res.counters["csm_texels"] > 0                # the wall covers texels fully
    assert res.counters["csm_false_shadows"] == 0
    np.testing.assert_array_equal(res.lit[gbuf.valid], truth[gbuf.valid])
