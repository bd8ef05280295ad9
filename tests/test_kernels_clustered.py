"""Clustered PTSV kernels (Warp, CPU backend) against the JAX method and the Embree
reference: setup and hierarchy bit for bit, lit masks, every integer counter, the
iterations of every job (per caster; per (triangle, node) job in two passes)."""

import functools

import numpy as np
import pytest

wp = pytest.importorskip("warp")

import shadowlab as sl
from shadowlab.kernels import clustered_ptsv as kc
from shadowlab.methods.clustered_ptsv import run_traversal_method
from shadowlab.methods.registry import resolve_options
from shadowlab.scene.procedural import default_view

SCENES = {
    "gate": ({"trees": 3, "leaves_per_tree": 60, "bars": 4}, 64),
    "sphere_grid": ({"n": 3, "triangles_per_sphere": 120}, 32),
    "soup": ({"count": 80}, 64),
}


@functools.cache
def _scene(name, directional=False):
    params, res = SCENES[name]
    scene = sl.load_scene(name, **params)
    view = default_view(name, scene, **params)
    light = view.light
    if directional:
        centre = scene.triangles.reshape(-1, 3).mean(0)      # light travels the same way
        light = sl.DirectionalLight(direction=centre - np.asarray(light.position, float))
    gbuf = sl.render_gbuffer(scene, view.camera.replace(resolution=(res, res)))
    return scene, light, gbuf, sl.reference_shadows(scene, gbuf, light)


_JAX = {}


def _jax(name, directional=False, **opts):
    key = (name, directional, tuple(sorted(opts.items())))
    if key not in _JAX:
        scene, light, gbuf, _ = _scene(name, directional)
        o = resolve_options("clustered_ptsv", opts)
        _JAX[key] = run_traversal_method(scene, gbuf, light, kind="cluster",
                                         method="clustered_ptsv", options=o, **o)
    return _JAX[key]


def _differing(j, k):
    """Counters of the kernel result that differ from the JAX result."""
    return [c for c, v in k.counters.items()
            if not np.array_equal(np.asarray(v), np.asarray(j.counters[c]))]


def _pass2_jobs(tri, node, iters):
    return {(int(t), int(n)): int(i) for t, n, i in zip(tri, node, iters)}


def _check_equal(name, form, directional=False, job_order=None, **opts):
    scene, light, gbuf, truth = _scene(name, directional)
    j, det = _jax(name, directional, **opts)
    k, kd = kc.run_details(scene, gbuf, light, form=form, job_order=job_order, **opts)
    assert np.array_equal(k.lit, j.lit)
    assert _differing(j, k) == []
    assert set(j.counters) - set(k.counters) == {"frontier_max"}
    np.testing.assert_array_equal(kd["iterations_pass1"], det["iterations_pass1"])
    if resolve_options("clustered_ptsv", opts)["passes"] == 2:
        want = _pass2_jobs(det["pass2_triangles"], det["pass2_nodes"], det["iterations_pass2"])
        got = _pass2_jobs(kd["pass2_triangles"], kd["pass2_nodes"], kd["iterations_pass2"])
        assert len(want) == len(det["pass2_triangles"]) and got == want
    assert np.count_nonzero((k.lit != truth) & gbuf.valid) == 0
    return k, kd


@pytest.mark.parametrize("name", list(SCENES))
def test_setup_is_bit_exact(name):
    """The setup kernel equals the JAX setup bit for bit: world planes and validity
    (``brute_force.setup``), post-perspective rows, extra planes and tolerances
    (``post_perspective_planes``), both as the JAX method computes them (triangles
    padded to its capacity) and on the unpadded triangles; keys and casters too."""
    import jax.numpy as jnp

    from shadowlab.methods.brute_force import setup
    from shadowlab.methods.volume_planes import post_perspective_planes
    from shadowlab.scene.view import hard_light

    scene, light, gbuf, _ = _scene(name)
    _, det = _jax(name)
    p = kc.prepare(scene, gbuf, light, resolve_options("clustered_ptsv", {}))
    n = scene.num_triangles
    f32 = np.float32
    assert p["planes"].dtype == f32 and np.asarray(det["planes"]).shape[0] > n   # padded
    np.testing.assert_array_equal(p["planes"], np.asarray(det["planes"])[:n])
    np.testing.assert_array_equal(p["g"], np.asarray(det["g"])[:n])
    np.testing.assert_array_equal(p["tol"], np.asarray(det["tol"])[:n])
    np.testing.assert_array_equal(p["bound"], np.asarray(det["bound"])[:n])
    assert 0 < p["valid"].sum() and p["g"][:, 4:].any()
    # unpadded JAX setup: the same values (no shape-dependent rounding)
    light_h = hard_light(light).homogeneous
    planes, valid = setup(jnp.asarray(scene.triangles.astype(f32)),
                          jnp.asarray(light_h.astype(f32)))
    np.testing.assert_array_equal(p["valid"], np.asarray(valid))
    np.testing.assert_array_equal(p["planes"], np.asarray(planes))
    tree = p["tree"]
    inv_view = jnp.asarray(np.linalg.inv(gbuf.camera.view_matrix()).astype(f32))
    qmax, pmax = f32(p["coords"][:, 2].max()), f32(np.abs(p["samples"].position).max())
    g, tol = post_perspective_planes(planes.reshape(-1, 4, 4), inv_view, jnp.asarray(qmax),
                                     jnp.asarray(pmax), extra="culling", p00=tree.p00,
                                     p11=tree.p11)
    np.testing.assert_array_equal(p["g"], np.asarray(g))
    np.testing.assert_array_equal(p["tol"], np.asarray(tol))
    # the post-perspective part alone, from given world planes
    q = kc.triangle_setup(scene.triangles.astype(f32), light_h, gbuf.camera, tree, qmax, pmax,
                          world_planes=(np.asarray(planes), np.asarray(valid)))
    np.testing.assert_array_equal(q["g"], np.asarray(g))
    np.testing.assert_array_equal(q["tol"], np.asarray(tol))
    np.testing.assert_array_equal(p["keys"], np.asarray(det["keys"])[: len(p["keys"])])
    np.testing.assert_array_equal(p["casters"], det["casters"])


@pytest.mark.parametrize("storage", ["compact", "full"])
@pytest.mark.parametrize("form", kc.FORMS)
def test_hierarchy_equals_jax(storage, form):
    scene, light, gbuf, _ = _scene("gate")
    _, det = _jax("gate", storage=storage)
    p = kc.prepare(scene, gbuf, light, resolve_options("clustered_ptsv", {"storage": storage}))
    h = kc.build_hierarchy(p["tree"], p["table"], p["keys"], p["coords"], p["scale"], storage,
                           form).host()
    jh = det["hierarchy"]
    assert h["counts"] == list(jh.counts)
    for lvl in range(p["tree"].levels):
        np.testing.assert_array_equal(h["masks"][lvl], np.asarray(jh.masks[lvl]))
        exists = np.asarray(jh.exists[lvl])
        if storage == "compact":
            np.testing.assert_array_equal(h["ptr"][lvl], np.asarray(jh.ptr[lvl]))
            rows = np.arange(jh.counts[lvl])
        else:
            rows = np.flatnonzero(exists)
        for a in ("lo", "hi", "smin"):
            np.testing.assert_array_equal(h[a][lvl][rows], np.asarray(getattr(jh, a)[lvl])[rows])


@pytest.mark.parametrize("name", list(SCENES))
@pytest.mark.parametrize("form", kc.FORMS)
def test_method_equals_jax_and_reference(name, form):
    k, _ = _check_equal(name, form)
    assert k.counters["tests"] > 0 and k.counters["node_tests"] > 0
    if name == "gate":
        assert k.counters["trivial_accepts"] > 0


@pytest.mark.parametrize("opts", [
    {"bounds": "implicit", "culling_planes": False},
    {"storage": "full", "passes": 2, "expand_level": 2},
    {"passes": 2, "expand_level": 5, "front_face_culling": True},
    {"bias": "cap", "leaf_samples": "cluster", "depth_slices": "scaled"},
    {"z_bits": 4, "bounds": "implicit", "passes": 2, "expand_level": 3},
])
def test_options_equal_jax(opts):
    for form in kc.FORMS:
        _check_equal("gate", form, **opts)


def test_directional_light_equals_jax():
    for form in kc.FORMS:
        _check_equal("soup", form, directional=True)
        _check_equal("gate", form, directional=True, passes=2, expand_level=3)


def test_job_order_does_not_matter_without_pruning():
    """Without pruning every counter is a sum over jobs that do not interact: another
    job order (a GPU's schedule) gives the same counters and per-job iterations."""
    casters = _jax("gate")[1]["casters"]
    order = np.random.default_rng(0).permutation(len(casters))
    _check_equal("gate", "warp", job_order=order)
    _check_equal("gate", "lanes", job_order=order[::-1].copy(), passes=2, expand_level=3)


def test_pruning_in_serial_order_equals_waves_of_one():
    """With pruning the kernel sees every accept at once (atomic AND); in the serial job
    order that is the JAX schedule with waves of one job: everything equal."""
    for form in kc.FORMS:
        _check_equal("gate", form, prune=True, wave=1)
        _check_equal("soup", form, prune=True, wave=1)


def test_pruning_counters_depend_on_the_schedule():
    """With pruning, counters depend on when accepts become visible; the shadows do not."""
    scene, light, gbuf, truth = _scene("gate")
    j, _ = _jax("gate", prune=True, wave=512)
    serial = kc.run(scene, gbuf, light, form="warp", prune=True)
    order = np.arange(j.counters["casters"])[::-1].copy()
    reverse = kc.run(scene, gbuf, light, form="warp", prune=True, job_order=order)
    for k in (serial, reverse):
        assert np.array_equal(k.lit, j.lit)
        assert np.count_nonzero((k.lit != truth) & gbuf.valid) == 0
    # accepts seen sooner prune more: never more node tests than the JAX waves
    assert serial.counters["node_tests"] < j.counters["node_tests"]
    assert serial.counters["node_tests"] != reverse.counters["node_tests"]
    unpruned, _ = _jax("gate")
    assert serial.counters["node_tests"] < unpruned.counters["node_tests"]


def test_float64_is_refused():
    scene, light, gbuf, _ = _scene("soup")
    with pytest.raises(ValueError, match="float32"):
        kc.run(scene, gbuf, light, precision="float64")
