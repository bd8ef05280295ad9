"""Run configurations: loading, overrides, views, and the error messages."""

from __future__ import annotations

import json
import shutil
import tomllib
from pathlib import Path

import numpy as np
import pytest

from shadowlab import methods
from shadowlab.config import (BUILTIN_DEFAULT, ConfigError, LightConfig, ReferenceConfig,
                              RunConfig, load_config, parse_override)
from shadowlab.scene import PointLight, SphereLight, View, procedural

REPO = Path(__file__).resolve().parents[1]
EXAMPLES = sorted((REPO / "configs").glob("*.toml"))

# A ground quad and a tetrahedron above it.
OBJ = """\
v -2 0 -2
v 2 0 -2
v 2 0 2
v -2 0 2
v 0 0.5 0
v 1 0.5 0
v 0 0.5 1
v 0 1.5 0
f 1 3 2
f 1 4 3
f 5 6 7
f 5 8 6
f 6 8 7
f 7 8 5
"""


def write(path: Path, text: str) -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(text)
    return path


def config_error(path, text: str | None = None, overrides=()) -> str:
    """Write ``text`` to ``path`` (if given), load it and return the ConfigError message."""
    if text is not None:
        write(Path(path), text)
    with pytest.raises(ConfigError) as info:
        load_config(path, overrides)
    return str(info.value)


# --------------------------------------------------------------------------- loading


def test_builtin_default_loads_and_builds_views():
    cfg = load_config()
    assert isinstance(cfg, RunConfig)
    assert cfg.source == BUILTIN_DEFAULT
    assert cfg.scene.source in procedural.GENERATORS
    assert cfg.scene.params["seed"] == 0
    assert set(cfg.scene.params) == set(procedural.GENERATORS[cfg.scene.source].defaults)
    assert cfg.methods.names == tuple(methods.names())
    assert set(cfg.methods.options) == set(cfg.methods.names)
    assert cfg.animation.frames == 1
    views = cfg.views()
    assert len(views) == 1 and isinstance(views[0], View)
    assert views[0].camera.resolution == cfg.camera.resolution
    json.dumps(cfg.to_dict())                       # plain, JSON-able metadata


def test_omitted_tables_take_the_builtin_defaults(tmp_path):
    empty = load_config(write(tmp_path / "empty.toml", ""))
    default = load_config()
    assert empty.scene == default.scene
    assert empty.reference == default.reference == ReferenceConfig()
    assert empty.methods == default.methods
    assert empty.animation == default.animation
    assert empty.light == default.light == LightConfig()
    assert empty.output.figures == default.output.figures
    assert empty.output.dir == "runs/empty"          # named after the config file
    assert default.output.dir == "runs/default"


@pytest.mark.parametrize("path", EXAMPLES, ids=[p.name for p in EXAMPLES])
def test_example_configs_load(path, tmp_path):
    assert {p.name for p in EXAMPLES} >= {"gate.toml", "mesh_file.toml", "animation.toml",
                                          "soft_sun.toml"}
    data = tomllib.loads(path.read_text())
    source = data.get("scene", {}).get("source", "gate")
    if source not in procedural.GENERATORS:
        # A mesh example: copy it, and the mesh it names, to a fresh folder.
        (tmp_path / "configs").mkdir()
        shipped = path.parent / source
        path = Path(shutil.copy(path, tmp_path / "configs" / path.name))
        (path.parent / source).parent.mkdir(parents=True, exist_ok=True)
        if shipped.exists():
            shutil.copy(shipped, path.parent / source)
        else:
            write(path.parent / source, OBJ)
    cfg = load_config(path, ["camera.resolution=[16, 16]"])
    assert cfg.source == str(path)
    views = cfg.views()
    assert len(views) == cfg.animation.frames
    json.dumps(cfg.to_dict())


def test_animation_example_moves_camera_and_light():
    cfg = load_config(REPO / "configs" / "animation.toml")
    assert cfg.animation.frames > 1 and cfg.animation.light_keys is not None
    views = cfg.views()
    assert np.allclose(views[0].camera.eye, cfg.animation.eye_keys[0])
    assert np.allclose(views[-1].camera.eye, cfg.animation.eye_keys[-1])
    assert np.allclose(views[0].light.position, cfg.animation.light_keys[0])
    assert np.allclose(views[-1].light.position, cfg.animation.light_keys[-1])
    # One clip range for the whole fly-through.
    assert len({(v.camera.near, v.camera.far) for v in views}) == 1


def test_soft_sun_example_is_a_sun_sphere_light():
    cfg = load_config(REPO / "configs" / "soft_sun.toml")
    assert cfg.scene.source == "terrain"
    (view,) = cfg.views()
    assert isinstance(view.light, SphereLight) and view.light.is_sun
    assert view.light.angular_radius_deg == cfg.light.angular_radius_deg
    assert cfg.reference.soft_rays >= 1


def test_reference_shadow_eps_is_the_methods_default(tmp_path):
    cfg = load_config(write(tmp_path / "c.toml", "[reference]\nshadow_eps = 1e-4\n"))
    assert all(opts["shadow_eps"] == 1e-4 for opts in cfg.methods.options.values())
    cfg = load_config(write(tmp_path / "d.toml", "[reference]\nshadow_eps = 1e-4\n"
                            "[methods.options.brute_force]\nshadow_eps = 0.0\n"))
    assert cfg.methods.options["brute_force"]["shadow_eps"] == 0.0


def test_camera_keys_merge_over_the_default_view(tmp_path):
    cfg = load_config(write(tmp_path / "c.toml", """
        [scene]
        source = "sphere_grid"
        [camera]
        eye = [0.0, 20.0, 20.0]
        target = [0.0, 0.0, 0.0]
        fov_y_deg = 40.0
    """))
    scene = cfg.build_scene()
    base = procedural.default_view("sphere_grid", scene, **cfg.scene.params)
    (view,) = cfg.views(scene)
    assert np.allclose(view.camera.eye, [0, 20, 20])
    assert view.camera.fov_y_deg == 40.0
    assert view.camera.resolution == base.camera.resolution
    assert np.allclose(view.light.position, base.light.position)
    # near/far are refitted for the moved camera: they bracket the scene's depth range.
    corners = np.array(np.meshgrid(*scene.bounds.T)).reshape(3, -1).T
    _, _, back = view.camera.basis()
    depth = (view.camera.eye - corners) @ back
    assert 0 < view.camera.near < view.camera.far <= depth.max() * 1.05
    assert (view.camera.near, view.camera.far) != (base.camera.near, base.camera.far)


# --------------------------------------------------------------------------- overrides


def test_overrides_change_values():
    cfg = load_config(None, ["camera.resolution=[256,128]", "scene.source=fuzzy",
                             'methods.names=["brute_force"]', "scene.params.seed=3",
                             "light.type=sun", "reference.soft_rays=16",
                             "output.figures=false", "output.dir=out/x"])
    assert cfg.camera.resolution == (256, 128)
    assert cfg.scene.source == "fuzzy" and cfg.scene.params["seed"] == 3
    assert cfg.methods.names == ("brute_force",)
    assert cfg.light.type == "sun"
    assert cfg.reference.soft_rays == 16
    assert cfg.output == type(cfg.output)(dir="out/x", figures=False)
    assert cfg.to_dict()["overrides"][0] == "camera.resolution=[256,128]"


def test_light_type_override_derives_the_missing_fields():
    cfg = load_config(None, ["light.type=sun", "scene.source=sphere_grid"])
    scene = cfg.build_scene()
    base = cfg.default_view(scene).light
    assert isinstance(base, PointLight)
    (view,) = cfg.views(scene)
    assert isinstance(view.light, SphereLight) and view.light.is_sun
    assert view.light.angular_radius_deg == pytest.approx(0.27)
    centre = scene.bounds.mean(axis=0)
    expect = (centre - base.position) / np.linalg.norm(centre - base.position)
    assert np.allclose(view.light.direction, expect)


def test_light_keys_without_type_change_the_default_light():
    cfg = load_config(None, ["light.position=[1, 30, 2]", "scene.source=sphere_grid"])
    (view,) = cfg.views()
    assert isinstance(view.light, PointLight)
    assert np.allclose(view.light.position, [1, 30, 2])


def test_override_values_are_validated():
    msg = config_error(None, overrides=["camera.resolution=[0,5]"])
    assert msg.startswith("--set: ")
    assert "camera.resolution must be two positive integers [width, height], got [0, 5]" in msg
    msg = config_error(None, overrides=["light.type=spot"])
    assert msg == ("--set: light.type = 'spot' is not allowed; "
                   "allowed: point, directional, sphere, sun")


def test_override_parsing():
    assert parse_override("camera.resolution=[256, 256]") == (("camera", "resolution"),
                                                              [256, 256])
    assert parse_override("scene.source = fuzzy") == (("scene", "source"), "fuzzy")
    assert parse_override('scene.source="a b.obj"') == (("scene", "source"), "a b.obj")
    assert parse_override("reference.shadow_eps=1e-4") == (("reference", "shadow_eps"), 1e-4)
    assert parse_override("output.figures=true") == (("output", "figures"), True)
    assert parse_override("scene.params={}") == (("scene", "params"), {})


@pytest.mark.parametrize("bad", ["camera.resolution", "=5", "a..b=1", "camera.eye=",
                                 ".x=1", "a b=1"])
def test_malformed_overrides_name_the_override(bad):
    msg = config_error(None, overrides=[bad])
    assert msg.startswith("--set: malformed override")
    assert repr(bad) in msg
    assert "key=value" in msg


def test_override_into_a_value_is_an_error():
    msg = config_error(None, overrides=["scene.source.x=1"])
    assert "--set" in msg and "scene.source" in msg and "not a table" in msg


def test_override_labels_only_its_own_keys(tmp_path):
    path = write(tmp_path / "x.toml", "[camera]\nresolution = [0, 5]\n")
    msg = config_error(path, overrides=["scene.params.seed=2"])
    assert msg.startswith(f"{path}: camera.resolution")


# --------------------------------------------------------------------------- errors


def test_error_unknown_light_type(tmp_path):
    path = tmp_path / "x.toml"
    msg = config_error(path, '[light]\ntype = "spot"\nposition = [0, 1, 0]\n')
    assert msg == (f"{path}: light.type = 'spot' is not allowed; "
                   "allowed: point, directional, sphere, sun")


def test_error_unknown_top_level_key(tmp_path):
    path = tmp_path / "x.toml"
    msg = config_error(path, "[camra]\nfov_y_deg = 50.0\n")
    assert msg.startswith(f"{path}: unknown key 'camra'")
    assert "did you mean 'camera'" in msg
    assert msg.endswith("allowed keys: scene, camera, light, animation, methods, reference, "
                        "output")


@pytest.mark.parametrize("text, key, allowed", [
    ("[camera]\neyes = [0, 1, 2]\n", "camera.eyes", "eye, target, up, fov_y_deg"),
    ("[light]\npos = [0, 1, 2]\n", "light.pos", "type, position, direction, radius"),
    ("[animation]\nframe = 3\n", "animation.frame", "frames, eye_keys"),
    ("[methods]\nname = 'all'\n", "methods.name", "names, options"),
    ("[reference]\nsoftrays = 3\n", "reference.softrays", "shadow_eps, soft_rays, seed"),
    ("[output]\nfigs = true\n", "output.figs", "dir, figures"),
    ("[scene]\nsrc = 'gate'\n", "scene.src", "source, params"),
])
def test_error_unknown_nested_keys(tmp_path, text, key, allowed):
    path = tmp_path / "x.toml"
    msg = config_error(path, text)
    assert msg.startswith(f"{path}: unknown key '{key}'")
    assert allowed in msg


def test_error_bad_resolution(tmp_path):
    path = tmp_path / "x.toml"
    msg = config_error(path, "[camera]\nresolution = [0, 5]\n")
    assert msg == (f"{path}: camera.resolution must be two positive integers "
                   "[width, height], got [0, 5]")
    for bad in ("[256]", "[1.5, 2]", "'big'", "[true, 2]"):
        assert "camera.resolution must be two positive integers" in config_error(
            path, f"[camera]\nresolution = {bad}\n")


def test_error_toml_syntax_names_file_and_line(tmp_path):
    path = tmp_path / "x.toml"
    msg = config_error(path, "[scene]\nsource = 'gate'\nseed = \n")
    assert msg.startswith(f"{path}: invalid TOML")
    assert "line 3" in msg


def test_error_toml_syntax_at_end_of_document_names_a_line(tmp_path):
    path = tmp_path / "x.toml"
    msg = config_error(path, "[scene]\nsource = 'gate'\nx = [1,\n")
    assert msg.startswith(f"{path}: invalid TOML") and "line 4" in msg


def test_error_nothing_in_view(tmp_path):
    path = write(tmp_path / "x.toml", "[scene]\nsource = 'sphere_grid'\n"
                 "[camera]\neye = [0.0, 5.0, 500.0]\ntarget = [0.0, 5.0, 1000.0]\n")
    cfg = load_config(path)
    with pytest.raises(ConfigError) as info:
        cfg.views()
    assert str(info.value).startswith(f"{path}: camera: no geometry of the scene is inside "
                                      "the view")


def test_error_missing_file(tmp_path):
    path = tmp_path / "nope.toml"
    assert config_error(path) == f"{path}: no such config file"
    assert "is a directory" in config_error(tmp_path)


def test_error_unknown_method_name(tmp_path):
    path = tmp_path / "x.toml"
    msg = config_error(path, "[methods]\nnames = ['brute_forse']\n")
    assert msg.startswith(f"{path}: methods.names")
    assert "'brute_forse'" in msg and "did you mean 'brute_force'" in msg
    assert "allowed: " + ", ".join(methods.names()) in msg
    for bad in ("[]", "3", "['brute_force', 'brute_force']"):
        msg = config_error(path, f"[methods]\nnames = {bad}\n")
        assert msg.startswith(f"{path}: methods.names")


def test_error_unknown_scene_source_lists_generators(tmp_path):
    path = tmp_path / "x.toml"
    msg = config_error(path, "[scene]\nsource = 'gat'\n")
    assert msg.startswith(f"{path}: scene.source = 'gat'")
    assert "did you mean 'gate'" in msg
    assert "generators: " + ", ".join(procedural.GENERATORS) in msg
    assert str(tmp_path / "gat") in msg             # where it looked for a file
    write(tmp_path / "notes.txt", "hello")
    msg = config_error(path, "[scene]\nsource = 'notes.txt'\n")
    assert "unknown mesh format '.txt'" in msg and ".obj" in msg


def test_error_method_options(tmp_path):
    path = tmp_path / "x.toml"
    msg = config_error(path, "[methods.options.brute_force]\nchunk = 5\n")
    assert msg.startswith(f"{path}: methods.options.brute_force.chunk")
    assert "allowed values: 4, 8, 16, 32" in msg
    msg = config_error(path, "[methods.options.brute_force]\nchunks = 8\n")
    assert msg.startswith(f"{path}: methods.options.brute_force.chunks")
    allowed = ", ".join(sorted(methods.get("brute_force").options))
    assert f"allowed options: {allowed}" in msg
    msg = config_error(path, "[methods.options.brute]\nchunk = 8\n")
    assert msg.startswith(f"{path}: unknown method 'methods.options.brute'")
    assert "allowed methods: " + ", ".join(methods.names()) in msg
    msg = config_error(path, "[methods.options]\nbrute_force = 3\n")
    assert "methods.options.brute_force must be a table" in msg


def test_error_scene_params(tmp_path):
    path = tmp_path / "x.toml"
    msg = config_error(path, "[scene]\nsource = 'gate'\n[scene.params]\ntree = 3\n")
    assert msg.startswith(f"{path}: unknown key 'scene.params.tree'")
    assert "did you mean 'trees'" in msg
    assert "allowed keys in [scene.params]: trees (default 12)" in msg
    msg = config_error(path, "[scene]\nsource = 'gate'\n[scene.params]\ntrees = -1\n")
    assert msg.startswith(f"{path}: scene.params.trees = -1 is not allowed")
    assert ">= 0" in msg
    msg = config_error(path, "[scene]\nsource = 'gate'\n[scene.params]\nseed = 1.5\n")
    assert msg.startswith(f"{path}: scene.params.seed = 1.5") and "integer" in msg
    # A generator's params are checked against the generator the source names.
    msg = config_error(path, "[scene.params]\ntrees = 3\n", ["scene.source=terrain"])
    assert "unknown key 'scene.params.trees'" in msg and "size (default" in msg


@pytest.mark.parametrize("text, key, expect", [
    ("[animation]\nframes = 0\n", "animation.frames", "an integer >= 1, got 0"),
    ("[animation]\nframes = 2.5\n", "animation.frames", "an integer >= 1, got 2.5"),
    ("[reference]\nsoft_rays = 0\n", "reference.soft_rays", "an integer >= 1, got 0"),
    ("[reference]\nshadow_eps = -1e-3\n", "reference.shadow_eps", ">= 0"),
    ("[reference]\nshadow_eps = nan\n", "reference.shadow_eps", "a finite number"),
    ("[reference]\nseed = -1\n", "reference.seed", "an integer >= 0"),
    ("[camera]\neye = [0, 1]\n", "camera.eye", "3 finite numbers [x, y, z], got [0, 1]"),
    ("[camera]\ntarget = [0, inf, 1]\n", "camera.target", "3 finite numbers"),
    ("[camera]\nup = [0, 0, 0]\n", "camera.up", "non-zero"),
    ("[camera]\nfov_y_deg = 180\n", "camera.fov_y_deg", "> 0 and < 180"),
    ("[camera]\nnear = 0\n", "camera.near", "> 0"),
    ("[camera]\nnear = 5.0\nfar = 1.0\n", "camera.far", "greater than camera.near"),
    ("[camera]\neye = [1, 2, 3]\ntarget = [1, 2, 3]\n", "camera.target", "differ"),
    ("[light]\ntype = 'sphere'\nradius = 0\n", "light.radius", "> 0"),
    ("[light]\ntype = 'sun'\nangular_radius_deg = 95\n", "light.angular_radius_deg", "< 90"),
    ("[light]\ntype = 'directional'\ndirection = [0, 0, 0]\n", "light.direction", "non-zero"),
    ("[light]\ntype = 'point'\ndirection = [0, -1, 0]\n", "light.direction",
     "not used by a point light (light.type = 'point'); allowed keys for a point light: "
     "type, position"),
    ("[light]\ntype = 'sun'\nradius = 1.0\n", "light.radius",
     "allowed keys for a sun light: type, direction, angular_radius_deg"),
    ("[animation]\neye_keys = []\n", "animation.eye_keys", "non-empty list"),
    ("[animation]\ntarget_keys = [[0, 1, 2], [3, 4]]\n", "animation.target_keys[1]",
     "3 finite numbers"),
    ("[light]\ntype = 'sun'\n[animation]\nlight_keys = [[0, 0, 0]]\n",
     "animation.light_keys[0]", "non-zero"),
    ("[output]\nfigures = 'yes'\n", "output.figures", "true or false"),
    ("[output]\ndir = ''\n", "output.dir", "non-empty"),
    ("camera = 3\n", "camera", "must be a table"),
    ("[scene]\nsource = 3\n", "scene.source", "generator name"),
    ("[scene]\nparams = 3\n", "scene.params", "must be a table"),
])
def test_error_types_and_ranges(tmp_path, text, key, expect):
    path = tmp_path / "x.toml"
    msg = config_error(path, text)
    assert msg.startswith(f"{path}: {key}"), msg
    assert expect in msg, msg


def test_error_sphere_light_needs_a_radius(tmp_path):
    path = write(tmp_path / "x.toml", "[scene]\nsource = 'sphere_grid'\n"
                 "[light]\ntype = 'sphere'\nposition = [0, 10, 0]\n")
    cfg = load_config(path)
    with pytest.raises(ConfigError) as info:
        cfg.views()
    assert str(info.value).startswith(f"{path}: light.type = 'sphere' needs light.radius")


def test_error_light_key_unused_by_the_default_light_type():
    cfg = load_config(None, ["scene.source=terrain", "light.position=[0, 10, 0]"])
    with pytest.raises(ConfigError) as info:
        cfg.views()
    msg = str(info.value)
    assert msg.startswith("--set: light.position is not used by a sun light")
    assert "set light.type to change it" in msg


def test_error_light_type_override_conflicting_with_file_keys(tmp_path):
    path = write(tmp_path / "x.toml", "[light]\ntype = 'point'\nposition = [0, 10, 0]\n")
    msg = config_error(path, overrides=["light.type=sun"])
    assert msg.startswith("--set: light.position is not used by a sun light")
    assert "--set 'light={" in msg                 # how to replace the whole table
    cfg = load_config(path, ['light={type="sun", direction=[0, -1, 0]}'])
    assert cfg.light == LightConfig(type="sun", direction=(0.0, -1.0, 0.0))


# --------------------------------------------------------------------------- mesh files


def test_relative_mesh_path_resolves_against_the_config_folder(tmp_path, monkeypatch):
    mesh = write(tmp_path / "meshes" / "tetra.obj", OBJ)
    path = write(tmp_path / "configs" / "mesh.toml",
                 "[scene]\nsource = '../meshes/tetra.obj'\n[camera]\nresolution = [32, 24]\n")
    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir()
    monkeypatch.chdir(elsewhere)
    cfg = load_config(path)
    assert Path(cfg.scene.source) == mesh.resolve()
    assert cfg.scene.params == {}
    scene = cfg.build_scene()
    assert scene.num_triangles == 6
    (view,) = cfg.views(scene)
    cam = view.camera
    assert cam.resolution == (32, 24)
    centre = scene.bounds.mean(axis=0)
    # The default camera looks at the box's centre from a diagonal direction ...
    assert np.allclose(cam.target, centre)
    d = cam.eye - centre
    assert (np.abs(d) > 0.1 * np.linalg.norm(d)).all()
    # ... from outside the box, with near/far bracketing the geometry.
    _, _, back = cam.basis()
    depth = (cam.eye - scene.vertices) @ back          # every vertex is in view
    assert 0 < cam.near <= depth.min() and cam.far >= depth.max()
    # The default light is a point light above and to the side of the box.
    assert isinstance(view.light, PointLight)
    lo, hi = scene.bounds
    assert view.light.position[1] > hi[1]
    assert not (lo[[0, 2]] <= view.light.position[[0, 2]]).all() or \
        not (view.light.position[[0, 2]] <= hi[[0, 2]]).all()


def test_mesh_path_from_override_resolves_against_cwd(tmp_path, monkeypatch):
    write(tmp_path / "work" / "m.obj", OBJ)
    path = write(tmp_path / "configs" / "c.toml", "[camera]\nresolution = [8, 8]\n")
    monkeypatch.chdir(tmp_path / "work")
    cfg = load_config(path, ["scene.source=m.obj"])
    assert Path(cfg.scene.source) == (tmp_path / "work" / "m.obj").resolve()
    # The same relative path in the file resolves against the config folder: missing.
    msg = config_error(write(tmp_path / "configs" / "d.toml", "[scene]\nsource = 'm.obj'\n"))
    assert msg.startswith(f"{tmp_path / 'configs' / 'd.toml'}: scene.source = 'm.obj'")
    assert str(tmp_path / "configs" / "m.obj") in msg


def test_mesh_with_camera_and_light(tmp_path):
    write(tmp_path / "m.obj", OBJ)
    path = write(tmp_path / "c.toml", """
        [scene]
        source = "m.obj"
        [camera]
        eye = [4.0, 3.0, 5.0]
        target = [0.0, 0.5, 0.0]
        [light]
        type = "directional"
        direction = [0.0, -1.0, 0.2]
    """)
    (view,) = load_config(path).views()
    assert np.allclose(view.camera.eye, [4, 3, 5])
    assert np.allclose(view.light.direction, np.array([0, -1, 0.2]) / np.hypot(1, 0.2))


def test_error_params_for_a_mesh_file(tmp_path):
    write(tmp_path / "m.obj", OBJ)
    path = tmp_path / "c.toml"
    msg = config_error(path, "[scene]\nsource = 'm.obj'\n[scene.params]\nseed = 1\n")
    assert msg.startswith(f"{path}: scene.params is only for procedural sources")
    assert ", ".join(procedural.GENERATORS) in msg


def test_error_broken_mesh_file_at_build(tmp_path):
    write(tmp_path / "m.obj", "v 0 0 0\nv nan 0 0\nv 0 1 0\nf 1 2 3\n")
    cfg = load_config(write(tmp_path / "c.toml", "[scene]\nsource = 'm.obj'\n"))
    with pytest.raises(ConfigError) as info:
        cfg.build_scene()
    assert str(info.value).startswith(f"{tmp_path / 'c.toml'}: scene.source = ")
    assert "NaN" in str(info.value)


# --------------------------------------------------------------------------- experiment configs

EXPERIMENT_CONFIGS = sorted((REPO / "configs" / "experiments").glob("*.toml"))


@pytest.mark.parametrize("path", EXPERIMENT_CONFIGS, ids=[p.name for p in EXPERIMENT_CONFIGS])
def test_shipped_experiment_configs_are_valid(path):
    from shadowlab.config.experiments import load_experiment_file

    assert load_experiment_file(path) == tomllib.loads(path.read_text())   # as parsed


def test_every_experiment_has_both_sizes():
    stems = {p.name.split(".")[0] for p in EXPERIMENT_CONFIGS}
    assert stems == {p.stem for p in (REPO / "experiments").glob("*.py")
                     if not p.stem.startswith("_")}
    assert len(EXPERIMENT_CONFIGS) == 2 * len(stems)


@pytest.mark.parametrize("text, expect", [
    ("resolutoin = [1, 2]\n", "unknown key 'resolutoin' (did you mean 'resolution'?); "
     "allowed keys: scene, scenes"),
    ("resolution = [0, 2]\n", "resolution must be two positive integers [width, height], "
     "got [0, 2]"),
    ("precision = 'f16'\n", "precision = 'f16' is not allowed; allowed: float32, float64"),
    ("scenes = ['gate', 'gat']\n", "scenes[1] = 'gat' is not allowed; allowed: sphere_grid, "
     "gate"),
    ("resolutions = [[1, 2], [3]]\n", "resolutions[1] must be two positive integers"),
    ("seeds = [0, -1]\n", "seeds must be a non-empty list of integers >= 0, got [0, -1]"),
    ("max_mae = 2.0\n", "max_mae must be a finite number >= 0 and <= 1, got 2.0"),
    ("repeats = 1.5\n", "repeats must be an integer >= 1, got 1.5"),
    ("slow_seconds = 0\n", "slow_seconds must be a finite number > 0 (seconds), got 0"),
    ("require_claims = 'yes'\n", "require_claims must be true or false, got 'yes'"),
    ("params = 3\n", "params must be a table, got an integer 3"),
    ("scene = 'gate'\nparams = {tree = 3}\n", "params: gate: unknown parameter 'tree'"),
    ("scenes = ['gate']\n[params.gat]\nn = 1\n", "unknown generator 'params.gat' (did you "
     "mean 'gate'?)"),
    ("scenes = ['gate']\n[params.gate]\ntrees = -1\n",
     "params.gate: gate: parameter 'trees' must be >= 0, got -1"),
    ("x = [1,\n", "invalid TOML"),
])
def test_experiment_config_errors_name_file_and_key(tmp_path, text, expect):
    from shadowlab.config.experiments import load_experiment_file

    path = write(tmp_path / "e.ci.toml", text)
    with pytest.raises(ConfigError) as info:
        load_experiment_file(path)
    assert str(info.value).startswith(f"{path}: {expect}"), str(info.value)


def test_experiment_config_error_through_figures(tmp_path):
    from shadowlab.harness.figures import ExperimentError, load_experiment_config

    write(tmp_path / "configs" / "experiments" / "demo.ci.toml", "resolution = 'big'\n")
    with pytest.raises(ExperimentError) as info:
        load_experiment_config(tmp_path, "demo", "ci")
    assert isinstance(info.value, ConfigError)
    assert "demo.ci.toml: resolution must be two positive integers" in str(info.value)
    with pytest.raises(ExperimentError, match="no such experiment config"):
        load_experiment_config(tmp_path, "demo", "full")
