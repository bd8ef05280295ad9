"""The IZB kernels (Warp, CPU: a serial schedule) equal the JAX method: the same lit
mask and every counter identical (list lengths and order, traced and depth-culled
fragments, tests per pixel), with and without the CSM prepass, float32 and float64, for
a point light (perspective face and cube) and a directional light."""

import functools

import numpy as np
import pytest

pytest.importorskip("warp")

import shadowlab as sl  # noqa: E402
from shadowlab import kernels  # noqa: E402
from shadowlab.scene.procedural import default_view  # noqa: E402

LIGHTS = {"point": None, "directional": sl.DirectionalLight(direction=(-0.4, -1.0, 0.3))}


@functools.lru_cache(maxsize=None)
def frame(light_name):
    scene = sl.load_scene("sphere_grid", n=3, triangles_per_sphere=200)
    view = default_view("sphere_grid", scene, n=3, triangles_per_sphere=200)
    gbuf = sl.render_gbuffer(scene, view.camera.replace(resolution=(40, 40)))
    return scene, gbuf, LIGHTS[light_name] or view.light


@pytest.mark.parametrize("light_name,projection", [("point", "auto"), ("point", "cube"),
                                                   ("directional", "auto")])
@pytest.mark.parametrize("prepass", ["none", "csm"])
def test_kernels_equal_the_jax_method(light_name, projection, prepass, precision):
    scene, gbuf, light = frame(light_name)
    opts = dict(prepass=prepass, precision=precision, projection=projection, resolution=512)
    a = sl.compute_shadows(scene, gbuf, light, method="izb", **opts)
    b = kernels.compute_shadows(scene, gbuf, light, method="izb", **opts)
    assert np.array_equal(a.lit, b.lit)
    assert a.counters.keys() == b.counters.keys()
    for k in a.counters:
        assert np.array_equal(np.asarray(a.counters[k]), np.asarray(b.counters[k])), k
    assert a.counters["tests"] > 0 and a.counters["list_nodes"] > 0
    if prepass == "csm":
        assert b.counters["csm_false_shadows"] == 0
