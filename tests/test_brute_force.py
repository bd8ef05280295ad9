"""brute_force: equal to the Embree reference on every valid pixel; counters exact."""

import numpy as np
import pytest

import shadowlab as sl
from shadowlab.methods import MethodError
from shadowlab.scene.procedural import GENERATORS, default_view
from scenes import sphere_over_plane

SMALL = {"sphere_grid": {"n": 3, "triangles_per_sphere": 128}, "gate": {"trees": 5},
         "fuzzy": {"triangles": 2000}, "terrain": {"size": 40}, "blobs": {"grid": 20},
         "soup": {"count": 40}}


@pytest.mark.parametrize("name", sorted(GENERATORS))
def test_equals_reference_on_every_procedural_scene(name, precision):
    scene = sl.load_scene(name, **SMALL[name])
    view = default_view(name, scene)
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
