"""brute_force: equal to the Embree reference on every valid pixel; counters exact."""

import numpy as np
import pytest

import shadowlab as sl
from shadowlab.methods import MethodError
from shadowlab.scene.procedural import GENERATORS, default_view
from scenes import sphere_over_plane

SMALL = {"sphere_grid": {"n": 3, "triangles_per_sphere": 128}, "gate": {"trees": 5},
         "fuzzy": {"triangles": 2000}, "terrain": {"size": 40}, "blobs": {"grid": 20},
         "soup": {"count": 40}, "atrium": {"bays": 3, "segments": 8, "banners": 4},
         "city": {"blocks": 3, "posts": 6, "defects": 1, "offset": [1e5, 0.0, -1e5]},
         "props": {"count": 6, "triangles": 1500}}


@pytest.mark.parametrize("name", sorted(GENERATORS))
def test_equals_reference_on_every_procedural_scene(name, precision):
    scene = sl.load_scene(name, **SMALL[name])
    view = default_view(name, scene, **SMALL[name])
    gbuf = sl.render_gbuffer(scene, view.camera.replace(resolution=(72, 64)))
    truth = sl.reference_shadows(scene, gbuf, view.light)
    res = sl.compute_shadows(scene, gbuf, view.light, method="brute_force", precision=precision)
    assert res.lit.shape == (64, 72) and res.lit.dtype == bool
    assert np.array_equal(res.lit[gbuf.valid], truth[gbuf.valid])
    assert not res.lit[~gbuf.valid].any()
    assert res.counters["lit"] == int(truth.sum())


@pytest.mark.parametrize("light", [sl.PointLight((1.0, 6.0, 0.5)),
                                   sl.DirectionalLight((0.4, -1.0, -0.3)),
                                   sl.SphereLight(position=(-1.0, 5.0, 1.0), radius=0.3)])
def test_equals_reference_for_every_light_type(light, precision):
    scene = sphere_over_plane(subdivisions=3)
    cam = sl.Camera(eye=(0, 6, 7), target=(0, 0.5, 0), resolution=(64, 64), near=0.5, far=40)
    gbuf = sl.render_gbuffer(scene, cam)
    truth = sl.reference_shadows(scene, gbuf, light)
    res = sl.compute_shadows(scene, gbuf, light, precision=precision)
    assert np.array_equal(res.lit, truth)
    assert 0 < truth.sum() < gbuf.valid.sum()


def test_counters_match_a_plain_loop():
    """Tests = samples x casters; shadowed samples from a per-pair NumPy loop."""
    scene = sl.load_scene("soup", count=12)
    view = default_view("soup", scene)
    gbuf = sl.render_gbuffer(scene, view.camera.replace(resolution=(24, 24)))
    res = sl.compute_shadows(scene, gbuf, view.light, precision="float64")
    light = view.light.position
    facing = gbuf.valid & (np.einsum("hwi,hwi->hw", gbuf.normal, light - gbuf.position) > 0)
    eps = 1e-5 * scene.diagonal
    shadowed = np.zeros(gbuf.valid.shape, bool)
    for (i, j) in zip(*np.nonzero(facing)):
        p, n = gbuf.position[i, j], gbuf.normal[i, j]
        for a, b, c in scene.triangles:
            # segment p -> light crosses the triangle more than eps above p's tangent plane
            e1, e2, d = b - a, c - a, light - p
            h = np.cross(d, e2)
            det = e1 @ h
            if abs(det) < 1e-14:
                continue
            s = p - a
            u = (s @ h) / det
            q = np.cross(s, e1)
            v = (d @ q) / det
            t = (e2 @ q) / det
            if u >= 0 and v >= 0 and u + v <= 1 and 0 < t < 1 and t * (n @ d) > eps:
                shadowed[i, j] = True
    assert np.array_equal(~res.lit[facing], shadowed[facing])
    report = scene.report()
    assert res.counters["samples"] == facing.sum()
    assert res.counters["casters"] + res.counters["culled_triangles"] == scene.num_triangles
    assert res.counters["culled_triangles"] >= report.degenerate_triangles
    assert res.counters["tests"] == res.counters["samples"] * res.counters["casters"]
    assert res.counters["tests_per_pixel"].sum() == res.counters["tests"]
    assert res.counters["shadowed"] == shadowed[facing].sum()


def test_cap_bias_mode_differs_only_at_contacts():
    scene = sl.load_scene("terrain", size=40)
    view = default_view("terrain", scene)
    gbuf = sl.render_gbuffer(scene, view.camera.replace(resolution=(64, 64)))
    truth = sl.reference_shadows(scene, gbuf, view.light)
    res = sl.compute_shadows(scene, gbuf, view.light, bias="cap")
    mismatch = (res.lit != truth)[gbuf.valid].mean()
    assert mismatch < 0.005


def test_options_are_validated():
    scene = sphere_over_plane(subdivisions=1)
    cam = sl.Camera(eye=(0, 6, 7), target=(0, 0.5, 0), resolution=(8, 8))
    gbuf = sl.render_gbuffer(scene, cam)
    light = sl.PointLight((0, 5, 0))
    with pytest.raises(MethodError, match="allowed values: 4, 8, 16, 32"):
        sl.compute_shadows(scene, gbuf, light, chunk=5)
    with pytest.raises(MethodError, match="unknown option"):
        sl.compute_shadows(scene, gbuf, light, chunks=8)
    with pytest.raises(MethodError, match="unknown method 'nope'"):
        sl.compute_shadows(scene, gbuf, light, method="nope")
    with pytest.raises(MethodError, match="float32"):
        sl.compute_shadows(scene, gbuf, light, precision="half")


def test_deterministic_and_timed():
    scene = sphere_over_plane(subdivisions=2)
    cam = sl.Camera(eye=(0, 6, 7), target=(0, 0.5, 0), resolution=(32, 32))
    gbuf = sl.render_gbuffer(scene, cam)
    light = sl.PointLight((1, 6, 0))
    a = sl.compute_shadows(scene, gbuf, light)
    b = sl.compute_shadows(scene, gbuf, light)
    assert np.array_equal(a.lit, b.lit)
    assert a.scalar_counters() == b.scalar_counters()
    assert {"setup", "test", "total"} <= set(b.timings)
    assert b.timings["setup_compile"] == 0.0      # compiled once, reused


# --------------------------------------------------------------------------- setup rounding

def _numpy_setup(tri, light):
    """shadow_volume_planes as plain NumPy, one IEEE operation at a time (NumPy never fuses
    a multiply into an add): planes [T, 16], valid [T]."""
    dt = tri.dtype.type
    tol = dt(64 * np.finfo(dt).eps)
    lx, ly, lz, lw = (dt(x) for x in light)

    def dot(a, b):
        return (a[0] * b[0] + a[1] * b[1]) + a[2] * b[2]

    def cross(a, b):
        return [a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2],
                a[0] * b[1] - a[1] * b[0]]

    def oriented(n, d, flip):
        n = [np.where(flip, -x, x) for x in n]
        d = np.where(flip, -d, d)
        length = np.sqrt(dot(n, n))
        safe = np.where(length > 0, length, dt(1))
        return [n[0] / safe, n[1] / safe, n[2] / safe, d / safe], length

    v = [[tri[:, i, k] for k in range(3)] for i in range(3)]
    cols, ok = [], np.ones(len(tri), bool)
    for i in range(3):
        a, b, c = v[i], v[(i + 1) % 3], v[(i + 2) % 3]
        swap = (b[0] < a[0]) | ((b[0] == a[0]) & ((b[1] < a[1]) | ((b[1] == a[1]) & (b[2] < a[2]))))
        lo = [np.where(swap, b[k], a[k]) for k in range(3)]
        hi = [np.where(swap, a[k], b[k]) for k in range(3)]
        n = cross([hi[k] - lo[k] for k in range(3)],
                  [lx - lw * lo[0], ly - lw * lo[1], lz - lw * lo[2]])
        d = -dot(n, lo)
        side = dot(n, [c[k] - lo[k] for k in range(3)])
        plane, length = oriented(n, d, side < 0)
        ca, cb = [c[k] - a[k] for k in range(3)], [c[k] - b[k] for k in range(3)]
        reach = np.maximum(np.sqrt(dot(ca, ca)), np.sqrt(dot(cb, cb)))
        ok &= (length > 0) & (np.abs(side) > (tol * length) * reach)
        cols += plane
    cn = cross([v[1][k] - v[0][k] for k in range(3)], [v[2][k] - v[0][k] for k in range(3)])
    cd = -dot(cn, v[0])
    tl = [lx - lw * v[0][0], ly - lw * v[0][1], lz - lw * v[0][2]]
    ls = dot(cn, tl)
    plane, length = oriented(cn, cd, ls < 0)
    ok &= (length > 0) & (np.abs(ls) > (tol * length) * np.sqrt(dot(tl, tl)))
    return np.stack(cols + plane, axis=1), ok


def _numpy_post(planes, inv_view, qmax, pmax, extra, p00, p11):
    """volume_planes.post_perspective_planes as plain NumPy: g [T, 7, 4], tol [T, 7]."""
    dt = planes.dtype.type
    u = dt(np.finfo(dt).eps)
    qmax, pmax = dt(qmax), dt(pmax)
    r00, r11 = dt(1.0 / p00), dt(1.0 / p11)
    p = planes.reshape(-1, 4, 4)
    t = len(p)
    rows, slack, wv = [], [], []
    for i in range(4):
        w = [((p[:, i, 0] * inv_view[0, j] + p[:, i, 1] * inv_view[1, j])
              + p[:, i, 2] * inv_view[2, j]) + p[:, i, 3] * inv_view[3, j] for j in range(4)]
        wv.append(w)
        rows.append([w[0] * r00, w[1] * r11, w[3], -w[2]])
        s3 = (np.abs(p[:, i, 0]) + np.abs(p[:, i, 1])) + np.abs(p[:, i, 2])
        slack.append((s3 * pmax + np.abs(p[:, i, 3])) * (qmax * (dt(4) * u)))
    for a, b in ((0, 2), (0, 1), (1, 2)):
        never = [np.zeros(t, dt), np.zeros(t, dt), np.zeros(t, dt), np.ones(t, dt)]
        if extra == "culling":
            n = p[:, a, :3] + p[:, b, :3]
            ok = np.sqrt((n[:, 0] * n[:, 0] + n[:, 1] * n[:, 1]) + n[:, 2] * n[:, 2]) > dt(1e-3)
            row = [rows[a][k] + rows[b][k] for k in range(4)]
            sl = slack[a] + slack[b]
        else:                                                       # silhouette
            ea, eb = wv[a][3], wv[b][3]
            ok = ea * eb < 0
            row = [np.abs(eb) * rows[a][k] + np.abs(ea) * rows[b][k] for k in range(4)]
            sl = np.abs(eb) * slack[a] + np.abs(ea) * slack[b]
        rows.append([np.where(ok, x, y) for x, y in zip(row, never)])
        slack.append(np.where(ok, sl, dt(0)))
    g = np.stack([np.stack(r, axis=-1) for r in rows], axis=1)
    mag = ((np.abs(g[..., 0]) + np.abs(g[..., 1])) + np.abs(g[..., 2]) * qmax) + np.abs(g[..., 3])
    return g, mag * (dt(64) * u) + np.stack(slack, axis=1)


SETUP_SCENES = {"gate": {"trees": 3, "leaves_per_tree": 60, "bars": 4},
                "sphere_grid": {"n": 3, "triangles_per_sphere": 120}, "soup": {"count": 80}}


def test_setup_rounding_is_the_same_at_every_size(precision):
    """shadow_volume_planes and post_perspective_planes equal a NumPy op-by-op loop bit for
    bit, on the triangles as they are and padded to the capacity clustered_ptsv pads
    them to (XLA's FMA contraction used to depend on that size)."""
    import jax.numpy as jnp

    from shadowlab.geometry.triangle_setup import shadow_volume_planes as setup
    from shadowlab.core.frame import precision_mode
    from shadowlab.geometry.volume_planes import post_perspective_planes
    from shadowlab.scene.view import hard_light

    with precision_mode(precision) as dt:
        for name, params in SETUP_SCENES.items():
            scene = sl.load_scene(name, **params)
            view = default_view(name, scene, **params)
            light = hard_light(view.light).homogeneous.astype(dt)
            tri = scene.triangles.astype(dt)
            n = len(tri)
            want, want_ok = _numpy_setup(tri, light)
            assert 0 < want_ok.sum() <= n
            iv = np.linalg.inv(view.camera.view_matrix()).astype(dt)
            qmax, pmax = dt(0.37), dt(np.abs(tri).max())
            for cap in (n, 2048):
                padded = np.zeros((cap, 3, 3), dt)
                padded[:n] = tri
                planes, ok = setup(jnp.asarray(padded), jnp.asarray(light))
                np.testing.assert_array_equal(np.asarray(planes)[:n], want)
                np.testing.assert_array_equal(np.asarray(ok)[:n], want_ok)
                assert np.asarray(planes).dtype == dt
                for extra in (("culling", "silhouette") if cap == 2048 else ("culling",)):
                    g, tol = post_perspective_planes(
                        planes.reshape(-1, 4, 4), jnp.asarray(iv), jnp.asarray(qmax),
                        jnp.asarray(pmax), extra=extra, p00=1.37, p11=1.81)
                    wg, wtol = _numpy_post(np.asarray(planes)[:n], iv, qmax, pmax, extra,
                                           1.37, 1.81)
                    np.testing.assert_array_equal(np.asarray(g)[:n], wg)
                    np.testing.assert_array_equal(np.asarray(tol)[:n], wtol)


def test_bias_scale_against_a_plain_loop():
    """The receiver bias scale n . (L.xyz - L.w p) - eps L.w per sample (point and
    directional lights), against a per-sample loop in float64; "cap" mode is all ones."""
    from shadowlab.core.frame import Samples, bias_scale

    rng = np.random.default_rng(5)
    pos = rng.normal(size=(300, 3)) * 20 + [1e4, 0.0, -1e4]
    nrm = rng.normal(size=(300, 3))
    nrm /= np.linalg.norm(nrm, axis=1, keepdims=True)
    samples = Samples(np.arange(300), pos, nrm, (15, 20))
    for light_h in (np.array([1e4 + 5.0, 80.0, -1e4 + 3.0, 1.0]), np.array([0.2, 0.9, 0.1, 0.0])):
        got = bias_scale(samples, light_h, 1e-3, "receiver")
        want = [sum(n[i] * (light_h[i] - light_h[3] * p[i]) for i in range(3)) - 1e-3 * light_h[3]
                for p, n in zip(pos, nrm)]
        np.testing.assert_allclose(got, want, rtol=1e-12, atol=1e-9)
    assert np.array_equal(bias_scale(samples, light_h, 1e-3, "cap"), np.ones(300))
