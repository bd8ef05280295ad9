"""The Warp kernels follow the frame-local precision model: far from the world origin
they still equal the JAX methods bit for bit (lit masks and integer counters)."""

import numpy as np
import pytest

wp = pytest.importorskip("warp")

import shadowlab as sl  # noqa: E402
from shadowlab.methods import registry  # noqa: E402
from shadowlab.scene import procedural  # noqa: E402

# counters one side has and the other has not (docs/kernels.md)
ONE_SIDED = {"cas_failures", "frontier_max", "build_rounds", "query_chunks"}


@pytest.mark.parametrize("method,cull", [("clustered_ptsv", "off"), ("d_hybrid", "off"),
                                         ("d_hybrid", "hull_averted")])
def test_kernels_equal_methods_far_from_the_origin(method, cull):
    """... also with the shared caster culling stage, which run_kernel applies as
    compute_shadows does."""
    params = {"blocks": 3, "posts": 6, "defects": 1, "offset": [1e5, -3e4, 1e5]}
    scene = procedural.make("city", **params)
    view = procedural.default_view("city", scene, **params)
    gbuf = sl.render_gbuffer(scene, view.camera.replace(resolution=(40, 40)))
    assert np.any(gbuf.origin != 0)
    jax_res = sl.compute_shadows(scene, gbuf, view.light, method=method, cull_casters=cull)
    k_res = registry.run_kernel(scene, gbuf, view.light, method, cull_casters=cull)
    assert (cull == "off") == ("culled_casters" not in k_res.counters)
    assert np.array_equal(k_res.lit, jax_res.lit)
    truth = sl.reference_shadows(scene, gbuf, view.light)
    assert np.array_equal(k_res.lit[gbuf.valid], truth[gbuf.valid])
    shared = (set(k_res.counters) & set(jax_res.counters)) - ONE_SIDED
    assert {"samples", "lit"} <= shared
    for name in shared:
        a, b = np.asarray(k_res.counters[name]), np.asarray(jax_res.counters[name])
        if np.issubdtype(a.dtype, np.integer) and np.issubdtype(b.dtype, np.integer):
            assert np.array_equal(a, b), name
