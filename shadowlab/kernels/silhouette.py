"""Per-edge multiplicity of silhouette shadow volumes as Warp kernels (Pečiva 2013).

The twin of the multiplicity stage of ``shadowlab.methods.silhouette``: a thread per
triangle computes s_T (Algorithm 2 on the sorted, eye-relative vertices), a thread per
edge record sums ``parity * s_T`` over its slots (Algorithm 1). The module is compiled
with ``fuse_fp=False`` and writes every product and sum in the order of
``methods.silhouette.triangle_signs`` (whose products are opaque to contraction), so
s_T, and with it m, equal the JAX method's bit for bit. float32 only (the GPU's).
The clip-space visibility test and the stencil are not part of this twin.
"""

from __future__ import annotations

import numpy as np
import warp as wp

from .runtime import init

wp.set_module_options({"fuse_fp": False, "enable_backward": False})


@wp.kernel
def triangle_sign(lo: wp.array2d(dtype=wp.float32), mid: wp.array2d(dtype=wp.float32),
                  hi: wp.array2d(dtype=wp.float32), light: wp.array(dtype=wp.float32),
                  out: wp.array(dtype=wp.int32)):
    t = wp.tid()
    lw = light[3]
    a0 = lo[t, 0]
    a1 = lo[t, 1]
    a2 = lo[t, 2]
    t0 = light[0] - lw * a0
    t1 = light[1] - lw * a1
    t2 = light[2] - lw * a2
    u0 = hi[t, 0] - a0
    u1 = hi[t, 1] - a1
    u2 = hi[t, 2] - a2
    n0 = u1 * t2 - u2 * t1
    n1 = u2 * t0 - u0 * t2
    n2 = u0 * t1 - u1 * t0
    w0 = mid[t, 0] - a0
    w1 = mid[t, 1] - a1
    w2 = mid[t, 2] - a2
    v = (n0 * w0 + n1 * w1) + n2 * w2
    s = wp.int32(0)
    if v > wp.float32(0.0):
        s = wp.int32(1)
    if v < wp.float32(0.0):
        s = wp.int32(-1)
    out[t] = s


@wp.kernel
def record_multiplicity(rec_vertices: wp.array2d(dtype=wp.int32),
                        slot_triangle: wp.array2d(dtype=wp.int32),
                        slot_opposite: wp.array2d(dtype=wp.int32),
                        sign: wp.array(dtype=wp.int32), out: wp.array(dtype=wp.int32)):
    r = wp.tid()
    a = rec_vertices[r, 0]
    b = rec_vertices[r, 1]
    m = wp.int32(0)
    for k in range(slot_triangle.shape[1]):
        t = slot_triangle[r, k]
        if t >= 0:
            o = slot_opposite[r, k]
            if a < o and o < b:
                m = m - sign[t]
            else:
                m = m + sign[t]
    out[r] = m


def multiplicity(scene, light_h: np.ndarray, eye: np.ndarray, *, adjacency: str = "object",
                 max_opposite: int = 2, active: np.ndarray | None = None,
                 device: str | None = None) -> dict:
    """s_T and m as the JAX method computes them (float32, ``multiplicity="sorted"``).

    Args:
        scene: the scene; light_h: float64 [4] homogeneous light; eye: float64 [3], the
            frame origin (the camera's eye).
        active: bool [m] triangles allowed to cast (default: the adjacency's kept ones);
            the method also drops the setup's degenerate/edge-on ones (``degenerate``).
    Returns:
        ``sign`` int32 [m] (0 where not active), ``m`` int32 [R], and the counters
        ``edges``, ``silhouette_edges``, ``side_quads``.
    """
    dev = init(device)
    adj = scene.adjacency(adjacency, max_opposite, np.float32)
    verts = (adj.positions.astype(np.float64) - eye).astype(np.float32)
    lrel = np.append(light_h[:3] - light_h[3] * eye, light_h[3]).astype(np.float32)
    srt = np.sort(adj.faces, axis=1)
    n = len(srt)
    out = wp.zeros(n, dtype=wp.int32, device=dev)
    if n:
        wp.launch(triangle_sign, dim=n, device=dev, inputs=[
            wp.array(verts[srt[:, 0]], dtype=wp.float32, device=dev),
            wp.array(verts[srt[:, 1]], dtype=wp.float32, device=dev),
            wp.array(verts[srt[:, 2]], dtype=wp.float32, device=dev),
            wp.array(lrel, dtype=wp.float32, device=dev), out])
    sign = out.numpy()
    keep = adj.kept if active is None else (adj.kept & active)
    sign = np.where(keep, sign, 0).astype(np.int32)
    r = len(adj.record_edge)
    m = wp.zeros(r, dtype=wp.int32, device=dev)
    if r:
        wp.launch(record_multiplicity, dim=r, device=dev, inputs=[
            wp.array(np.ascontiguousarray(adj.record_vertices), dtype=wp.int32, device=dev),
            wp.array(np.ascontiguousarray(adj.triangle), dtype=wp.int32, device=dev),
            wp.array(np.ascontiguousarray(adj.opposite), dtype=wp.int32, device=dev),
            wp.array(sign, dtype=wp.int32, device=dev), m])
    m = m.numpy()
    return {"sign": sign, "m": m, "edges": int(r), "silhouette_edges": int(np.count_nonzero(m)),
            "side_quads": int(np.abs(m).sum())}
