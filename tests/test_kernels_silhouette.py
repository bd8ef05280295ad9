"""The Warp multiplicity kernel equals the JAX method's s_T and m bit for bit (float32),
on the soup (non-manifold, degenerate) and on the grazing sheet, where s_T is a rounding
decision for most triangles."""

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
