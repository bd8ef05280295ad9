"""Per-edge multiplicity of silhouette shadow volumes as Warp kernels (Pečiva 2013).

The twin of the multiplicity stage of ``shadowlab.methods.silhouette``: a thread per
triangle computes s_T (Algorithm 2 on the sorted, eye-relative vertices), a thread per
edge record sums ``parity * s_T`` over its slots (Algorithm 1). The module is compiled
with ``fuse_fp=False`` and writes every product and sum in the order of
``methods.silhouette.triangle_signs`` (whose products are opaque to contraction), so
s_T, and with it m, equal the JAX method's bit for bit. float32 only (the GPU's).

The clip-space visibility test of the sides (``geometry.clip_visibility``, option
``cull_sides``) is a third kernel, a thread per side, generic in float32 and float64:
it repeats the NumPy test's products and sums in their order, so its cull decisions
(and the ``culled_sides`` counter) equal ``side_visible`` in the same dtype bit for bit.
The stencil is not part of this twin.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import warp as wp

from ..geometry.clip_visibility import CULL_MODES, MARGIN, screen_corner_rays

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


@wp.func
def _corner(m: wp.array2d(dtype=Any), i: int, x0: Any, x1: Any, x2: Any, x3: Any):
    """Row i of ``m (x0, x1, x2, x3)``: ((m_i0 x0 + m_i1 x1) + m_i2 x2) + m_i3 x3."""
    return ((x0 * m[i, 0] + x1 * m[i, 1]) + x2 * m[i, 2]) + x3 * m[i, 3]


@wp.func
def _segment_visible(p: Any, q: Any, axes: int, widen: Any):
    """Algorithm 3 (Liang-Barsky) on clip-space points p, q (vec4): 1 if the segment meets
    |x|, |y| (and |z| with axes = 3) <= widen w."""
    zero = widen - widen
    left = zero
    right = zero + widen / widen
    ok = int(1)
    wpv = p[3] * widen
    wqv = q[3] * widen
    for i in range(axes):
        for k in range(2):
            m = wpv + p[i]
            n = wqv + q[i]
            if k == 1:
                m = -p[i] + wpv
                n = -q[i] + wqv
            v = n - m
            if v == zero and m < zero:
                ok = 0
            if v > zero:
                left = wp.max(left, -m / v)
            if v < zero:
                right = wp.min(right, -m / v)
    if ok == 1 and left <= right:
        return 1
    return 0


@wp.func
def _flip(x: Any, diag: int):
    """x (vec4) with component ``diag`` negated (none for diag = -1)."""
    x0 = x[0]
    x1 = x[1]
    x2 = x[2]
    if diag == 0:
        x0 = -x[0]
    if diag == 1:
        x1 = -x[1]
    if diag == 2:
        x2 = -x[2]
    return wp.vector(x0, x1, x2, x[3])


@wp.func
def _cross_dot(a0: Any, a1: Any, a2: Any, b0: Any, b1: Any, b2: Any, d0: Any, d1: Any,
               d2: Any):
    """(a x b) . d with the NumPy test's order: components a_i b_j - a_j b_i, ordered dot."""
    c0 = a1 * b2 - a2 * b1
    c1 = a2 * b0 - a0 * b2
    c2 = a0 * b1 - a1 * b0
    return (c0 * d0 + c1 * d1) + c2 * d2


@wp.kernel
def side_visibility(a: wp.array2d(dtype=Any), b: wp.array2d(dtype=Any),
                    light: wp.array(dtype=Any), vp: wp.array2d(dtype=Any),
                    eye: wp.array(dtype=Any), rays: wp.array2d(dtype=Any),
                    widen: wp.array(dtype=Any), exact: int, out: wp.array(dtype=wp.int32)):
    r = wp.tid()
    zero = light[3] - light[3]
    one = widen[1]
    lw = light[3]
    ax = a[r, 0]
    ay = a[r, 1]
    az = a[r, 2]
    bx = b[r, 0]
    by = b[r, 1]
    bz = b[r, 2]
    cx = ax * lw - light[0]
    cy = ay * lw - light[1]
    cz = az * lw - light[2]
    dx = bx * lw - light[0]
    dy = by * lw - light[1]
    dz = bz * lw - light[2]
    ac = wp.vector(_corner(vp, 0, ax, ay, az, one), _corner(vp, 1, ax, ay, az, one),
                   _corner(vp, 2, ax, ay, az, one), _corner(vp, 3, ax, ay, az, one))
    bc = wp.vector(_corner(vp, 0, bx, by, bz, one), _corner(vp, 1, bx, by, bz, one),
                   _corner(vp, 2, bx, by, bz, one), _corner(vp, 3, bx, by, bz, one))
    cc = wp.vector(_corner(vp, 0, cx, cy, cz, zero), _corner(vp, 1, cx, cy, cz, zero),
                   _corner(vp, 2, cx, cy, cz, zero), _corner(vp, 3, cx, cy, cz, zero))
    dc = wp.vector(_corner(vp, 0, dx, dy, dz, zero), _corner(vp, 1, dx, dy, dz, zero),
                   _corner(vp, 2, dx, dy, dz, zero), _corner(vp, 3, dx, dy, dz, zero))
    axes = 3
    wdn = one
    if exact == 1:
        axes = 2
        wdn = widen[0]
    vis = _segment_visible(ac, bc, axes, wdn)
    vis = vis | _segment_visible(ac, cc, axes, wdn)
    vis = vis | _segment_visible(bc, dc, axes, wdn)
    vis = vis | _segment_visible(cc, dc, axes, wdn)
    if exact == 0:
        # Algorithm 4: the side normal transformed as a vector picks the diagonal
        ex = bx - ax
        ey = by - ay
        ez = bz - az
        tx = light[0] - lw * ax
        ty = light[1] - lw * ay
        tz = light[2] - lw * az
        n0 = ey * tz - ez * ty
        n1 = ez * tx - ex * tz
        n2 = ex * ty - ey * tx
        u0 = int(0)
        u1 = int(0)
        u2 = int(0)
        if (n0 * vp[0, 0] + n1 * vp[0, 1]) + n2 * vp[0, 2] > zero:
            u0 = 1
        if (n0 * vp[1, 0] + n1 * vp[1, 1]) + n2 * vp[1, 2] > zero:
            u1 = 1
        if (n0 * vp[2, 0] + n1 * vp[2, 1]) + n2 * vp[2, 2] > zero:
            u2 = 1
        if u2 == 1:
            u0 = 1 - u0
            u1 = 1 - u1
        diag = u0 + 2 * u1 - 1
        # Algorithm 5: the parallelogram ac + t f + l g against that diagonal
        f = bc - ac
        g = cc - ac
        av = _flip(ac, diag)
        bv = _flip(f, diag)
        cv = _flip(g, diag)
        m = av[0] - av[1]
        n = bv[0] - bv[1]
        o = cv[0] - cv[1]
        p = av[0] - av[2]
        q = bv[0] - bv[2]
        rr = cv[0] - cv[2]
        d = q * o - n * rr
        if d != zero:
            t = (m * rr - p * o) / d
            l = -(m * q - p * n) / d
            if t > zero and t < one and l > zero and l < one:
                inside = int(1)
                for i in range(3):
                    xi = (ac[i] + t * f[i]) + l * g[i]
                    xw = (ac[3] + t * f[3]) + l * g[3]
                    if -xw >= xi or xi >= xw:
                        inside = 0
                vis = vis | inside
    else:
        # the four screen-corner eye rays against the quad
        px = ax - eye[0]
        py = ay - eye[1]
        pz = az - eye[2]
        qx = bx - eye[0]
        qy = by - eye[1]
        qz = bz - eye[2]
        lx = light[0] - lw * eye[0]
        ly = light[1] - lw * eye[1]
        lz = light[2] - lw * eye[2]
        pi3 = -_cross_dot(px, py, pz, qx, qy, qz, lx, ly, lz)
        for k in range(rays.shape[0]):
            d0 = rays[k, 0]
            d1 = rays[k, 1]
            d2 = rays[k, 2]
            sa = _cross_dot(lx, ly, lz, px, py, pz, d0, d1, d2)
            sb = _cross_dot(lx, ly, lz, qx, qy, qz, d0, d1, d2)
            pi1 = _cross_dot(px, py, pz, qx, qy, qz, d0, d1, d2)
            rho = _cross_dot(lx - lw * px, ly - lw * py, lz - lw * pz, qx - px, qy - py,
                             qz - pz, d0, d1, d2)
            if (sa >= zero) != (sb >= zero) and (pi1 >= zero) == (rho >= zero) and \
                    (rho >= zero) == (pi3 >= zero):
                vis = 1
    out[r] = vis


def side_visibility_mask(a: np.ndarray, b: np.ndarray, light_h: np.ndarray, camera,
                         mode: str, dtype=np.float32, device: str | None = None) -> dict:
    """The visibility test of side quads (edges a, b [N, 3], world or frame-local units,
    light_h [4]) as ``clip_visibility.side_visible(..., mode, dtype=dtype)`` computes it.

    Args:
        mode: "paper" (Algorithms 3-6, the paper's diagonal) or "exact".
        dtype: np.float32 or np.float64 (inputs, matrix, eye and rays rounded to it).
    Returns:
        ``visible`` bool [N] and the counter ``culled_sides``.
    """
    if mode not in CULL_MODES or mode == "off":
        raise ValueError(f"mode must be 'paper' or 'exact', got {mode!r}")
    dev = init(device)
    wt = wp.float32 if np.dtype(dtype) == np.float32 else wp.float64
    n = len(a)

    def arr(x):
        return wp.array(np.ascontiguousarray(np.asarray(x, dtype)), dtype=wt, device=dev)

    out = wp.zeros(max(n, 1), dtype=wp.int32, device=dev)
    if n:
        widen = np.array([1 + MARGIN, 1.0])
        wp.launch(side_visibility, dim=n, device=dev, inputs=[
            arr(a), arr(b), arr(light_h), arr(camera.view_projection()), arr(camera.eye),
            arr(screen_corner_rays(camera)), arr(widen), int(mode == "exact"), out])
    vis = out.numpy()[:n].astype(bool)
    return {"visible": vis, "culled_sides": int((~vis).sum())}
