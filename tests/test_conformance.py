"""Conformance of every registered method, driven by the registry.

The tests are parametrized over ``shadowlab.methods.names()`` at collection time, so a
newly registered method is covered without new test code. For every method, on two
small scenes (a closed gate and a triangle soup; soft methods under a sphere light; the
exact methods also on closed props resting on a slab) in float32 and float64:

- an exact method equals ``reference_shadows`` on valid pixels, except pixels that the
  float64 boundary analysis explains (``analysis.boundary``): no unexplained mismatch;
- every declared counter is present, and the counters are consistent: counts are ints
  >= 0, per-pixel maps are int arrays [H, W] >= 0, and a map sums (or maxes) to its
  total where both exist;
- two runs are bit-identical (lit and every counter);
- a bad value of every option, and an unknown option, are refused with a MethodError
  naming the method and the option, before any work.
"""

import functools

import numpy as np
import pytest

import shadowlab as sl
from shadowlab.reference.boundary import unexplained_mismatches
from shadowlab.core.counters import COUNTERS
from shadowlab.methods import MethodError, MethodKind, registry
from shadowlab.scene.procedural import default_view

METHODS = registry.names()
SCENES = ("gate", "soup")
#: the exact methods also run on closed props resting on a slab (vertices exactly on the
#: ground's top face: contact)
EXACT_SCENES = SCENES + ("props",)
RES = (32, 32)
PARAMS = {"soup": {"count": 200}, "props": {"count": 8, "triangles": 4000}}

#: per-pixel map -> the scalar it sums to
SUMS = {"tests_per_pixel": "tests", "visited_nodes_per_pixel": "visited_nodes",
        "stencil_updates_per_pixel": "stencil_updates",
        "stack_overflows_per_pixel": "stack_overflows",
        "stackless_switches_per_pixel": "stackless_switches",
        "rasterized_per_pixel": "rasterized_triangles",
        "csm_culled_per_pixel": "csm_culled"}
#: per-pixel map -> the scalar that is its maximum
MAXES = {"stack_max_per_pixel": "stack_max", "tile_triangles_per_pixel": "tile_triangles_max",
         "list_length_per_pixel": "list_length_max"}


@functools.lru_cache(maxsize=None)
def frame(scene_name: str, soft: bool):
    """(scene, gbuf, light) of a small view; a sphere light above the scene if ``soft``."""
    params = PARAMS.get(scene_name, {})
    scene = sl.load_scene(scene_name, **params)
    view = default_view(scene_name, scene, **params)
    light = view.light
    if soft:
        light = sl.SphereLight(position=np.asarray(light.position, float),
                               radius=0.05 * scene.diagonal)
    gbuf = sl.render_gbuffer(scene, view.camera.replace(resolution=RES))
    return scene, gbuf, light


@functools.lru_cache(maxsize=None)
def runs(method: str, scene_name: str, precision: str):
    """Two independent runs of ``method`` (default options) on the scene."""
    info = registry.get(method)
    scene, gbuf, light = frame(scene_name, info.soft)
    return tuple(sl.compute_shadows(scene, gbuf, light, method=method, precision=precision)
                 for _ in range(2))


def _cases(keep=lambda info: True, scenes=SCENES):
    return [pytest.param(m, s, id=f"{m}-{s}") for m in METHODS for s in scenes
            if keep(registry.get(m))]


CASES = _cases()
EXACT_CASES = _cases(lambda info: info.kind is MethodKind.EXACT, EXACT_SCENES)
SOFT_CASES = _cases(lambda info: info.soft)


@pytest.mark.parametrize("method,scene_name", EXACT_CASES)
def test_exact_methods_equal_the_reference(method, scene_name, precision):
    scene, gbuf, light = frame(scene_name, False)
    res = runs(method, scene_name, precision)[0]
    truth = sl.reference_shadows(scene, gbuf, light)
    assert res.lit.dtype == bool and res.lit.shape == gbuf.valid.shape
    assert not (res.lit & ~gbuf.valid).any()
    assert 0 < truth[gbuf.valid].sum() < gbuf.valid.sum()       # the view has shadows
    bad = unexplained_mismatches(scene, gbuf, light, res.lit, truth,
                                 res.options["shadow_eps"])
    assert len(bad) == 0, bad


@pytest.mark.parametrize("method,scene_name", SOFT_CASES)
def test_soft_methods_return_visibility(method, scene_name, precision):
    scene, gbuf, light = frame(scene_name, True)
    vis = runs(method, scene_name, precision)[0].lit
    assert vis.shape == gbuf.valid.shape and np.issubdtype(vis.dtype, np.floating)
    assert np.all((vis >= 0) & (vis <= 1))
    assert 0 < vis[gbuf.valid].mean() < 1


@pytest.mark.parametrize("method,scene_name", CASES)
def test_declared_counters_are_present_and_consistent(method, scene_name, precision):
    info = registry.get(method)
    assert info.counters is not None, f"{method} declares no counters"
    assert info.stages, f"{method} declares no timing stages"
    scene, gbuf, _ = frame(scene_name, info.soft)
    res = runs(method, scene_name, precision)[0]
    c = res.counters
    assert set(c) == set(info.counters)
    assert set(c) <= set(COUNTERS)
    for name, value in c.items():
        kind = COUNTERS[name].kind
        if kind == "int":
            assert isinstance(value, (int, np.integer)) and not isinstance(value, bool), name
            assert value >= 0, name
        elif kind == "float":
            assert isinstance(value, (float, np.floating)) and np.isfinite(value), name
            assert value >= 0, name
        elif kind == "map":
            assert np.shape(value) == gbuf.valid.shape, name
            assert np.issubdtype(np.asarray(value).dtype, np.integer), name
            assert np.all(value >= 0), name
        else:
            assert np.ndim(value) == 1 and np.all(np.asarray(value) >= 0), name
    for m, total in SUMS.items():
        if m in c and total in c:
            assert int(np.sum(c[m])) == c[total], (m, total)
    for m, top in MAXES.items():
        if m in c and top in c:
            assert int(np.max(c[m], initial=0)) == c[top] or top == "tile_triangles_max" \
                and int(np.max(c[m], initial=0)) <= c[top], (m, top)
    if "samples" in c:
        assert c["samples"] <= int(gbuf.valid.sum())
    if "casters" in c and "culled_triangles" in c:
        assert c["casters"] + c["culled_triangles"] == scene.num_triangles
    if "lit" in c and res.lit.dtype == bool:
        assert c["lit"] == int(res.lit.sum())
    if "shadowed" in c and "samples" in c:
        assert c["shadowed"] <= c["samples"]
    if "visited_nodes_mean" in c:
        assert c["visited_nodes_mean"] == pytest.approx(c["visited_nodes"] / max(c["samples"], 1))
    if "overflow_pixels" in c:
        assert c["overflow_pixels"] == int(np.count_nonzero(c["stack_overflows_per_pixel"]))
    stages = {k.removesuffix("_compile") for k in res.timings} - {"total"}
    assert stages <= set(info.stages)
    assert res.timings["total"] == pytest.approx(sum(
        v for k, v in res.timings.items() if k != "total" and not k.endswith("_compile")))
    assert res.method == method and res.options == registry.resolve_options(
        method, {"precision": precision})


def _same(a, b) -> bool:
    return a.dtype == b.dtype and np.array_equal(a, b) if isinstance(a, np.ndarray) else \
        type(a) is type(b) and a == b


@pytest.mark.parametrize("method,scene_name", CASES)
def test_two_runs_are_bit_identical(method, scene_name, precision):
    one, two = runs(method, scene_name, precision)
    assert one.lit.dtype == two.lit.dtype and np.array_equal(one.lit, two.lit)
    assert set(one.counters) == set(two.counters)
    diff = [k for k in one.counters if not _same(np.asarray(one.counters[k]) if np.ndim(
        one.counters[k]) else one.counters[k], np.asarray(two.counters[k]) if np.ndim(
        two.counters[k]) else two.counters[k])]
    assert diff == []


def _bad_value(spec):
    """A value the option must refuse."""
    if spec.allowed is not None:
        return "__not_allowed__"
    if spec.maximum is not None:
        return spec.maximum + 1
    if spec.minimum is not None:
        return spec.minimum - 1
    return "__not_a_number__"


@pytest.mark.parametrize("method", METHODS)
def test_bad_and_unknown_options_are_refused(method):
    info = registry.get(method)
    scene, gbuf, light = frame("gate", info.soft)
    for option, spec in info.options.items():
        bad = _bad_value(spec)
        with pytest.raises(MethodError) as err:
            sl.compute_shadows(scene, gbuf, light, method=method, **{option: bad})
        msg = str(err.value)
        assert repr(method) in msg and f"{option}={bad!r}" in msg, msg
        assert registry.resolve_options(method, {option: spec.default})[option] == spec.default
    with pytest.raises(MethodError, match=f"'{method}': unknown option.*no_such_option"):
        sl.compute_shadows(scene, gbuf, light, method=method, no_such_option=1)


#: float64 runs of the culling check (compiles are the cost; every method runs float32)
CULL_FLOAT64 = ("brute_force", "silhouette", "psv", "izb")


@pytest.mark.parametrize("method,precision", [
    pytest.param(m, p, id=f"{m}-{p}") for m in METHODS
    if registry.get(m).kind is MethodKind.EXACT
    for p in ("float32", "float64") if p == "float32" or m in CULL_FLOAT64])
def test_caster_culling_leaves_the_lit_mask_unchanged(method, precision):
    """The shared cull_casters stage (every step: the hull, light-averted triangles of
    closed objects, triangles behind the receivers) removes work, never a shadow: the lit
    mask is bit-identical to the unculled run's."""
    scene, gbuf, light = frame("gate", False)
    plain = runs(method, "gate", precision)[0]
    culled = sl.compute_shadows(scene, gbuf, light, method=method, precision=precision,
                                cull_casters="all")
    np.testing.assert_array_equal(culled.lit, plain.lit)
    c = culled.counters
    assert c["culled_casters"] == (c["culled_casters_hull"] + c["culled_casters_averted"]
                                   + c["culled_casters_receivers"])
    assert c["culled_casters_averted"] > 0          # gate's parts are closed
    assert c["culled_casters_receivers"] > 0
    assert "cull_casters" in culled.timings and "culled_casters" not in plain.counters
