"""The Warp multiplicity kernel equals the JAX method's s_T and m bit for bit (float32),
on the soup (non-manifold, degenerate) and on the grazing sheet, where s_T is a rounding
decision for most triangles; the Warp visibility test of the sides takes the decisions of
``clip_visibility.side_visible`` bit for bit (float32 and float64)."""

import jax.numpy as jnp
import numpy as np
import pytest

pytest.importorskip("warp")

import shadowlab as sl  # noqa: E402
from shadowlab.kernels import silhouette as ks  # noqa: E402
from shadowlab.methods.silhouette import record_multiplicity, triangle_signs  # noqa: E402
from shadowlab.scene.procedural import grazing_sheet  # noqa: E402

pytestmark = pytest.mark.kernels


def _jax(scene, lh, eye):
    adj = scene.adjacency("object", 2, np.float32)
    verts = (adj.positions.astype(np.float64) - eye).astype(np.float32)
    lrel = np.append(lh[:3] - lh[3] * eye, lh[3]).astype(np.float32)
    srt = np.sort(adj.faces, axis=1)
    s, _ = triangle_signs(*(jnp.asarray(verts[srt[:, k]]) for k in range(3)), jnp.asarray(lrel))
    s = np.where(adj.kept, np.asarray(s), 0).astype(np.int32)
    return s, record_multiplicity(adj, s, verts, lrel, "sorted")


@pytest.mark.parametrize("case", ["soup", "grazing", "directional"])
def test_multiplicity_kernel_is_bit_identical(case):
    if case == "grazing":
        scene, lh, eye = grazing_sheet(), np.array([-2.0, 1.0, 0.3, 1.0]), np.zeros(3)
    else:
        scene = sl.load_scene("soup", count=120)
        lh = (np.array([3.0, 9.0, 2.0, 1.0]) if case == "soup"
              else np.array([0.3, 0.9, 0.2, 0.0]))
        eye = np.array([1.5, 4.0, 12.0])
    s, m = _jax(scene, lh, eye)
    out = ks.multiplicity(scene, lh, eye)
    assert np.array_equal(out["sign"], s)
    assert np.array_equal(out["m"], m)
    assert out["side_quads"] == int(np.abs(m).sum()) and out["silhouette_edges"] > 0


def _random_sides(n, seed):
    """Edges and point lights far outside a 60-degree view (as in test_silhouette), plus
    the camera: many sides cross the view only through the quad's interior."""
    cam = sl.Camera(eye=(0.3, -0.2, 0.5), target=(0.3, -0.2, -0.5), up=(0, 1, 0),
                    fov_y_deg=60.0, near=0.1, far=100.0, resolution=(16, 16))
    rng = np.random.default_rng(seed)

    def far(r):
        d = rng.normal(size=(n, 3))
        return d / np.linalg.norm(d, axis=1, keepdims=True) * r + cam.eye

    return far(rng.uniform(20, 60, (n, 1))), far(rng.uniform(20, 60, (n, 1))), \
        far(rng.uniform(5, 60, (n, 1))), cam


@pytest.mark.parametrize("dtype", [np.float32, np.float64])
@pytest.mark.parametrize("mode", ["paper", "exact"])
def test_visibility_kernel_is_bit_identical(mode, dtype):
    """The Warp visibility test culls exactly the sides side_visible culls, in float32
    and float64, on random far sides (point and directional lights) and on a scene's
    silhouette records, where the method's culled_sides counter must match."""
    from shadowlab.geometry.clip_visibility import side_visible
    a, b, lp, cam = _random_sides(1500, 5)
    for i, lh in enumerate([np.append(lp[k], 1.0) for k in range(300)] +
                           [np.array([0.3, 0.9, -0.2, 0.0])]):
        sel = slice(None) if i == 300 else slice(5 * i, 5 * i + 5)
        ref = side_visible(a[sel], b[sel], lh, cam, mode, dtype=dtype)
        out = ks.side_visibility_mask(a[sel], b[sel], lh, cam, mode, dtype=dtype)
        assert np.array_equal(out["visible"], ref), i
    # a scene: the records the method draws, with its own counter
    scene = sl.load_scene("gate", trees=3, leaves_per_tree=40, bars=4)
    from shadowlab.scene.procedural import default_view
    view = default_view("gate", scene, trees=3, leaves_per_tree=40, bars=4)
    gbuf = sl.render_gbuffer(scene, view.camera.replace(resolution=(16, 16)))
    res = sl.compute_shadows(scene, gbuf, view.light, method="silhouette", cull_sides=mode,
                             bins="off", chunk=4)
    adj = scene.adjacency("object", 2, np.float32)
    _, m = _jax(scene, view.light.homogeneous, np.asarray(gbuf.camera.eye))
    ev = adj.edge_vertices[adj.record_edge[np.flatnonzero(m)]]
    p = adj.positions.astype(np.float64)
    lh = view.light.homogeneous
    ref = side_visible(p[ev[:, 0]], p[ev[:, 1]], lh, gbuf.camera, mode, dtype=dtype)
    out = ks.side_visibility_mask(p[ev[:, 0]], p[ev[:, 1]], lh, gbuf.camera, mode, dtype=dtype)
    assert np.array_equal(out["visible"], ref)
    assert 0 < out["culled_sides"] < len(ev)
    if dtype == np.float64:
        assert out["culled_sides"] == res.counters["culled_sides"]
