"""The per-fragment bitmask rasterizer of tiled soft shadows (Kalbertodt 2023) as a kernel.

A thread per fragment (as the paper's fragment shader): the thread keeps the sun-disk
grid in registers (``words``, up to 31 uint32), initialises it to the disk mask (minus
the part below the receiver's horizon), and for each of its triangles builds the
triangle's edge functions in disk space, computes on every scanline the cells outside
each edge with one division per edge and one logical shift, ORs them and ANDs the
result into the grid. Visibility = set bits / disk bits. The arithmetic is that of
``shadowlab.structures.sun_disk`` (``project_paper`` / ``triangle_edges_2d`` or
``homogeneous_edges``, ``horizon_edge``, ``edge_outside_rows``, ``polygon_keep_rows``,
``pack_rows``, ``visibility``), which rounds every value deciding a bit in a fixed way
(opaque products, ordered sums, true divisions, negations for orientation). This file
does the same plain operations in the same order, compiled without contraction
(``fuse_fp=False``), so the grids are bit-identical, exact ties included.

Inputs are per fragment: the triangle vertices minus the fragment in its light frame
``d`` [F, T, 3, 3], the disk scale ``s`` [F], the receiver normal ``n`` [F, 3] (light
frame), ``active`` [F, T] (the tile list entries that pass the per-pixel quick reject)
and, for a sphere light, the silhouette depth ``z_light`` [F].
"""

from __future__ import annotations

import functools

import numpy as np
import warp as wp

from .runtime import init

wp.set_module_options({"fuse_fp": False, "enable_backward": False})

MAX_WORDS = 32
PROJECTIONS = {"paper": 0, "homogeneous": 1}
PAPER_CLAMP = 1e-4

Words = wp.types.vector(length=MAX_WORDS, dtype=wp.uint32)
Edges = wp.types.vector(length=5, dtype=wp.float32)


@wp.func
def _shr(x: wp.uint32, k: wp.uint32):
    """Logical right shift; a shift by 32 or more gives 0."""
    r = wp.uint32(0)
    if k < wp.uint32(32):
        r = x >> k
    return r


@wp.func
def _flip(x: wp.float32, neg: bool):
    """-x if neg (an orientation flip: a negation, as sun_disk._flip)."""
    r = x
    if neg:
        r = -x
    return r


@wp.func
def _edge_setup(a: wp.float32, b: wp.float32, c: wp.float32, c0: wp.float32,
                w: wp.float32):
    """Per-edge values of sun_disk.edge_outside_list: (step, base, t0, dt)."""
    step = a * w
    base = a * c0 + c                      # fuse_fp=False: rounded product, then add
    inv = wp.float32(0.0)
    if step != 0.0:                        # a NaN step divides too, as in JAX
        inv = wp.float32(-1.0) / step
    return wp.vec4f(step, base, base * inv, b * inv)


@wp.func
def _outside_row(e: wp.vec4f, b: wp.float32, y: wp.float32, cols: wp.int32,
                 full: wp.uint32):
    """Cells of a scanline at height y outside the edge set up by ``_edge_setup``
    (sun_disk's ``edge_outside_list`` for one row)."""
    step = e[0]
    nf = wp.float32(cols)
    out = wp.uint32(0)
    if step == 0.0:
        if e[1] + b * y < 0.0:
            out = full
    else:
        t = e[2] + e[3] * y
        if wp.isnan(t):
            t = nf + 1.0
        t = wp.min(wp.max(t, -1.0), nf + 1.0)
        if step > 0.0:
            first_in = wp.uint32(wp.min(wp.max(wp.ceil(t), 0.0), nf))
            out = full ^ _shr(full, first_in)          # columns 0 .. first_in - 1
        else:                                          # step < 0 or NaN
            first_out = wp.uint32(wp.min(wp.max(wp.floor(t) + 1.0, 0.0), nf))
            out = _shr(full, first_out)                # columns first_out .. cols - 1
    return out


@wp.func
def _and_row(words: Words, r: wp.int32, keep: wp.uint32, per_word: wp.int32):
    """AND a scanline's kept cells into the packed grid (16x16: row 2k in the high half)."""
    if per_word == 1:
        words[r] = words[r] & keep
    else:
        k = r >> 1
        if (r & 1) == 0:
            words[k] = words[k] & ((keep << wp.uint32(16)) | wp.uint32(0xFFFF))
        else:
            words[k] = words[k] & (keep | ~wp.uint32(0xFFFF))
    return words


@wp.kernel
def rasterize(d: wp.array4d(dtype=wp.float32), s_in: wp.array(dtype=wp.float32),
              n_in: wp.array2d(dtype=wp.float32), z_light: wp.array(dtype=wp.float32),
              active: wp.array2d(dtype=wp.int32), eps: wp.float32,
              disk: wp.array(dtype=wp.uint32), row_y: wp.array(dtype=wp.float32),
              cols: wp.int32, rows: wp.int32, per_word: wp.int32, full: wp.uint32,
              c0: wp.float32, w: wp.float32, inv_bits: wp.float32,
              projection: wp.int32, sphere: wp.int32, horizon: wp.int32,
              words_out: wp.array2d(dtype=wp.uint32), vis_out: wp.array(dtype=wp.float32),
              drawn_out: wp.array(dtype=wp.int32)):
    """A thread per fragment: rasterize its triangles into its sun-disk grid."""
    f = wp.tid()
    nwords = rows // per_word
    words = Words()
    for k in range(nwords):
        words[k] = disk[k]
    s = s_in[f]
    nx = n_in[f, 0]
    ny = n_in[f, 1]
    nz = n_in[f, 2]
    if horizon != 0:                     # clear the disk below the receiver's horizon
        hb = s * ny
        he = _edge_setup(s * nx, hb, nz, c0, w)
        for r in range(rows):
            below = _outside_row(he, hb, row_y[r], cols, full)
            words = _and_row(words, r, full & ~below, per_word)
    drawn = int(0)
    for t in range(d.shape[1]):
        if active[f, t] == 0:
            continue
        ea = Edges()
        eb = Edges()
        ec = Edges()
        ne = int(3)
        ok = bool(True)
        if projection == 0:
            # paper: q = d.xy * (1 / max(1e-4, s |z|)), then the 2-D triangle's edges
            qx = wp.vec3f()
            qy = wp.vec3f()
            for i in range(3):
                den = wp.max(wp.float32(PAPER_CLAMP), s * wp.abs(d[f, t, i, 2]))
                rec = wp.float32(1.0) / den
                qx[i] = d[f, t, i, 0] * rec
                qy[i] = d[f, t, i, 1] * rec
            term = wp.vec3f()
            for i in range(3):
                j = (i + 1) % 3
                ex = qx[j] - qx[i]
                ey = qy[j] - qy[i]
                ea[i] = -ey
                eb[i] = ex
                ec[i] = ey * qx[i] - ex * qy[i]
                term[i] = qx[i] * qy[j] - qx[j] * qy[i]
            area = (term[0] + term[1]) + term[2]
            neg = area < 0.0
            ok = area != 0.0
            for i in range(3):
                ea[i] = _flip(ea[i], neg)
                eb[i] = _flip(eb[i], neg)
                ec[i] = _flip(ec[i], neg)
        else:
            # homogeneous: u = (s x, s y, 1) hits the triangle iff u . (d_i x d_i+1)
            # has the sign of det(d0, d1, d2); plus the receiver-bias edge (and the
            # light's silhouette plane for a sphere light).
            m = wp.mat33f()
            for i in range(3):
                j = (i + 1) % 3
                ax = d[f, t, i, 0]
                ay = d[f, t, i, 1]
                az = d[f, t, i, 2]
                bx = d[f, t, j, 0]
                by = d[f, t, j, 1]
                bz = d[f, t, j, 2]
                m[i, 0] = ay * bz - az * by
                m[i, 1] = az * bx - ax * bz
                m[i, 2] = ax * by - ay * bx
            det = (d[f, t, 2, 0] * m[0, 0] + d[f, t, 2, 1] * m[0, 1]) \
                + d[f, t, 2, 2] * m[0, 2]
            neg = det < 0.0
            ok = det != 0.0
            for i in range(3):
                ea[i] = s * _flip(m[i, 0], neg)
                eb[i] = s * _flip(m[i, 1], neg)
                ec[i] = _flip(m[i, 2], neg)
            e1x = d[f, t, 1, 0] - d[f, t, 0, 0]
            e1y = d[f, t, 1, 1] - d[f, t, 0, 1]
            e1z = d[f, t, 1, 2] - d[f, t, 0, 2]
            e2x = d[f, t, 2, 0] - d[f, t, 0, 0]
            e2y = d[f, t, 2, 1] - d[f, t, 0, 1]
            e2z = d[f, t, 2, 2] - d[f, t, 0, 2]
            ntx = e1y * e2z - e1z * e2y
            nty = e1z * e2x - e1x * e2z
            ntz = e1x * e2y - e1y * e2x
            ad = wp.abs(det)
            es = _flip(eps, neg)
            ea[3] = s * (ad * nx - es * ntx)
            eb[3] = s * (ad * ny - es * nty)
            ec[3] = ad * nz - es * ntz
            ne = 4
            if sphere != 0:
                zl = z_light[f]
                ea[4] = _flip(s * (zl * ntx), neg)
                eb[4] = _flip(s * (zl * nty), neg)
                ec[4] = _flip(zl * ntz - det, neg)
                ne = 5
        if not ok:
            continue
        drawn += 1
        es0 = _edge_setup(ea[0], eb[0], ec[0], c0, w)
        es1 = _edge_setup(ea[1], eb[1], ec[1], c0, w)
        es2 = _edge_setup(ea[2], eb[2], ec[2], c0, w)
        es3 = _edge_setup(ea[3], eb[3], ec[3], c0, w)
        es4 = _edge_setup(ea[4], eb[4], ec[4], c0, w)
        for r in range(rows):
            y = row_y[r]
            out = _outside_row(es0, eb[0], y, cols, full)
            out = out | _outside_row(es1, eb[1], y, cols, full)
            out = out | _outside_row(es2, eb[2], y, cols, full)
            if ne > 3:
                out = out | _outside_row(es3, eb[3], y, cols, full)
            if ne > 4:
                out = out | _outside_row(es4, eb[4], y, cols, full)
            words = _and_row(words, r, out, per_word)      # keep the cells outside
    bits = int(0)
    for k in range(nwords):
        words_out[f, k] = words[k]
        bits += wp.bit_count(words[k])
    vis_out[f] = wp.float32(bits) * inv_bits     # sun_disk.visibility: popcount * fl(1/bits)
    drawn_out[f] = drawn


def visibility(d, s, n, *, grid: str = "16x16", projection: str = "paper",
               eps: float = 0.0, z_light=None, active=None, horizon: bool = False,
               device: str | None = None) -> dict:
    """Rasterize every fragment's triangles into its grid (a thread per fragment).

    Args:
        d: [F, T, 3, 3] triangle vertices minus the fragment, light frame (+z to the light).
        s: [F] disk scale; n: [F, 3] receiver normal (light frame); eps: receiver bias.
        z_light: None (sun) or [F] silhouette depth (sphere light, homogeneous only).
        active: [F, T] bool, triangles to rasterize (default all).
        horizon: clear the disk below the receiver's tangent plane first.
    Returns:
        dict: ``words`` uint32 [F, W], ``visibility`` float32 [F], ``rasterized`` int32
        [F] (triangles drawn: active and non-degenerate).
    """
    from ..structures import sun_disk as sd

    dev = init(device)
    g = sd.grid(grid)
    d = np.ascontiguousarray(d, np.float32)
    f_count, t_count = d.shape[:2]
    if active is None:
        active = np.ones((f_count, t_count), bool)
    sphere = z_light is not None
    if sphere and projection != "homogeneous":
        raise ValueError("a sphere light's silhouette edge needs projection='homogeneous'")
    zl = np.zeros(f_count, np.float32) if z_light is None else z_light
    _, ys = g.centres()
    w64 = 2.0 / g.cols
    f32 = np.float32

    def arr(a, dtype):
        a = np.ascontiguousarray(a, dtype)
        return wp.array(a, dtype=wp.dtype_from_numpy(a.dtype), device=dev)

    words = wp.zeros((max(f_count, 1), g.words), dtype=wp.uint32, device=dev)
    vis = wp.zeros(max(f_count, 1), dtype=wp.float32, device=dev)
    drawn = wp.zeros(max(f_count, 1), dtype=wp.int32, device=dev)
    if f_count:
        wp.launch(rasterize, dim=f_count, device=dev, inputs=[
            wp.array(d, dtype=wp.float32, device=dev), arr(np.broadcast_to(s, (f_count,)), f32),
            arr(n, f32), arr(zl, f32), arr(active, np.int32), f32(eps),
            arr(g.disk_mask(), np.uint32), arr(ys, f32), g.cols, g.rows, g.per_word,
            int(g.full_row), f32(-1.0 + 0.5 * w64), f32(w64), f32(1) / f32(g.disk_bits),
            PROJECTIONS[projection], int(sphere), int(horizon),
            words, vis, drawn])
    return {"words": words.numpy()[:f_count], "visibility": vis.numpy()[:f_count],
            "rasterized": drawn.numpy()[:f_count]}


def jax_visibility(d, s, n, *, grid: str = "16x16", projection: str = "paper",
                   eps: float = 0.0, z_light=None, active=None, horizon: bool = False):
    """The same rasterizer composed from the JAX primitives of ``methods.sun_disk``
    (vectorized over fragments and triangles): the version the kernel must equal."""
    import jax.numpy as jnp

    d = np.asarray(d, np.float32)
    f_count, t_count = d.shape[:2]
    if active is None:
        active = np.ones((f_count, t_count), bool)
    run = _jax_rasterizer(grid, projection, float(eps), z_light is not None, bool(horizon))
    zl = jnp.zeros(f_count, jnp.float32) if z_light is None else jnp.asarray(z_light,
                                                                             jnp.float32)
    words, vis, drawn = run(jnp.asarray(d), jnp.asarray(np.broadcast_to(s, (f_count,)),
                                                        jnp.float32),
                            jnp.asarray(n, jnp.float32), zl, jnp.asarray(active))
    return {"words": np.asarray(words), "visibility": np.asarray(vis),
            "rasterized": np.asarray(drawn).astype(np.int32)}


@functools.lru_cache(maxsize=None)
def _jax_rasterizer(grid, projection, eps, sphere, horizon):
    import jax
    import jax.numpy as jnp

    from ..core.numerics import opaque_zero
    from ..structures import sun_disk as sd

    g = sd.grid(grid)

    @jax.jit
    def run(d, s, n, zl, active):
        f_count, t_count = d.shape[:2]
        zero = opaque_zero(s, jnp.int32)       # one opaque zero for every product
        words = jnp.broadcast_to(jnp.asarray(g.disk_mask()), (f_count, g.words))
        if horizon:
            he = sd.horizon_edge_list((n[:, 0], n[:, 1], n[:, 2]), s, zero)
            below = sd.edge_outside_rows(*he, g, zero)
            words = words & ~sd.pack_rows(below, g)
        sb = jnp.broadcast_to(s[:, None], (f_count, t_count))
        nb = jnp.broadcast_to(n[:, None, :], (f_count, t_count, 3))
        if projection == "paper":
            q = sd.project_paper(d, sb[..., None], zero)
            edges, ok = sd.triangle_edges_2d(q, zero)
        else:
            zlb = jnp.broadcast_to(zl[:, None], (f_count, t_count)) if sphere else None
            edges, ok = sd.homogeneous_edges(d, sb, nb, eps, zlb, zero)
        keep = sd.pack_rows(sd.polygon_keep_rows(edges, g, active & ok, zero), g)  # [F, T, W]
        for t in range(t_count):
            words = words & keep[:, t]
        return words, sd.visibility(words, g), jnp.sum(active & ok, axis=1)

    return run


def load(device: str | None = None) -> None:
    """Compile (or load from the kernel cache) this file's kernels on ``device``."""
    wp.load_module(rasterize.module, device=init(device))
