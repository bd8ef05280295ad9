"""Procedural scenes: registry, parameter validation, determinism, sizes, topology and
default views (framing, near/far, a mix of lit and shadowed pixels)."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest
from hypothesis import given, settings, strategies as st

from shadowlab.reference import raycast
from shadowlab.scene import (GENERATORS, Camera, PointLight, Scene, SceneError, SphereLight,
                             View, default_view, generators, load_scene, make, mesh_report)
from shadowlab.scene import primitives as prim
from shadowlab.scene.procedural import Generator, fit_clip_range

NAMES = ["sphere_grid", "gate", "fuzzy", "terrain", "blobs", "soup", "atrium", "city",
         "props"]
RANDOMISED = [n for n in NAMES if n != "sphere_grid"]   # sphere_grid is regular
# One integer size parameter per generator (for type/range errors and scaling).
SIZE_PARAM = {"sphere_grid": "n", "gate": "trees", "fuzzy": "triangles",
              "terrain": "size", "blobs": "grid", "soup": "count", "atrium": "bays",
              "city": "blocks", "props": "count"}


def _same(a: Scene, b: Scene) -> bool:
    return (np.array_equal(a.vertices, b.vertices) and np.array_equal(a.faces, b.faces)
            and np.array_equal(a.object_id, b.object_id) and a.object_names == b.object_names)


@pytest.fixture(scope="module")
def scenes() -> dict[str, Scene]:
    return {name: make(name) for name in NAMES}


# --------------------------------------------------------------------------- registry

def test_registry_names_and_fields():
    assert list(GENERATORS) == NAMES
    assert generators() == {n: g.defaults for n, g in GENERATORS.items()}
    for name, gen in GENERATORS.items():
        assert isinstance(gen, Generator) and gen.name == name
        assert "seed" in gen.defaults and gen.defaults["seed"] == 0
        assert set(gen.params) == set(gen.defaults)
        assert gen.doc and "\n" not in gen.doc
        with pytest.raises(dataclasses.FrozenInstanceError):
            gen.name = "x"


def test_generators_returns_copies():
    generators()["gate"]["trees"] = -5
    assert GENERATORS["gate"].defaults["trees"] == 12


def test_build_equals_make_and_names(scenes):
    for name in NAMES:
        assert _same(GENERATORS[name].build(), scenes[name])
        assert scenes[name].name == f"{name}(seed=0)"
    assert make("fuzzy", triangles=500, seed=3).name == "fuzzy(triangles=500, seed=3)"
    assert _same(load_scene("soup", count=3), make("soup", count=3))


def test_dtypes_and_ground(scenes):
    for name, s in scenes.items():
        assert s.vertices.dtype == np.float64 and s.faces.dtype == np.int32
        assert s.object_id.dtype == np.int32
        assert np.array_equal(np.unique(s.object_id), np.arange(s.num_objects)), name
        if name != "terrain":
            assert s.object_names[0] == "ground"
            ground = s.triangles[s.object_id == 0]
            if name in ("city", "props"):           # a closed slab whose top is y = 0
                assert ground[..., 1].max() == 0.0 and ground[..., 1].min() < 0
            else:
                assert np.all(ground[..., 1] == 0.0)


# --------------------------------------------------------------------------- determinism

@pytest.mark.parametrize("name", NAMES)
def test_deterministic(name, scenes):
    assert _same(make(name, seed=0), scenes[name])


@pytest.mark.parametrize("name", RANDOMISED)
def test_seed_changes_scene(name, scenes):
    other = make(name, seed=1)
    assert not (other.vertices.shape == scenes[name].vertices.shape
                and np.array_equal(other.vertices, scenes[name].vertices))


# --------------------------------------------------------------------------- errors

def test_unknown_generator_lists_names():
    with pytest.raises(SceneError) as err:
        make("spheres")
    for name in NAMES:
        assert name in str(err.value)
    with pytest.raises(SceneError):
        default_view("spheres")


@pytest.mark.parametrize("name", NAMES)
def test_unknown_parameter(name):
    with pytest.raises(SceneError) as err:
        make(name, colour=3)
    msg = str(err.value)
    assert "'colour'" in msg
    for key in GENERATORS[name].defaults:
        assert key in msg
    with pytest.raises(SceneError, match="colour"):
        default_view(name, colour=3)


@pytest.mark.parametrize("name", NAMES)
@pytest.mark.parametrize("bad", [-1, 2.5, "4", True, None])
def test_bad_values_name_the_parameter(name, bad):
    key = SIZE_PARAM[name]
    with pytest.raises(SceneError, match=repr(key)):
        make(name, **{key: bad})
    with pytest.raises(SceneError, match="'seed'"):
        make(name, seed=-1 if bad is not None else None)


def test_float_parameters():
    with pytest.raises(SceneError, match="'height'"):
        make("terrain", height=-1.0, size=4)
    with pytest.raises(SceneError, match="'height'"):
        make("terrain", height=math.inf, size=4)
    flat = make("terrain", height=0, size=4)           # an int is a valid float
    assert np.all(flat.vertices[:, 1] == 0.0)


@pytest.mark.parametrize("name", NAMES)
def test_params_model_is_built_from_the_param_specs(name):
    """One pydantic model per generator: its fields, defaults and bounds are the Params'."""
    from shadowlab.scene.procedural import params_model

    gen = GENERATORS[name]
    model = params_model(name)
    assert list(model.model_fields) == list(gen.params)
    assert model().model_dump() == gen.defaults
    schema = model.model_json_schema()["properties"]
    for key, spec in gen.params.items():
        text = str(schema[key])
        if spec.lo is not None:
            assert f"'minimum': {spec.lo}" in text, (key, text)
        if spec.hi is not None:
            assert f"'maximum': {spec.hi}" in text, (key, text)
            with pytest.raises(SceneError, match=f"'{key}' must be <= {spec.hi}"):
                make(name, **{key: spec.kind(spec.hi * 2 + 1)})
        if spec.lo is not None and spec.lo > 0:
            with pytest.raises(SceneError, match=f"'{key}' must be >= {spec.lo}"):
                make(name, **{key: spec.kind(spec.lo - 1)})


def test_numpy_scalars_are_accepted_as_parameters():
    a = make("soup", count=np.int64(3), seed=np.int32(1))
    assert _same(a, make("soup", count=3, seed=1))
    with pytest.raises(SceneError, match="'count'"):
        make("soup", count=np.bool_(True))


def test_impossible_combinations():
    with pytest.raises(SceneError, match="'objects'"):
        make("sphere_grid", n=2, triangles_per_sphere=6, objects=25)
    with pytest.raises(SceneError, match="'clusters'"):
        make("fuzzy", triangles=3, clusters=4)


# --------------------------------------------------------------------------- sizes

def test_sphere_grid_counts():
    for n, tps in [(1, 6), (2, 100), (3, 512), (4, 2000)]:
        stacks, slices = prim.sphere_resolution(tps)
        per = 2 * slices * (stacks - 1)
        assert abs(per - tps) <= 0.05 * tps + 2
        s = make("sphere_grid", n=n, triangles_per_sphere=tps)
        assert s.num_triangles == n * n * per + 2
        assert s.num_objects == n * n + 1


def test_gate_counts():
    for trees, leaves, bars in [(12, 300, 9), (0, 0, 0), (3, 50, 20)]:
        s = make("gate", trees=trees, leaves_per_tree=leaves, bars=bars)
        assert s.num_triangles == 2 + 12 * (5 + bars) + 44 + trees * (40 + leaves)
        assert s.num_objects == 1 + 5 + bars + 4 + 2 * trees


def test_simple_counts():
    assert make("fuzzy", triangles=2345, clusters=7).num_triangles == 2345 + 2
    assert make("fuzzy", triangles=2345, clusters=7).num_objects == 8
    assert make("terrain", size=33).num_triangles == 2 * 32 * 32
    assert make("soup", count=7).num_triangles == 20 * 7 + 2


def test_blobs_scale_with_grid():
    small, large = (make("blobs", grid=g).num_triangles for g in (24, 48))
    assert 3.0 < large / small < 5.0


def test_large_fuzzy_builds():
    s = make("fuzzy", triangles=400_000)
    assert s.num_triangles == 400_002
    tri = s.triangles[s.object_id > 0]
    assert tri[..., 1].min() > 0.0                      # strands stay above the ground


# --------------------------------------------------------------------------- topology

def test_sphere_grid_spheres_closed_and_outward(scenes):
    s = scenes["sphere_grid"]
    rep = mesh_report(s)
    assert rep.degenerate_triangles == 0 and rep.nonmanifold_edges == 0
    assert all(o.closed for o in rep.objects[1:]) and not rep.objects[0].closed
    for oid in range(1, s.num_objects):
        faces = s.faces[s.object_id == oid]
        vol = prim.signed_volume(s.vertices, faces)
        assert vol == pytest.approx(4 / 3 * math.pi, rel=0.05)


def test_sphere_grid_merged_objects_closed():
    s = make("sphere_grid", n=3, objects=4, triangles_per_sphere=60)
    assert s.num_objects == 5
    rep = mesh_report(s)
    assert all(o.closed for o in rep.objects[1:])
    sizes = np.bincount(s.object_id)[1:] // 60           # whole spheres per object
    assert sizes.sum() == 9 and sizes.max() - sizes.min() <= 1


@settings(max_examples=25, deadline=None)
@given(n=st.integers(1, 3), tps=st.integers(6, 80), frac=st.floats(0.01, 1.0))
def test_sphere_grid_objects_partition(n, tps, frac):
    stacks, slices = prim.sphere_resolution(tps)
    per = 2 * slices * (stacks - 1)
    objects = max(1, int(frac * n * n * per))
    s = make("sphere_grid", n=n, triangles_per_sphere=tps, objects=objects)
    plain = make("sphere_grid", n=n, triangles_per_sphere=tps)
    assert np.array_equal(s.vertices, plain.vertices) and np.array_equal(s.faces, plain.faces)
    assert s.num_objects == objects + 1
    counts = np.bincount(s.object_id, minlength=s.num_objects)
    assert counts.min() >= 1 and counts[0] == 2
    assert np.all(np.diff(s.object_id[2:]) >= 0)         # objects are contiguous
    if objects <= n * n:
        assert all(o.closed for o in mesh_report(s).objects[1:])


def test_blobs_closed(scenes):
    rep = mesh_report(scenes["blobs"])
    assert len(rep.objects) >= 2
    assert all(o.closed for o in rep.objects[1:])
    s = scenes["blobs"]
    for oid in range(1, s.num_objects):
        assert prim.signed_volume(s.vertices, s.faces[s.object_id == oid]) > 0


def test_gate_objects(scenes):
    s = scenes["gate"]
    names = s.object_names
    assert "house.walls" in names and "house.roof" in names and "gate.lintel" in names
    assert sum(n.startswith("gate.bar") for n in names) == 9
    assert sum(n.endswith(".crown") for n in names) == 12
    rep = {o.name: o for o in mesh_report(s).objects}
    assert all(rep[n].closed for n in names if n.startswith(("gate.", "house.")) or
               n.endswith(".trunk"))


def test_soup_defects(scenes):
    rep = mesh_report(scenes["soup"])
    by_name = {o.name: o for o in rep.objects}
    assert rep.degenerate_triangles == 100
    assert rep.nonmanifold_edges > 0 and by_name["nonmanifold"].nonmanifold_edges == 100
    assert rep.open_edges > 0 and by_name["open"].open_edges == 4 * 100
    s = scenes["soup"]
    dup = s.faces[s.object_id == s.object_names.index("duplicated")]
    assert np.array_equal(np.sort(dup[0::2], 1), np.sort(dup[1::2], 1))
    cop = s.triangles[s.object_id == s.object_names.index("coplanar")]
    assert np.any(np.all(cop[..., 1] == 0.0, axis=1))   # some lie on the ground plane


# --------------------------------------------------------------------------- primitives

@pytest.mark.parametrize("mesh, volume", [
    (prim.box((0, 0, 0), (1, 2, 3)), 6.0),
    (prim.cylinder(64), math.pi),
    (prim.gable_prism((0, 0, 0), (2, 1, 3)), 3.0),
    (prim.uv_sphere(40, 80), 4 / 3 * math.pi),
    (prim.cylinder(64, 5), math.pi),
    (prim.torus(96, 48, 0.3), 2 * math.pi ** 2 * 0.3 ** 2),
    (prim.capsule(41, 80, 0.5), 4 / 3 * math.pi + math.pi),
])
def test_closed_primitives(mesh, volume):
    v, f = mesh
    s = Scene(v, f, np.zeros(len(f)))
    assert mesh_report(s).all_closed
    assert prim.signed_volume(v, f) == pytest.approx(volume, rel=0.01)


def test_primitive_counts_and_bad_arguments():
    assert [len(m[1]) for m in (prim.cylinder(7, 3), prim.torus(5, 4, 0.5),
                                prim.capsule(5, 6, 1.0))] == [2 * 7 * 4, 2 * 5 * 4, 2 * 6 * 4]
    assert np.array_equal(prim.cylinder(9, 1)[1], prim.cylinder(9)[1])
    v, _ = prim.capsule(7, 8, 2.0)
    assert v[:, 1].max() == 3.0 and v[:, 1].min() == -3.0 and not np.any(v[:, 1] == 0)
    for bad in (lambda: prim.cylinder(8, 0), lambda: prim.torus(8, 2, 0.3),
                lambda: prim.torus(8, 8, 1.0), lambda: prim.capsule(6, 8, 1.0),
                lambda: prim.capsule(7, 8, -1.0)):
        with pytest.raises(ValueError):
            bad()


def test_props_rest_on_and_float_over_a_closed_slab(scenes):
    s = scenes["props"]
    rep = mesh_report(s)
    assert rep.all_closed and rep.degenerate_triangles == 0 and s.num_objects == 41
    assert abs(s.num_triangles - 20_000) < 0.02 * 20_000
    assert abs(make("props", triangles=50_000).num_triangles - 50_000) < 0.02 * 50_000
    lows = np.array([s.triangles[s.object_id == o][..., 1].min()
                     for o in range(1, s.num_objects)])
    resting = lows == 0.0                         # exactly on the slab's top face
    assert 0.3 < resting.mean() < 0.7 and np.all(lows[~resting] >= 0.3)
    assert {n.rstrip("0123456789") for n in s.object_names[1:]} == {"torus", "capsule",
                                                                    "cylinder"}
    for o in range(1, s.num_objects):               # every prop wound outward
        v, f = s.vertices, s.faces[s.object_id == o]
        assert prim.signed_volume(v, f) > 0
    for share, rests in ((0.0, True), (1.0, False)):
        other = make("props", floating=share, count=12, triangles=2000)
        other_lows = [other.triangles[other.object_id == o][..., 1].min()
                      for o in range(1, other.num_objects)]
        assert all((low == 0.0) == rests and (rests or low >= 0.3) for low in other_lows)


def test_grid_and_instances():
    v, f = prim.height_grid(np.zeros((3, 4)), (0, 3), (0, 2))
    assert len(f) == 2 * 3 * 2
    n = np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]])
    assert np.all(n[:, 1] > 0) and np.allclose(n[:, [0, 2]], 0)
    bv, bf = prim.box((0, 0, 0), (1, 1, 1))
    iv, i_f = prim.instances(bv, bf, [[0, 0, 0], [5, 0, 0]], [1.0, 2.0])
    assert iv.shape == (16, 3) and i_f.shape == (24, 3)
    assert np.allclose(iv[8:].max(0), [7, 2, 2])
    rot = prim.random_rotations(np.random.default_rng(0), 5)
    assert np.allclose(np.einsum("kij,kil->kjl", rot, rot), np.eye(3))
    assert np.allclose(np.linalg.det(rot), 1.0)


def test_fit_clip_range_single_triangle():
    tri = Scene(np.array([[-1.0, -1, -5], [1, -1, -5], [0, 1, -7]]), np.array([[0, 1, 2]]),
                np.zeros(1))
    near, far = fit_clip_range(tri, (0, 0, 0), (0, 0, -1), fov_y_deg=90.0, margin=0.0)
    assert near == pytest.approx(5.0) and far == pytest.approx(7.0)
    # only the part inside a narrow frustum counts: the plane z = 6 + y meets the
    # frustum's top and bottom planes y = +-t z at z = 6 / (1 -+ t)
    near, far = fit_clip_range(tri, (0, 0, 0), (0, 0, -1), fov_y_deg=2.0, margin=0.0)
    t = math.tan(math.radians(1.0))
    assert near == pytest.approx(6 / (1 + t)) and far == pytest.approx(6 / (1 - t))
    with pytest.raises(SceneError):
        fit_clip_range(tri, (0, 0, 0), (0, 0, 1))


# --------------------------------------------------------------------------- views

@pytest.mark.parametrize("name", NAMES)
def test_default_view_shadows(name, scenes):
    s = scenes[name]
    view = default_view(name, s)
    cam = view.camera
    assert cam.resolution == (256, 256)
    assert cam.far / cam.near <= 1e4
    gbuf = raycast.render_gbuffer(s, cam)
    valid = gbuf.valid
    assert valid.mean() > 0.3, valid.mean()
    lit = raycast.reference_shadows(s, gbuf, view.light)
    frac = lit[valid].mean()
    assert 0.05 < frac < 0.95, frac
    # near/far clip nothing that is visible: same coverage with a very wide range
    wide = raycast.render_gbuffer(s, cam.replace(near=cam.near * 1e-3, far=cam.far * 1e3))
    assert np.array_equal(wide.valid, valid)
    assert gbuf.depth[valid].min() > cam.near and gbuf.depth[valid].max() < cam.far


def test_default_view_builds_scene_with_params():
    view = default_view("fuzzy", triangles=300, clusters=2)
    assert isinstance(view, View) and isinstance(view.light, PointLight)
    assert isinstance(view.camera, Camera)


def test_terrain_sun():
    light = default_view("terrain", size=8).light
    assert isinstance(light, SphereLight) and light.is_sun
    assert light.angular_radius_deg == pytest.approx(0.27)
    elevation = math.degrees(math.asin(-light.direction[1]))
    assert 5 <= elevation <= 15
