"""Scene loading, flattening, the topology report, and every bad-input error."""

import numpy as np
import pytest
import trimesh

from shadowlab.scene import Scene, SceneError, load_scene, mesh_report


def _box():
    return trimesh.creation.box(extents=(1, 2, 3))


@pytest.mark.parametrize("ext", ["obj", "ply", "stl", "off", "glb"])
def test_every_format_loads_the_same_triangles(tmp_path, ext):
    mesh = _box()
    path = tmp_path / f"box.{ext}"
    mesh.export(path)
    scene = load_scene(path)
    assert scene.vertices.dtype == np.float64 and scene.faces.dtype == np.int32
    assert scene.num_triangles == 12
    # Same set of triangles (as sorted corner sets), whatever vertex sharing the format keeps.
    got = np.sort(np.round(scene.triangles, 6).reshape(12, -1), axis=0)
    want = np.sort(np.round(mesh.vertices[mesh.faces], 6).reshape(12, -1), axis=0)
    np.testing.assert_allclose(np.sort(got, axis=None), np.sort(want, axis=None))
    assert scene.report().objects[0].closed or ext == "stl"  # STL is soup, no shared indices


def test_scene_graph_is_flattened_with_transforms_and_object_ids(tmp_path):
    a = trimesh.creation.box(extents=(1, 1, 1))
    b = trimesh.creation.icosphere(subdivisions=1)
    sc = trimesh.Scene()
    sc.add_geometry(a, node_name="box", geom_name="box")
    t = np.eye(4)
    t[:3, 3] = (10, 0, 0)
    sc.add_geometry(b, node_name="ball", geom_name="ball", transform=t)
    path = tmp_path / "two.glb"
    sc.export(path)
    scene = load_scene(path)
    assert scene.num_objects == 2
    assert scene.num_triangles == len(a.faces) + len(b.faces)
    assert set(np.unique(scene.object_id)) == {0, 1}
    ball = scene.object_names.index("ball")
    centre = scene.triangles[scene.object_id == ball].reshape(-1, 3).mean(axis=0)
    np.testing.assert_allclose(centre, (10, 0, 0), atol=1e-6)


def test_report_finds_open_nonmanifold_and_degenerate():
    v = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1], [0, -1, 0], [2, 0, 0]], float)
    # three triangles on edge (0, 1): non-manifold; a zero-area triangle (0, 1, 5).
    f = np.array([[0, 1, 2], [1, 0, 3], [0, 1, 4], [0, 1, 5]])
    rep = mesh_report(Scene(v, f, np.zeros(4)))
    assert rep.degenerate_triangles == 1
    assert rep.nonmanifold_edges == 1
    assert rep.open_edges == 6
    assert not rep.objects[0].closed


def test_closed_object_detected_even_with_duplicated_vertices():
    box = _box()
    soup_v = box.vertices[box.faces].reshape(-1, 3)          # every corner duplicated
    soup_f = np.arange(len(soup_v)).reshape(-1, 3)
    rep = mesh_report(Scene(soup_v, soup_f, np.zeros(len(soup_f))))
    assert rep.objects[0].closed and rep.open_edges == 0


def test_inconsistent_winding_is_not_closed():
    box = _box()
    faces = box.faces.copy()
    faces[0] = faces[0][::-1]
    rep = mesh_report(Scene(box.vertices, faces, np.zeros(len(faces))))
    assert not rep.objects[0].closed


@pytest.mark.parametrize("name, content, message", [
    ("nan.obj", "v 0 0 0\nv 1 0 nan\nv 0 1 0\nf 1 2 3\n", "NaN or infinite"),
    ("inf.obj", "v 0 0 0\nv 1 0 inf\nv 0 1 0\nf 1 2 3\n", "NaN or infinite"),
    ("range.obj", "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 9\n", "out of range"),
    ("range.off", "OFF\n3 1 0\n0 0 0\n1 0 0\n0 1 0\n3 0 1 7\n", "range"),
    ("empty.obj", "v 0 0 0\nv 1 0 0\n", "empty"),
    ("empty.off", "OFF\n0 0 0\n", ""),
    ("garbage.ply", "this is not a ply file\n", "cannot be read"),
])
def test_bad_files_raise_clear_errors(tmp_path, name, content, message):
    path = tmp_path / name
    path.write_text(content)
    with pytest.raises(SceneError) as err:
        load_scene(path)
    assert str(path) in str(err.value)
    assert message in str(err.value)


def test_missing_file_and_unknown_format(tmp_path):
    with pytest.raises(SceneError, match="no such file"):
        load_scene(tmp_path / "nope.obj")
    other = tmp_path / "model.xyz"
    other.write_text("1 2 3\n")
    with pytest.raises(SceneError, match=r"unknown mesh format '\.xyz'.*\.obj"):
        load_scene(other)
    with pytest.raises(SceneError, match="directory"):
        load_scene(tmp_path)


def test_array_validation_names_the_problem():
    v = np.zeros((3, 3))
    with pytest.raises(SceneError, match="out of range"):
        Scene(v, np.array([[0, 1, 3]]), np.zeros(1))
    with pytest.raises(SceneError, match="no triangles"):
        Scene(v, np.zeros((0, 3)), np.zeros(0))
    with pytest.raises(SceneError, match=r"shape \[n, 3\]"):
        Scene(np.zeros((3, 2)), np.array([[0, 1, 2]]), np.zeros(1))
    with pytest.raises(SceneError, match="NaN"):
        Scene(np.array([[0, 0, 0], [1, 0, 0], [0, np.nan, 0]]), np.array([[0, 1, 2]]), np.zeros(1))


def test_parameters_for_a_file_are_an_error(tmp_path):
    path = tmp_path / "box.obj"
    _box().export(path)
    with pytest.raises(SceneError, match="only for procedural"):
        load_scene(path, seed=3)


def _report_per_object(scene):
    """Plain loop: each object's edges keyed by welded position, counted one by one."""
    weld = {}
    canon = np.array([weld.setdefault(tuple(p), len(weld)) for p in scene.vertices.tolist()])
    from shadowlab.scene.mesh import degenerate_mask

    degenerate = degenerate_mask(scene.triangles)
    out = []
    for oid in range(len(scene.object_names)):
        uses = {}
        for t in np.flatnonzero((scene.object_id == oid) & ~degenerate):
            f = canon[scene.faces[t]]
            for a, b in ((f[0], f[1]), (f[1], f[2]), (f[2], f[0])):
                if a != b:
                    key = (min(a, b), max(a, b))
                    n, o = uses.get(key, (0, 0))
                    uses[key] = (n + 1, o + (1 if a < b else -1))
        open_ = sum(n == 1 for n, _ in uses.values())
        nm = sum(n > 2 for n, _ in uses.values())
        consistent = all(o == 0 for n, o in uses.values() if n == 2)
        out.append((bool(uses) and open_ == 0 and nm == 0 and consistent, open_, nm))
    return out


@pytest.mark.parametrize("name,params", [("soup", {}), ("sphere_grid", {"n": 2, "objects": 7}),
                                         ("gate", {})])
def test_mesh_report_equals_a_per_object_loop(name, params):
    scene = load_scene(name, **params)
    rep = mesh_report(scene)
    want = _report_per_object(scene)
    got = [(o.closed, o.open_edges, o.nonmanifold_edges) for o in rep.objects]
    assert got == want
    assert rep.open_edges == sum(w[1] for w in want)
    assert any(w[0] for w in want) or name == "soup"
