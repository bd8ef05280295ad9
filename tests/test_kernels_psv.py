"""PSV kernels (Warp, CPU backend) against the JAX methods and the Embree reference:
the tree node for node, lit masks and every integer counter exactly."""

import numpy as np
import pytest

wp = pytest.importorskip("warp")

import shadowlab as sl  # noqa: E402
from shadowlab import kernels  # noqa: E402
from shadowlab.kernels import psv as kpsv  # noqa: E402
from shadowlab.structures import top_tree as tt  # noqa: E402
from shadowlab.methods.registry import resolve_options  # noqa: E402
from shadowlab.scene.procedural import default_view  # noqa: E402

SCENES = {
    "gate": ({"trees": 3, "leaves_per_tree": 60, "bars": 4}, 64),
    "sphere_grid": ({"n": 3, "triangles_per_sphere": 120}, 32),
    "soup": ({"count": 80}, 64),
}
_CACHE = {}


def _scene(name):
    if name not in _CACHE:
        params, res = SCENES[name]
        scene = sl.load_scene(name, **params)
        view = default_view(name, scene, **params)
        gbuf = sl.render_gbuffer(scene, view.camera.replace(resolution=(res, res)))
        _CACHE[name] = scene, view.light, gbuf, sl.reference_shadows(scene, gbuf, view.light)
    return _CACHE[name]


def _input(name, **options):
    scene, light, gbuf, _ = _scene(name)
    o = resolve_options("d_psv", options)
    return kpsv.prepare(scene, gbuf, light, o)


KERNEL_ONLY = {"cas_failures"}


def _same_counters(a, b):
    """Names of counters that differ (the kernel omits build_rounds and query_chunks and
    adds cas_failures, 0 in the CPU backend's rank-order schedule)."""
    assert b.counters["cas_failures"] == 0
    diff = []
    for k, v in b.counters.items():
        if k in KERNEL_ONLY:
            continue
        if not np.array_equal(np.asarray(a.counters[k]), np.asarray(v)):
            diff.append(k)
    missing = set(a.counters) - set(b.counters) - {"build_rounds", "query_chunks"}
    return diff + sorted(missing)


@pytest.mark.parametrize("name", list(SCENES))
def test_tree_equals_jax_build(name):
    _, inp, _, _, _ = _input(name)
    jtree = tt.build_parallel(inp)
    for schedule in ("threads", "serial"):
        ktree, stats = kpsv.build_tree(inp, schedule=schedule)
        assert ktree.same_as(jtree) == [], schedule
        assert stats["cas_failures"] == 0


def test_tree_equals_sequential_build_all_wedges():
    _, inp, _, _, _ = _input("soup")
    for wedge in tt.WEDGES:
        ktree, _ = kpsv.build_tree(inp, wedge)
        assert ktree.same_as(tt.build_sequential(inp, wedge)) == [], wedge


@pytest.mark.parametrize("name", list(SCENES))
@pytest.mark.parametrize("method", kernels.PSV_METHODS)
def test_method_equals_jax_and_reference(name, method):
    scene, light, gbuf, truth = _scene(name)
    j = sl.compute_shadows(scene, gbuf, light, method=method)
    k = kernels.compute_shadows(scene, gbuf, light, method=method)
    assert np.array_equal(k.lit, j.lit)
    assert _same_counters(j, k) == []
    ok = gbuf.valid
    if "stack_overflows_per_pixel" in k.counters:
        ok = ok & (k.counters["stack_overflows_per_pixel"] == 0)
    assert np.count_nonzero((k.lit != truth) & ok) == 0


@pytest.mark.parametrize("method,options", [
    ("psv", {"stack_size": 2}),                       # overflows (lost subtrees)
    ("d_hybrid", {"stack_size": 2}),                  # stackless switches
    ("d_hybrid", {"stack_size": 1, "stackless_cap": "public"}),
    ("d_stackless", {"wedge": "vertex"}),
    ("d_psv", {"wedge": "off", "edge_tie": "outside", "order": "distance"}),
    ("d_psv", {"classify_ulps": 0, "order": "mesh", "bias": "cap"}),
    ("d_hybrid", {"wedge": "signed", "stack_size": 2}),
    ("d_stackless", {"wedge": "signed"}),
])
def test_options_equal_jax(method, options):
    scene, light, gbuf, _ = _scene("gate")
    j = sl.compute_shadows(scene, gbuf, light, method=method, **options)
    k = kernels.compute_shadows(scene, gbuf, light, method=method, **options)
    assert np.array_equal(k.lit, j.lit)
    assert _same_counters(j, k) == []
    if options.get("stack_size", 32) <= 2:
        key = "stack_overflows" if method == "psv" else "stackless_switches"
        assert k.counters[key] > 0


def test_other_arrival_order_changes_the_tree_not_the_shadows():
    """Threads arriving in another order (as on a GPU) build another valid TOP tree:
    the schedule-dependent counters change, the lit mask does not."""
    scene, light, gbuf, truth = _scene("gate")
    samples, inp, scale, key, light_h = _input("gate")
    jtree = tt.build_parallel(inp)
    order = np.arange(inp.count)[::-1]
    ktree, _ = kpsv.build_tree(inp, thread_order=order)
    assert "pos" in ktree.same_as(jtree)
    assert ktree.root == 4 * (inp.count - 1)
    args = (samples.position.astype(np.float32), scale.astype(np.float32),
            key.astype(np.float32), light_h)
    opts = dict(query="hybrid", depth_test=True, wedge="conservative", stack_size=12)
    a = kpsv.query(jtree, *args, **opts)
    b = kpsv.query(ktree, *args, **opts)
    assert not np.array_equal(a["visited"], b["visited"])
    lit = samples.scatter(~b["shadow"], fill=False)
    assert np.count_nonzero((lit != truth) & gbuf.valid) == 0


@pytest.mark.parametrize("method", ["psv", "d_stackless", "d_hybrid"])
def test_directional_light_equals_jax_and_reference(method):
    """A light at infinity (homogeneous w = 0): no wedge distance, edge planes through
    the direction; same tree, lit mask and counters as the JAX method."""
    scene, light, gbuf, _ = _scene("gate")
    centre = scene.triangles.reshape(-1, 3).mean(0)
    sun = sl.DirectionalLight(direction=centre - np.asarray(light.position, float))
    truth = sl.reference_shadows(scene, gbuf, sun)
    j = sl.compute_shadows(scene, gbuf, sun, method=method)
    k = kernels.compute_shadows(scene, gbuf, sun, method=method)
    assert np.array_equal(k.lit, j.lit)
    assert _same_counters(j, k) == []
    assert 0 < k.counters["shadowed"] < k.counters["samples"]
    assert np.count_nonzero((k.lit != truth) & gbuf.valid) == 0


def test_float64_is_refused():
    scene, light, gbuf, _ = _scene("soup")
    with pytest.raises(ValueError, match="float32"):
        kernels.compute_shadows(scene, gbuf, light, method="psv", precision="float64")
