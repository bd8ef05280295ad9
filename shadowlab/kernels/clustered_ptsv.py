"""Clustered per-triangle shadow volume kernels (Sintorn et al. 2014, Algorithm 1).

Stages, each a kernel (or two) with the same inputs, rounding and counters as
``shadowlab.methods.clustered_ptsv`` (docs/clustered_ptsv.md, docs/kernels.md):

- ``build_lanes`` / ``build_tile``: the hierarchy. One 8x8 tile per warp: the tile's 64
  samples (two per lane) repeatedly pick the smallest key left in the tile (a cluster),
  reduce its box and minimum bias scale across the lanes, and lane 0 updates every
  level above it with atomic OR (child-mask bits, phase 0) or atomic min / max
  (boxes, phase 1; compact storage needs the pointers of phase 0 first). ``pad_boxes``
  pads the boxes as ``cluster_hierarchy.pad_box`` does.
- ``setup``: a thread per triangle: the four world-space shadow-volume planes (the math
  of ``geometry.triangle_setup.shadow_volume_planes``), the post-perspective rows, the three
  extra culling planes and the tolerances (``volume_planes.post_perspective_planes``).
- ``traverse_lanes`` / ``traverse_warp``: Algorithm 1 with persistent workers pulling
  jobs from an atomic counter. A job is a triangle (pass 1, from the root) or a
  (triangle, node) pair (pass 2 of the two-pass variant, from level L). Each visit of
  an inner node tests its 32 children, one per lane, ballots the accept and intersect
  bits, records accepts with an atomic OR (and, when pruning, clears them from the
  node's mask with an atomic AND), and descends into the intersected children highest
  bit first (31 - clz) with an explicit per-level stack (the paper's iterative form).
  At level L of pass 1 the child is pushed onto the job list instead; at the leaves
  the lanes test the tile's samples (test-and-set).
- ``merge``: a thread per sample: shadowed by a leaf test, or inside a node some
  triangle trivially accepted.

Two forms of the warp-level kernels:

- *faithful* (``form="lanes"``): one Warp thread per lane, 32-thread blocks
  (``wp.launch_tiled(block_dim=32)``; cooperative fibers on the CPU backend). Ballot =
  a bit-OR tile reduction of ``1 << lane``, broadcast = a tile sum, cluster bounds =
  tile min / max.
- *fast* (``form="warp"``): one thread per warp, looping over the 32 lanes (same
  results, no block synchronisation; what a CPU runs fastest).

Float rounding: compiled with ``fuse_fp=False``. The setup is plain operations in the
order of the JAX setup, which never fuses them (``core.numerics.opaque_mul``); where the
JAX leaf test and box padding let XLA fuse multiply-adds on this machine, the kernels
place the same FMAs explicitly (``fma`` flag, see ``psv.xla_contracts`` and
docs/kernels.md).
"""

from __future__ import annotations

import functools
import time

import numpy as np
import warp as wp

from ..core.capacity import check_int32, retry_on_overflow
from .psv import fma32, xla_contracts
from .runtime import init

# block_dim 32: the faithful kernels' tiles are one warp (their CUDA build, ahead of time)
wp.set_module_options({"fuse_fp": False, "enable_backward": False, "block_dim": 32})

MAX_LEVELS = 8                         # mask levels + 1 (keys of at most 32 bits: 7 levels)
SENTINEL = 0xFFFFFFFF                  # "no key" (keys have fewer than 32 bits): ~0 in kernels
TILE_PIXELS = 64                       # an 8 x 8 tile
N_COUNTS = 5                           # node tests, accepts, rejects, extra rejects, leaf visits
FORMS = ("lanes", "warp")

U32Vec = wp.types.vector(length=MAX_LEVELS, dtype=wp.uint32)
I32Vec = wp.types.vector(length=MAX_LEVELS, dtype=wp.int32)


@wp.func_native("""
#if defined(__CUDA_ARCH__)
return __clz((int)x);
#else
return x == 0u ? 32 : __builtin_clz(x);
#endif
""")
def clz(x: wp.uint32) -> wp.int32:
    """Count leading zeros (CUDA's __clz)."""


@wp.func_native("""
#if defined(__CUDA_ARCH__)
return __popc(x);
#else
return __builtin_popcount(x);
#endif
""")
def popc(x: wp.uint32) -> wp.int32:
    """Population count (CUDA's __popc)."""


# --------------------------------------------------------------------------- setup

@wp.func
def _mul_add(a: wp.float32, b: wp.float32, c: wp.float32, fma: wp.int32):
    if fma != 0:
        return fma32(a, b, c)
    return a * b + c


@wp.func
def _dot3(a: wp.vec3f, b: wp.vec3f):
    return (a[0] * b[0] + a[1] * b[1]) + a[2] * b[2]


@wp.func
def _norm(a: wp.vec3f):
    return wp.sqrt(_dot3(a, a))


@wp.func
def _cross(a: wp.vec3f, b: wp.vec3f):
    return wp.vec3f(a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2],
                    a[0] * b[1] - a[1] * b[0])


@wp.func
def _lex_less(a: wp.vec3f, b: wp.vec3f):
    return (a[0] < b[0]) or (a[0] == b[0] and (a[1] < b[1] or (a[1] == b[1] and a[2] < b[2])))


@wp.func
def _store_plane(planes: wp.array2d(dtype=wp.float32), t: wp.int32, row: wp.int32,
                 n: wp.vec3f, d: wp.float32, length: wp.float32):
    safe = wp.where(length > 0.0, length, wp.float32(1.0))
    planes[t, 4 * row + 0] = n[0] / safe
    planes[t, 4 * row + 1] = n[1] / safe
    planes[t, 4 * row + 2] = n[2] / safe
    planes[t, 4 * row + 3] = d / safe


@wp.kernel
def setup(tri: wp.array3d(dtype=wp.float32), light: wp.vec4f, inv_view: wp.mat44f,
          r00: wp.float32, r11: wp.float32, qmax: wp.float32, pmax: wp.float32,
          degen: wp.float32, extra: wp.int32, world: wp.int32,
          planes: wp.array2d(dtype=wp.float32), valid: wp.array(dtype=wp.int32),
          g: wp.array3d(dtype=wp.float32), tol: wp.array2d(dtype=wp.float32)):
    """A thread per triangle: world planes [T, 16], valid [T] (``world=0``: given in
    ``planes`` / ``valid``), post-perspective rows g [T, 7, 4] (edges, cap, three extra
    culling planes) and tolerances tol [T, 7]. The operations of ``shadow_volume_planes``
    and ``volume_planes.post_perspective_planes`` in their order, one rounding each
    (``fuse_fp=False``), so the results are equal bit for bit."""
    t = wp.tid()
    if world != 0:
        _world_planes(t, tri, light, degen, planes, valid)
    _post_perspective(t, inv_view, r00, r11, qmax, pmax, extra, planes, g, tol)


@wp.func
def _world_planes(t: wp.int32, tri: wp.array3d(dtype=wp.float32), light: wp.vec4f,
                  degen: wp.float32, planes: wp.array2d(dtype=wp.float32),
                  valid: wp.array(dtype=wp.int32)):
    """geometry.triangle_setup.shadow_volume_planes for triangle t."""
    v = wp.mat33f()
    for i in range(3):
        for k in range(3):
            v[i, k] = tri[t, i, k]
    lxyz = wp.vec3f(light[0], light[1], light[2])
    ok = bool(True)  # noqa: UP018 (a dynamic Warp variable)
    for e in range(3):
        a = v[e]
        b = v[(e + 1) % 3]
        c = v[(e + 2) % 3]
        lo = a
        hi = b
        if _lex_less(b, a):
            lo = b
            hi = a
        n = _cross(hi - lo, lxyz - light[3] * lo)
        d = -_dot3(n, lo)
        side = _dot3(n, c - lo)
        if side < 0.0:
            n = -n
            d = -d
        length = _norm(n)
        _store_plane(planes, t, e, n, d, length)
        reach = wp.max(_norm(c - a), _norm(c - b))
        ok = ok and length > 0.0 and wp.abs(side) > (degen * length) * reach
    cn = _cross(v[1] - v[0], v[2] - v[0])
    cd = -_dot3(cn, v[0])
    light_dir = lxyz - light[3] * v[0]
    ls = _dot3(cn, light_dir)
    if ls < 0.0:
        cn = -cn
        cd = -cd
    length = _norm(cn)
    _store_plane(planes, t, 3, cn, cd, length)
    ok = ok and length > 0.0 and wp.abs(ls) > (degen * length) * _norm(light_dir)
    valid[t] = wp.where(ok, 1, 0)


@wp.func
def _post_perspective(t: wp.int32, inv_view: wp.mat44f, r00: wp.float32, r11: wp.float32,
                      qmax: wp.float32, pmax: wp.float32, extra: wp.int32,
                      planes: wp.array2d(dtype=wp.float32), g: wp.array3d(dtype=wp.float32),
                      tol: wp.array2d(dtype=wp.float32)):
    """volume_planes.post_perspective_planes (extra "culling" or "none") for triangle t."""
    u = wp.float32(1.1920929e-07)
    q4 = qmax * (wp.float32(4.0) * u)
    c64 = wp.float32(64.0) * u
    slack = wp.vec4f()
    for p in range(4):
        w = wp.vec4f()
        for j in range(4):
            w[j] = ((planes[t, 4 * p] * inv_view[0, j] + planes[t, 4 * p + 1] * inv_view[1, j])
                    + planes[t, 4 * p + 2] * inv_view[2, j]) + planes[t, 4 * p + 3] * inv_view[3, j]
        g[t, p, 0] = w[0] * r00
        g[t, p, 1] = w[1] * r11
        g[t, p, 2] = w[3]
        g[t, p, 3] = -w[2]
        s3 = (wp.abs(planes[t, 4 * p]) + wp.abs(planes[t, 4 * p + 1])) \
            + wp.abs(planes[t, 4 * p + 2])
        slack[p] = (s3 * pmax + wp.abs(planes[t, 4 * p + 3])) * q4
        mag = ((wp.abs(g[t, p, 0]) + wp.abs(g[t, p, 1])) + wp.abs(g[t, p, 2]) * qmax) \
            + wp.abs(g[t, p, 3])
        tol[t, p] = mag * c64 + slack[p]
    for x in range(3):
        ra = 0
        rb = 2
        if x == 1:
            rb = 1
        elif x == 2:
            ra = 1
            rb = 2
        use = bool(False)  # noqa: UP018 (a dynamic Warp variable)
        if extra != 0:
            use = _norm(wp.vec3f(planes[t, 4 * ra] + planes[t, 4 * rb],
                                 planes[t, 4 * ra + 1] + planes[t, 4 * rb + 1],
                                 planes[t, 4 * ra + 2] + planes[t, 4 * rb + 2])) > wp.float32(1e-3)
        for k in range(4):
            val = wp.float32(0.0)
            if k == 3:
                val = wp.float32(1.0)
            if use:
                val = g[t, ra, k] + g[t, rb, k]
            g[t, 4 + x, k] = val
        sl = wp.float32(0.0)
        if use:
            sl = slack[ra] + slack[rb]
        mag = ((wp.abs(g[t, 4 + x, 0]) + wp.abs(g[t, 4 + x, 1])) + wp.abs(g[t, 4 + x, 2]) * qmax) \
            + wp.abs(g[t, 4 + x, 3])
        tol[t, 4 + x] = mag * c64 + sl


# --------------------------------------------------------------------------- build

@wp.func
def _box_index(storage: wp.int32, ptr: wp.array(dtype=wp.int32), poff: wp.array(dtype=wp.int32),
               boff: wp.array(dtype=wp.int32), bl: wp.int32, node: wp.uint32):
    """Row of node ``node`` of box level ``bl`` (= tree level - 1) in lo / hi / smin."""
    if storage == 0:                                  # full
        return boff[bl] + wp.int32(node)
    return boff[bl] + wp.max(ptr[poff[bl] + wp.int32(node)], 0)


@wp.func
def _cluster_update(phase: wp.int32, cur: wp.uint32, levels: wp.int32,
                    masks: wp.array(dtype=wp.uint32), moff: wp.array(dtype=wp.int32),
                    storage: wp.int32, ptr: wp.array(dtype=wp.int32),
                    poff: wp.array(dtype=wp.int32), boff: wp.array(dtype=wp.int32),
                    lo: wp.array2d(dtype=wp.float32), hi: wp.array2d(dtype=wp.float32),
                    smin: wp.array(dtype=wp.float32), blo: wp.vec3f, bhi: wp.vec3f,
                    bs: wp.float32):
    """One cluster's updates of every level above it (one thread)."""
    for level in range(levels):
        node = cur >> wp.uint32(5 * (levels - level))
        child = (cur >> wp.uint32(5 * (levels - level - 1))) & wp.uint32(31)
        if phase == 0:
            wp.atomic_or(masks, moff[level] + wp.int32(node), wp.uint32(1) << child)
        else:
            i = _box_index(storage, ptr, poff, boff, level, (node << wp.uint32(5)) | child)
            for a in range(3):
                wp.atomic_min(lo, i, a, blo[a])
                wp.atomic_max(hi, i, a, bhi[a])
            wp.atomic_min(smin, i, bs)


@wp.kernel
def build_lanes(table: wp.array2d(dtype=wp.int32), keys: wp.array(dtype=wp.uint32),
                coords: wp.array2d(dtype=wp.float32), scale: wp.array(dtype=wp.float32),
                levels: wp.int32, phase: wp.int32,
                masks: wp.array(dtype=wp.uint32), moff: wp.array(dtype=wp.int32),
                storage: wp.int32, ptr: wp.array(dtype=wp.int32), poff: wp.array(dtype=wp.int32),
                boff: wp.array(dtype=wp.int32), lo: wp.array2d(dtype=wp.float32),
                hi: wp.array2d(dtype=wp.float32), smin: wp.array(dtype=wp.float32)):
    """Faithful form: a 32-lane block per 8x8 tile, two samples per lane."""
    tile, lane = wp.tid()
    s0 = table[tile, lane]
    s1 = table[tile, lane + 32]
    k0 = (~wp.uint32(0))
    k1 = (~wp.uint32(0))
    if s0 >= 0:
        k0 = keys[s0]
    if s1 >= 0:
        k1 = keys[s1]
    big = wp.float32(3.4028235e38)
    while True:
        cur = wp.tile_min(wp.tile(wp.min(k0, k1)))[0]       # the next cluster of the tile
        if cur == (~wp.uint32(0)):
            break
        m0 = k0 == cur
        m1 = k1 == cur
        blo = wp.vec3f(big, big, big)
        bhi = wp.vec3f(-big, -big, -big)
        bs = big
        if phase == 1:
            for a in range(3):
                x0 = wp.float32(0.0)
                x1 = wp.float32(0.0)
                if m0:
                    x0 = coords[s0, a]
                if m1:
                    x1 = coords[s1, a]
                blo[a] = wp.tile_min(wp.tile(wp.min(wp.where(m0, x0, big),
                                                    wp.where(m1, x1, big))))[0]
                bhi[a] = wp.tile_max(wp.tile(wp.max(wp.where(m0, x0, -big),
                                                    wp.where(m1, x1, -big))))[0]
            c0 = big
            c1 = big
            if m0:
                c0 = scale[s0]
            if m1:
                c1 = scale[s1]
            bs = wp.tile_min(wp.tile(wp.min(c0, c1)))[0]
        if lane == 0:
            _cluster_update(phase, cur, levels, masks, moff, storage, ptr, poff, boff, lo, hi,
                            smin, blo, bhi, bs)
        if m0:
            k0 = (~wp.uint32(0))
        if m1:
            k1 = (~wp.uint32(0))


@wp.kernel
def build_tile(table: wp.array2d(dtype=wp.int32), keys: wp.array(dtype=wp.uint32),
               coords: wp.array2d(dtype=wp.float32), scale: wp.array(dtype=wp.float32),
               levels: wp.int32, phase: wp.int32,
               masks: wp.array(dtype=wp.uint32), moff: wp.array(dtype=wp.int32),
               storage: wp.int32, ptr: wp.array(dtype=wp.int32), poff: wp.array(dtype=wp.int32),
               boff: wp.array(dtype=wp.int32), lo: wp.array2d(dtype=wp.float32),
               hi: wp.array2d(dtype=wp.float32), smin: wp.array(dtype=wp.float32)):
    """Fast form: one thread per 8x8 tile does the warp's work."""
    tile = wp.tid()
    big = wp.float32(3.4028235e38)
    done0 = wp.uint32(0)                 # consumed samples (bits of pixels 0-31, 32-63)
    done1 = wp.uint32(0)
    while True:
        cur = (~wp.uint32(0))
        for p in range(TILE_PIXELS):
            s = table[tile, p]
            if s >= 0:
                word = wp.where(p < 32, done0, done1)
                if ((word >> wp.uint32(p % 32)) & wp.uint32(1)) == wp.uint32(0):
                    cur = wp.min(cur, keys[s])
        if cur == (~wp.uint32(0)):
            break
        blo = wp.vec3f(big, big, big)
        bhi = wp.vec3f(-big, -big, -big)
        bs = big
        for p in range(TILE_PIXELS):
            s = table[tile, p]
            if s >= 0 and keys[s] == cur:
                if p < 32:
                    done0 = done0 | (wp.uint32(1) << wp.uint32(p))
                else:
                    done1 = done1 | (wp.uint32(1) << wp.uint32(p - 32))
                if phase == 1:
                    for a in range(3):
                        blo[a] = wp.min(blo[a], coords[s, a])
                        bhi[a] = wp.max(bhi[a], coords[s, a])
                    bs = wp.min(bs, scale[s])
        _cluster_update(phase, cur, levels, masks, moff, storage, ptr, poff, boff, lo, hi,
                        smin, blo, bhi, bs)


@wp.kernel
def compact_pointers(masks: wp.array(dtype=wp.uint32), moff: wp.array(dtype=wp.int32),
                     level: wp.int32, rank: wp.array(dtype=wp.int32),
                     ptr: wp.array(dtype=wp.int32), poff: wp.array(dtype=wp.int32)):
    """ptr of level ``level + 1`` nodes from the inclusive scan ``rank`` of their bits."""
    n = wp.tid()
    word = masks[moff[level] + n / 32]
    if ((word >> wp.uint32(n % 32)) & wp.uint32(1)) != wp.uint32(0):
        ptr[poff[level] + n] = rank[n] - 1
    else:
        ptr[poff[level] + n] = -1


@wp.kernel
def existence_bits(masks: wp.array(dtype=wp.uint32), moff: wp.array(dtype=wp.int32),
                   level: wp.int32, out: wp.array(dtype=wp.int32)):
    n = wp.tid()
    word = masks[moff[level] + n / 32]
    out[n] = wp.where(((word >> wp.uint32(n % 32)) & wp.uint32(1)) != wp.uint32(0), 1, 0)


@wp.kernel
def pad_boxes(lo: wp.array2d(dtype=wp.float32), hi: wp.array2d(dtype=wp.float32),
              pad: wp.float32, tiny: wp.float32, fma: wp.int32):
    """cluster_hierarchy.pad_box: lo - (|lo| pad + tiny), hi + (|hi| pad + tiny)."""
    i = wp.tid()
    for a in range(3):
        lo[i, a] = lo[i, a] - _mul_add(wp.abs(lo[i, a]), pad, tiny, fma)
        hi[i, a] = hi[i, a] + _mul_add(wp.abs(hi[i, a]), pad, tiny, fma)


# --------------------------------------------------------------------------- traversal

@wp.func
def _extremes(g: wp.array3d(dtype=wp.float32), t: wp.int32, r: wp.int32, blo: wp.vec3f,
              bhi: wp.vec3f):
    """(max, min) of row r of triangle t's g over the box: the extreme corner per axis,
    summed as ``clustered_ptsv._test_children`` does, (x + q) + y, then the constant."""
    mx = wp.vec3f()
    mn = wp.vec3f()
    for a in range(3):
        p = g[t, r, a] * blo[a]
        q = g[t, r, a] * bhi[a]
        mx[a] = wp.max(p, q)
        mn[a] = wp.min(p, q)
    return wp.vec2f(((mx[0] + mx[2]) + mx[1]) + g[t, r, 3], ((mn[0] + mn[2]) + mn[1]) + g[t, r, 3])


@wp.func
def _classify(t: wp.int32, level: wp.int32, child: wp.uint32, key_bits: wp.int32,
              levels: wp.int32, layout: wp.array(dtype=wp.int32), ax: wp.vec3i,
              imp_lo: wp.array(dtype=wp.float32), imp_hi: wp.array(dtype=wp.float32),
              ioff: wp.array(dtype=wp.int32), storage: wp.int32, ptr: wp.array(dtype=wp.int32),
              poff: wp.array(dtype=wp.int32), boff: wp.array(dtype=wp.int32),
              lo: wp.array2d(dtype=wp.float32), hi: wp.array2d(dtype=wp.float32),
              smin: wp.array(dtype=wp.float32), g: wp.array3d(dtype=wp.float32),
              tol: wp.array2d(dtype=wp.float32), bound: wp.array(dtype=wp.float32),
              extra: wp.int32):
    """Child ``child`` (a node of ``level + 1``) against triangle t's volume: 0 trivial
    accept, 1 trivial reject (volume planes), 2 reject by an extra plane, 3 intersect.
    The expressions of ``clustered_ptsv._test_children``, rounded the same way."""
    bl = level                                        # box level of the child (level + 1 - 1)
    i = _box_index(storage, ptr, poff, boff, bl, child)
    blo = wp.vec3f(lo[i, 0], lo[i, 1], lo[i, 2])
    bhi = wp.vec3f(hi[i, 0], hi[i, 1], hi[i, 2])
    sm = smin[i]
    if ax[0] == 0 or ax[1] == 0 or ax[2] == 0:
        # implicit box: decode the child's coordinates from its key bits above shift
        shift = 5 * (levels - level - 1)
        c = wp.vec3i(0, 0, 0)
        used = wp.vec3i(0, 0, 0)
        for b in range(key_bits - shift):
            a = layout[shift + b]
            c[a] = c[a] | wp.int32((child >> wp.uint32(b)) & wp.uint32(1)) << used[a]
            used[a] = used[a] + 1
        for a in range(3):
            if ax[a] == 0:
                blo[a] = imp_lo[ioff[3 * bl + a] + c[a]]
                bhi[a] = imp_hi[ioff[3 * bl + a] + c[a]]
    vmax = wp.vec4f()
    vmin = wp.vec4f()
    code = 3
    rej = bool(False)  # noqa: UP018 (a dynamic Warp variable)
    acc_edge = bool(True)  # noqa: UP018 (a dynamic Warp variable)
    for r in range(4):
        e = _extremes(g, t, r, blo, bhi)
        vmax[r] = e[0]
        vmin[r] = e[1]
    for r in range(3):
        if vmax[r] < -tol[t, r]:
            rej = True
        if not (vmin[r] >= tol[t, r]):
            acc_edge = False
    cmax = vmax[3] + tol[t, 3]
    cmin = vmin[3] - tol[t, 3]
    pos = sm > 0.0
    u = wp.float32(1.1920929e-07)
    if pos and cmin > 0.0:
        rej = True
    if rej:
        code = 1
    else:
        acc_cap = pos and cmax < 0.0 and (
            (cmax / bhi[2]) * sm * (wp.float32(1.0) - wp.float32(64.0) * u)
            < bound[t] * (wp.float32(1.0) + wp.float32(64.0) * u))
        if acc_edge and acc_cap:
            code = 0
        elif extra != 0:
            for r in range(4, 7):
                if _extremes(g, t, r, blo, bhi)[0] < -tol[t, r]:
                    code = 2
    return code


@wp.func
def _test_child(word: wp.uint32, bit: wp.uint32, t: wp.int32, level: wp.int32,
                child: wp.uint32, key_bits: wp.int32, levels: wp.int32,
                layout: wp.array(dtype=wp.int32), ax: wp.vec3i,
                imp_lo: wp.array(dtype=wp.float32), imp_hi: wp.array(dtype=wp.float32),
                ioff: wp.array(dtype=wp.int32), storage: wp.int32,
                ptr: wp.array(dtype=wp.int32), poff: wp.array(dtype=wp.int32),
                boff: wp.array(dtype=wp.int32), lo: wp.array2d(dtype=wp.float32),
                hi: wp.array2d(dtype=wp.float32), smin: wp.array(dtype=wp.float32),
                g: wp.array3d(dtype=wp.float32), tol: wp.array2d(dtype=wp.float32),
                bound: wp.array(dtype=wp.float32), extra: wp.int32):
    """One lane's work at an inner node (both forms): the code of ``_classify`` for the
    child whose bit ``bit`` is set in the node's mask ``word``, 4 if it is absent."""
    if (word & bit) == wp.uint32(0):
        return 4
    return _classify(t, level, child, key_bits, levels, layout, ax, imp_lo, imp_hi, ioff,
                     storage, ptr, poff, boff, lo, hi, smin, g, tol, bound, extra)


@wp.func
def _leaf_tile(leaf: wp.uint32, key_bits: wp.int32, layout: wp.array(dtype=wp.int32),
               tiles_x: wp.int32):
    x = wp.int32(0)
    y = wp.int32(0)
    ux = wp.int32(0)
    uy = wp.int32(0)
    for b in range(key_bits):
        bit = wp.int32((leaf >> wp.uint32(b)) & wp.uint32(1))
        if layout[b] == 0:
            x = x | (bit << ux)
            ux += 1
        elif layout[b] == 1:
            y = y | (bit << uy)
            uy += 1
    return y * tiles_x + x


@wp.func
def _test_sample(t: wp.int32, s: wp.int32, leaf: wp.uint32, cluster_only: wp.int32,
                 skeys: wp.array(dtype=wp.uint32), pos: wp.array2d(dtype=wp.float32),
                 scale: wp.array(dtype=wp.float32), planes: wp.array2d(dtype=wp.float32),
                 bound: wp.array(dtype=wp.float32), fma: wp.int32,
                 shadow: wp.array(dtype=wp.int32), tests: wp.array(dtype=wp.int32)):
    """Test-and-set of sample s against triangle t (the brute_force test)."""
    if s < 0:
        return
    if cluster_only != 0 and skeys[s] != leaf:
        return
    x = pos[s, 0]
    y = pos[s, 1]
    z = pos[s, 2]
    inside = bool(True)  # noqa: UP018 (a dynamic Warp variable)
    for r in range(4):
        v = wp.float32(0.0)
        if fma != 0:
            v = fma32(z, planes[t, 4 * r + 2], fma32(x, planes[t, 4 * r], y * planes[t, 4 * r + 1])) \
                + planes[t, 4 * r + 3]
        else:
            v = ((x * planes[t, 4 * r] + y * planes[t, 4 * r + 1]) + z * planes[t, 4 * r + 2]) \
                + planes[t, 4 * r + 3]
        if r < 3:
            if not (v >= 0.0):
                inside = False
        elif not (v * scale[s] < bound[t]):
            inside = False
    wp.atomic_add(tests, s, 1)
    if inside:
        shadow[s] = 1


@wp.kernel
def traverse_warp(job_tri: wp.array(dtype=wp.int32), job_node: wp.array(dtype=wp.uint32),
                  n_jobs: wp.int32, level0: wp.int32, stop: wp.int32,
                  next_job: wp.array(dtype=wp.int32),
                  levels: wp.int32, key_bits: wp.int32, layout: wp.array(dtype=wp.int32),
                  masks: wp.array(dtype=wp.uint32), moff: wp.array(dtype=wp.int32),
                  ta: wp.array(dtype=wp.uint32), prune: wp.int32,
                  ax: wp.vec3i, imp_lo: wp.array(dtype=wp.float32),
                  imp_hi: wp.array(dtype=wp.float32), ioff: wp.array(dtype=wp.int32),
                  storage: wp.int32, ptr: wp.array(dtype=wp.int32), poff: wp.array(dtype=wp.int32),
                  boff: wp.array(dtype=wp.int32), lo: wp.array2d(dtype=wp.float32),
                  hi: wp.array2d(dtype=wp.float32), smin: wp.array(dtype=wp.float32),
                  g: wp.array3d(dtype=wp.float32), tol: wp.array2d(dtype=wp.float32),
                  bound: wp.array(dtype=wp.float32), planes: wp.array2d(dtype=wp.float32),
                  extra: wp.int32, fma: wp.int32,
                  table: wp.array2d(dtype=wp.int32), tiles_x: wp.int32, cluster_only: wp.int32,
                  skeys: wp.array(dtype=wp.uint32), pos: wp.array2d(dtype=wp.float32),
                  scale: wp.array(dtype=wp.float32),
                  shadow: wp.array(dtype=wp.int32), tests: wp.array(dtype=wp.int32),
                  iters: wp.array(dtype=wp.int32), counts: wp.array(dtype=wp.int64),
                  out_tri: wp.array(dtype=wp.int32), out_node: wp.array(dtype=wp.uint32),
                  out_n: wp.array(dtype=wp.int64)):
    """Fast form: a persistent thread per warp, looping over the 32 lanes itself."""
    while True:
        j = wp.atomic_add(next_job, 0, 1)
        if j >= n_jobs:
            break
        t = job_tri[j]
        fr_mask = U32Vec()
        fr_node = U32Vec()
        sp = wp.int32(0)
        lv = level0
        n = job_node[j]
        visit = bool(True)  # noqa: UP018 (a dynamic Warp variable)
        its = wp.int32(0)
        c_tests = wp.int32(0)
        c_acc = wp.int32(0)
        c_rej = wp.int32(0)
        c_xrej = wp.int32(0)
        c_leaf = wp.int32(0)
        while True:
            if visit:
                visit = False
                its += 1
                if lv == levels:                      # TESTVIEWSAMPLES
                    c_leaf += 1
                    tile = _leaf_tile(n, key_bits, layout, tiles_x)
                    for p in range(TILE_PIXELS):
                        _test_sample(t, table[tile, p], n, cluster_only, skeys, pos, scale,
                                     planes, bound, fma, shadow, tests)
                else:
                    word = masks[moff[lv] + wp.int32(n)]
                    acc_bits = wp.uint32(0)
                    int_bits = wp.uint32(0)
                    for lane in range(32):
                        bit = wp.uint32(1) << wp.uint32(lane)
                        code = _test_child(word, bit, t, lv, (n << wp.uint32(5)) | wp.uint32(lane),
                                           key_bits, levels, layout, ax, imp_lo, imp_hi, ioff,
                                           storage, ptr, poff, boff, lo, hi, smin, g, tol, bound,
                                           extra)
                        acc_bits = acc_bits | wp.where(code == 0, bit, wp.uint32(0))
                        int_bits = int_bits | wp.where(code == 3, bit, wp.uint32(0))
                        c_rej += wp.where(code == 1 or code == 2, 1, 0)
                        c_xrej += wp.where(code == 2, 1, 0)
                    c_tests += popc(word)
                    c_acc += popc(acc_bits)
                    if acc_bits != wp.uint32(0):
                        wp.atomic_or(ta, moff[lv] + wp.int32(n), acc_bits)
                        if prune != 0:
                            wp.atomic_and(masks, moff[lv] + wp.int32(n), ~acc_bits)
                    fr_mask[sp] = int_bits
                    fr_node[sp] = n
                    sp += 1
            if sp == 0:
                break
            m = fr_mask[sp - 1]
            if m == wp.uint32(0):
                sp -= 1
                continue
            c = 31 - clz(m)
            fr_mask[sp - 1] = m & ~(wp.uint32(1) << wp.uint32(c))
            child = (fr_node[sp - 1] << wp.uint32(5)) | wp.uint32(c)
            clv = level0 + sp
            if clv == stop:                           # two-pass: push a (triangle, node) job
                k = wp.atomic_add(out_n, 0, wp.int64(1))
                if k < wp.int64(out_tri.shape[0]):
                    out_tri[k] = t
                    out_node[k] = child
                continue
            lv = clv
            n = child
            visit = True
        iters[j] = its
        wp.atomic_add(counts, 0, wp.int64(c_tests))
        wp.atomic_add(counts, 1, wp.int64(c_acc))
        wp.atomic_add(counts, 2, wp.int64(c_rej))
        wp.atomic_add(counts, 3, wp.int64(c_xrej))
        wp.atomic_add(counts, 4, wp.int64(c_leaf))


@wp.kernel
def traverse_lanes(job_tri: wp.array(dtype=wp.int32), job_node: wp.array(dtype=wp.uint32),
                   n_jobs: wp.int32, level0: wp.int32, stop: wp.int32,
                   next_job: wp.array(dtype=wp.int32),
                   levels: wp.int32, key_bits: wp.int32, layout: wp.array(dtype=wp.int32),
                   masks: wp.array(dtype=wp.uint32), moff: wp.array(dtype=wp.int32),
                   ta: wp.array(dtype=wp.uint32), prune: wp.int32,
                   ax: wp.vec3i, imp_lo: wp.array(dtype=wp.float32),
                   imp_hi: wp.array(dtype=wp.float32), ioff: wp.array(dtype=wp.int32),
                   storage: wp.int32, ptr: wp.array(dtype=wp.int32),
                   poff: wp.array(dtype=wp.int32),
                   boff: wp.array(dtype=wp.int32), lo: wp.array2d(dtype=wp.float32),
                   hi: wp.array2d(dtype=wp.float32), smin: wp.array(dtype=wp.float32),
                   g: wp.array3d(dtype=wp.float32), tol: wp.array2d(dtype=wp.float32),
                   bound: wp.array(dtype=wp.float32), planes: wp.array2d(dtype=wp.float32),
                   extra: wp.int32, fma: wp.int32,
                   table: wp.array2d(dtype=wp.int32), tiles_x: wp.int32, cluster_only: wp.int32,
                   skeys: wp.array(dtype=wp.uint32), pos: wp.array2d(dtype=wp.float32),
                   scale: wp.array(dtype=wp.float32),
                   shadow: wp.array(dtype=wp.int32), tests: wp.array(dtype=wp.int32),
                   iters: wp.array(dtype=wp.int32), counts: wp.array(dtype=wp.int64),
                   out_tri: wp.array(dtype=wp.int32), out_node: wp.array(dtype=wp.uint32),
                   out_n: wp.array(dtype=wp.int64)):
    """Faithful form: a persistent 32-lane warp (block) per job, a lane per child.

    Every lane runs the same control flow (the warp-uniform stack of Algorithm 1's
    iterative form); lane ``l`` tests child ``l``; ballots are bit-OR reductions."""
    _w, lane = wp.tid()
    bit = wp.uint32(1) << wp.uint32(lane)
    while True:
        mine = wp.int32(0)
        if lane == 0:
            mine = wp.atomic_add(next_job, 0, 1)
        j = wp.tile_sum(wp.tile(mine))[0]             # broadcast lane 0's job
        if j >= n_jobs:
            break
        t = job_tri[j]
        fr_mask = U32Vec()
        fr_node = U32Vec()
        sp = wp.int32(0)
        lv = level0
        n = job_node[j]
        visit = bool(True)  # noqa: UP018 (a dynamic Warp variable)
        its = wp.int32(0)
        c_tests = wp.int32(0)
        c_acc = wp.int32(0)
        c_rej = wp.int32(0)
        c_xrej = wp.int32(0)
        c_leaf = wp.int32(0)
        while True:
            if visit:
                visit = False
                its += 1
                if lv == levels:                      # TESTVIEWSAMPLES: two samples per lane
                    c_leaf += 1
                    tile = _leaf_tile(n, key_bits, layout, tiles_x)
                    _test_sample(t, table[tile, lane], n, cluster_only, skeys, pos, scale,
                                 planes, bound, fma, shadow, tests)
                    _test_sample(t, table[tile, lane + 32], n, cluster_only, skeys, pos, scale,
                                 planes, bound, fma, shadow, tests)
                else:
                    word = masks[moff[lv] + wp.int32(n)]
                    code = _test_child(word, bit, t, lv, (n << wp.uint32(5)) | wp.uint32(lane),
                                       key_bits, levels, layout, ax, imp_lo, imp_hi, ioff,
                                       storage, ptr, poff, boff, lo, hi, smin, g, tol, bound,
                                       extra)
                    acc_bits = wp.tile_reduce(wp.bit_or, wp.tile(
                        wp.where(code == 0, bit, wp.uint32(0))))[0]           # BALLOT(TA)
                    int_bits = wp.tile_reduce(wp.bit_or, wp.tile(
                        wp.where(code == 3, bit, wp.uint32(0))))[0]           # BALLOT(intersect)
                    rej = wp.tile_sum(wp.tile(wp.where(code == 1, 1, wp.where(
                        code == 2, 65537, 0))))[0]    # rejects + (extra-plane rejects << 16)
                    c_tests += popc(word)
                    c_acc += popc(acc_bits)
                    c_rej += rej & 65535
                    c_xrej += rej >> 16
                    if lane == 0 and acc_bits != wp.uint32(0):
                        wp.atomic_or(ta, moff[lv] + wp.int32(n), acc_bits)
                        if prune != 0:
                            wp.atomic_and(masks, moff[lv] + wp.int32(n), ~acc_bits)
                    fr_mask[sp] = int_bits
                    fr_node[sp] = n
                    sp += 1
            if sp == 0:
                break
            m = fr_mask[sp - 1]
            if m == wp.uint32(0):
                sp -= 1
                continue
            c = 31 - clz(m)
            fr_mask[sp - 1] = m & ~(wp.uint32(1) << wp.uint32(c))
            child = (fr_node[sp - 1] << wp.uint32(5)) | wp.uint32(c)
            clv = level0 + sp
            if clv == stop:
                if lane == 0:
                    k = wp.atomic_add(out_n, 0, wp.int64(1))
                    if k < wp.int64(out_tri.shape[0]):
                        out_tri[k] = t
                        out_node[k] = child
                continue
            lv = clv
            n = child
            visit = True
        if lane == 0:
            iters[j] = its
            wp.atomic_add(counts, 0, wp.int64(c_tests))
            wp.atomic_add(counts, 1, wp.int64(c_acc))
            wp.atomic_add(counts, 2, wp.int64(c_rej))
            wp.atomic_add(counts, 3, wp.int64(c_xrej))
            wp.atomic_add(counts, 4, wp.int64(c_leaf))


@wp.kernel
def merge(skeys: wp.array(dtype=wp.uint32), levels: wp.int32, ta: wp.array(dtype=wp.uint32),
          moff: wp.array(dtype=wp.int32), shadow: wp.array(dtype=wp.int32),
          final: wp.array(dtype=wp.int32), ta_only: wp.array(dtype=wp.int32)):
    """A thread per sample: shadowed by a leaf test or inside a trivially accepted node."""
    s = wp.tid()
    k = skeys[s]
    hit = bool(False)  # noqa: UP018 (a dynamic Warp variable)
    for level in range(levels):
        node = k >> wp.uint32(5 * (levels - level))
        child = (k >> wp.uint32(5 * (levels - level - 1))) & wp.uint32(31)
        if ((ta[moff[level] + wp.int32(node)] >> child) & wp.uint32(1)) != wp.uint32(0):
            hit = True
    leaf = shadow[s] != 0
    final[s] = wp.where(leaf or hit, 1, 0)
    ta_only[s] = wp.where(hit and not leaf, 1, 0)


# --------------------------------------------------------------------------- host side

def _arr(a, dtype, device):
    a = np.ascontiguousarray(a, dtype=dtype)
    return wp.array(a, dtype=wp.dtype_from_numpy(a.dtype), device=device)


def _offsets(sizes):
    off = np.zeros(len(sizes) + 1, np.int64)
    off[1:] = np.cumsum(sizes)
    return off


def load(device: str | None = None) -> None:
    """Compile (or load from the kernel cache) this file's kernels."""
    wp.load_module(setup.module, device=init(device))


def triangle_setup(tri: np.ndarray, light_h: np.ndarray, camera, tree, qmax: float,
                   pmax: float, extra: bool = True, world_planes=None,
                   device: str | None = None) -> dict:
    """The ``setup`` kernel: world planes [T, 16], valid [T] bool, g [T, 7, 4], tol [T, 7]
    (float32), for triangles [T, 3, 3]. ``world_planes`` = (planes [T, 16], valid [T]):
    take the world planes as given and compute only the post-perspective part."""
    from ..geometry.triangle_setup import degeneracy_tolerance

    dev = init(device)
    n = tri.shape[0]
    t = max(n, 1)
    f32 = np.float32
    if world_planes is None:
        planes = wp.zeros((t, 16), dtype=wp.float32, device=dev)
        valid = wp.zeros(t, dtype=wp.int32, device=dev)
    else:
        planes = _arr(np.asarray(world_planes[0]).reshape(-1, 16)[:n], f32, dev)
        valid = _arr(np.asarray(world_planes[1])[:n], np.int32, dev)
    out = {"planes": planes, "valid": valid,
               "g": wp.zeros((t, 7, 4), dtype=wp.float32, device=dev),
               "tol": wp.zeros((t, 7), dtype=wp.float32, device=dev)}
    if n:
        iv = np.linalg.inv(camera.view_matrix()).astype(f32)
        wp.launch(setup, dim=n, device=dev, inputs=[
            _arr(tri, f32, dev), wp.vec4f(*light_h.astype(f32)), wp.mat44f(*iv.reshape(-1)),
            f32(1.0 / tree.p00), f32(1.0 / tree.p11), f32(qmax), f32(pmax),
            f32(degeneracy_tolerance(np.float32)), int(extra), int(world_planes is None),
            *out.values()])
    h = {k: v.numpy()[:n] for k, v in out.items()}
    h["valid"] = h["valid"].astype(bool)
    return h


class Hierarchy:
    """The kernel-built hierarchy (Warp arrays, flat per-level layout) and its host view."""

    def __init__(self, tree, storage, masks, moff, ptr, poff, lo, hi, smin, boff, counts):
        self.tree, self.storage = tree, storage
        self.masks, self.moff, self.ptr, self.poff = masks, moff, ptr, poff
        self.lo, self.hi, self.smin, self.boff, self.counts = lo, hi, smin, boff, counts

    def host(self) -> dict:
        """Per level NumPy arrays: masks (levels 0..D-1), ptr / lo / hi / smin (1..D)."""
        d = self.tree.levels
        mo, po, bo = self.moff.numpy(), self.poff.numpy(), self.boff.numpy()
        m, p, lo, hi, sm = self.masks.numpy(), self.ptr.numpy(), self.lo.numpy(), \
            self.hi.numpy(), self.smin.numpy()
        return {"masks": [m[mo[i]:mo[i + 1]] for i in range(d)],
                "ptr": [p[po[i]:po[i + 1]] for i in range(d)] if self.storage == "compact"
                else None,
                "lo": [lo[bo[i]:bo[i + 1]] for i in range(d)],
                "hi": [hi[bo[i]:bo[i + 1]] for i in range(d)],
                "smin": [sm[bo[i]:bo[i + 1]] for i in range(d)],
                "counts": list(self.counts)}


def tile_table(tree, px: np.ndarray, py: np.ndarray) -> np.ndarray:
    """int32 [tiles, 64]: the sample at each pixel of each 8x8 tile, -1 for none."""
    table = np.full((tree.tiles_x * tree.tiles_y, TILE_PIXELS), -1, np.int32)
    table[(py // 8) * tree.tiles_x + px // 8, (py % 8) * 8 + px % 8] = np.arange(len(px))
    return table


def build_hierarchy(tree, table: np.ndarray, keys: np.ndarray, coords: np.ndarray,
                    scale: np.ndarray, storage: str = "compact", form: str = "lanes",
                    fma: bool | None = None, device: str | None = None) -> Hierarchy:
    """Masks (phase 0), compact pointers (a scan per level), boxes and smin (phase 1),
    padding. ``form``: "lanes" (32-lane blocks per tile) or "warp" (a thread per tile)."""
    from ..structures.cluster_hierarchy import pad_fraction

    dev = init(device)
    if fma is None:
        fma = xla_contracts(np.float32)
    if tree.kind != "cluster" or tree.tile != (8, 8):
        raise ValueError("the kernels build the 2014 cluster tree (8x8 tiles)")
    if tree.key_bits >= 32:
        raise ValueError("the kernels need keys of at most 31 bits (0xFFFFFFFF = no key)")
    d = tree.levels
    f32 = np.float32
    mo = _offsets([tree.nodes(level) for level in range(d)])
    masks = wp.zeros(int(mo[-1]), dtype=wp.uint32, device=dev)
    moff = _arr(mo, np.int32, dev)
    po = _offsets([tree.nodes(level) for level in range(1, d + 1)]
                  if storage == "compact" else [0] * d)
    ptr = wp.full(max(int(po[-1]), 1), -1, dtype=wp.int32, device=dev)
    poff = _arr(po, np.int32, dev)
    big = np.finfo(f32).max
    dummy2 = wp.zeros((1, 3), dtype=wp.float32, device=dev)
    dummy1 = wp.zeros(1, dtype=wp.float32, device=dev)
    wtable, wkeys = _arr(table, np.int32, dev), _arr(keys, np.uint32, dev)
    wcoords, wscale = _arr(coords, f32, dev), _arr(scale, f32, dev)
    kern = build_lanes if form == "lanes" else build_tile
    tiles = table.shape[0]

    def launch(phase, lo, hi, smin, boff):
        args = [wtable, wkeys, wcoords, wscale, d, phase, masks, moff,
                0 if storage == "full" else 1, ptr, poff, boff, lo, hi, smin]
        if form == "lanes":
            wp.launch_tiled(kern, dim=[tiles], inputs=args, block_dim=32, device=dev)
        else:
            wp.launch(kern, dim=tiles, inputs=args, device=dev)

    launch(0, dummy2, dummy2, dummy1, _arr(np.zeros(d + 1), np.int32, dev))
    counts = []
    for level in range(d):                    # existence of level + 1 nodes, their pointers
        n = tree.nodes(level + 1)
        bits = wp.zeros(n, dtype=wp.int32, device=dev)
        wp.launch(existence_bits, dim=n, inputs=[masks, moff, level, bits], device=dev)
        rank = wp.zeros(n, dtype=wp.int32, device=dev)
        wp.utils.array_scan(bits, rank, inclusive=True)
        counts.append(int(rank.numpy()[-1]))
        if storage == "compact":
            wp.launch(compact_pointers, dim=n, inputs=[masks, moff, level, rank, ptr, poff],
                      device=dev)
    if storage == "full":
        caps = [tree.nodes(level) for level in range(1, d + 1)]
    else:
        caps = [max(32, 1 << max(0, (c - 1).bit_length())) for c in counts]
    bo = _offsets(caps)
    lo = wp.full((int(bo[-1]), 3), big, dtype=wp.float32, device=dev)
    hi = wp.full((int(bo[-1]), 3), -big, dtype=wp.float32, device=dev)
    smin = wp.full(int(bo[-1]), big, dtype=wp.float32, device=dev)
    boff = _arr(bo, np.int32, dev)
    launch(1, lo, hi, smin, boff)
    wp.launch(pad_boxes, dim=int(bo[-1]), inputs=[
        lo, hi, f32(pad_fraction(f32)), f32(float(np.finfo(f32).tiny) * 1e6), int(bool(fma))],
        device=dev)
    return Hierarchy(tree, storage, masks, moff, ptr, poff, lo, hi, smin, boff, counts)


@functools.lru_cache(maxsize=16)
def implicit_tables(tree) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Implicit box coordinates per (box level, axis, coordinate), computed by
    ``cluster_hierarchy.implicit_bounds`` itself (each padded coordinate depends on its
    own axis only): flat lo, hi float32 and int32 offsets [3 D + 1]."""
    import jax
    import jax.numpy as jnp

    from ..geometry.morton import encode
    from ..structures import cluster_hierarchy as ch

    d = tree.levels
    los, his, sizes = [], [], []
    for level in range(1, d + 1):
        shift = min(tree.shift(level), tree.key_bits)
        for a in range(3):
            e = tree.extent_bits(level, a)
            m = 1 << (tree.bits[a] - e)
            coords = [np.zeros(m, np.uint32) for _ in range(3)]
            coords[a] = (np.arange(m, dtype=np.uint32) << e)
            node = encode(coords, tree.layout) >> np.uint32(shift)
            fn = jax.jit(lambda nd, level=level: ch.implicit_bounds(tree, level, nd, jnp.float32))
            lo, hi = fn(jnp.asarray(node))
            los.append(np.asarray(lo)[:, a])
            his.append(np.asarray(hi)[:, a])
            sizes.append(m)
    return (np.concatenate(los).astype(np.float32), np.concatenate(his).astype(np.float32),
            _offsets(sizes).astype(np.int32))


@functools.lru_cache(maxsize=16)
def _sample_stage(tree):
    """Jitted post-perspective coordinates and cluster keys (``cluster_hierarchy``'s
    functions) for a tree layout: the build's inputs, computed by JAX."""
    import jax

    from ..structures import cluster_hierarchy as ch

    @jax.jit
    def stage(pos, view, px, py):
        coords = ch.sample_coords(tree, pos, view)
        keys, saturated = ch.sample_keys(tree, px, py, coords)
        return coords, keys, saturated
    return stage


def prepare(scene, gbuf, light, o: dict, device: str | None = None) -> dict:
    """Everything before the traversal, as ``clustered_ptsv.run_traversal_method`` does it:
    samples, cluster keys and post-perspective coordinates (JAX, the inputs of the
    build), the ``setup`` kernel (planes, g, tol), bias terms, casters. With
    ``front_face_culling`` the setup covers the kept triangles only (``scene`` in the
    result: the subset, whose indices ``casters`` and the setup arrays use;
    ``face_culled``: how many were dropped).
    """
    import jax.numpy as jnp

    from ..structures import cluster_hierarchy as ch
    from ..methods import clustered_ptsv as cm
    from ..core.frame import bias_terms, cap_bias, view_samples
    from ..scene.view import hard_light

    f32 = np.float32
    t0 = time.perf_counter()
    samples = view_samples(gbuf, light)
    camera = gbuf.camera
    light_h = hard_light(light).homogeneous
    _h, w = gbuf.shape
    tree = ch.cluster_layout(camera, o["z_bits"], o["depth_slices"])
    px = (samples.index % w).astype(np.int32)
    py = (samples.index // w).astype(np.int32)
    pos = samples.position.astype(f32)
    view = camera.view_matrix().astype(f32)

    sample_stage = _sample_stage(tree)
    tm = {"samples": time.perf_counter() - t0}
    t0 = time.perf_counter()
    if samples.count:
        coords, keys, saturated = (np.asarray(x) for x in sample_stage(
            jnp.asarray(pos), jnp.asarray(view), jnp.asarray(px), jnp.asarray(py)))
    else:
        coords, keys, saturated = (np.zeros((0, 3), f32), np.zeros(0, np.uint32),
                                   np.zeros(0, bool))
    tm["keys"] = time.perf_counter() - t0
    t0 = time.perf_counter()
    face_culled = 0
    if o["front_face_culling"]:      # dropped before the setup, as the JAX method does
        scene, face_culled = cm.without_culled_faces(scene, light_h,
                                                     o.get("cull_side", "averted"))
    qmax = float(coords[:, 2].max()) if samples.count else 1.0
    pmax = float(np.abs(samples.position).max()) if samples.count else 1.0
    tri = scene.triangles.astype(f32)
    extra = bool(o["culling_planes"])
    st = triangle_setup(tri, light_h, camera, tree, qmax, pmax, extra, device=device)
    scale, bound = bias_terms(samples, light_h, st["planes"].reshape(-1, 4, 4),
                              cap_bias(scene, o["shadow_eps"]), o["bias"])
    bound = np.where(st["valid"], bound, -np.inf).astype(f32)
    casters = np.flatnonzero(st["valid"]).astype(np.int32)
    tm["setup"] = time.perf_counter() - t0
    return dict(timings=tm, samples=samples, tree=tree, px=px, py=py, pos=pos, coords=coords, keys=keys,
                saturated=saturated, scale=scale.astype(f32), bound=bound, casters=casters,
                face_culled=face_culled, scene=scene, table=tile_table(tree, px, py),
                extra=extra, **st)


def traverse(p: dict, hier: Hierarchy, o: dict, form: str = "lanes", workers: int = 64,
             job_order: np.ndarray | None = None, fma: bool | None = None,
             device: str | None = None) -> dict:
    """Pass 1 over the casters (and pass 2 over the job list for ``passes=2``); merge.

    ``workers``: persistent warps (form "lanes": 32-thread blocks; "warp": threads).
    On the CPU backend the first worker runs every job in order: the serial job order
    (casters in ascending triangle index). ``job_order`` (a permutation of the casters'
    positions) hands the pass-1 jobs out in another order, as another GPU schedule
    would; iterations are still reported per caster in caster order.
    """
    dev = init(device)
    if fma is None:
        fma = xla_contracts(np.float32)
    if form not in FORMS:
        raise ValueError(f"form must be one of {FORMS}")
    tree = p["tree"]
    d = tree.levels
    f32, i32 = np.float32, np.int32
    s = max(len(p["keys"]), 1)
    bounds = o["bounds"]
    ax = (1, 1, 1) if bounds == "explicit" else (0, 0, 0)
    if bounds == "implicit":
        ilo, ihi, ioff = implicit_tables(tree)
    else:
        ilo, ihi, ioff = np.zeros(1, f32), np.zeros(1, f32), np.zeros(3 * d + 1, i32)
    common = {
        "levels": d, "key_bits": tree.key_bits, "layout": _arr(np.array(tree.layout), i32, dev),
        "masks": wp.clone(hier.masks), "moff": hier.moff,
        "ta": wp.zeros(hier.masks.shape[0], dtype=wp.uint32, device=dev),
        "prune": int(bool(o["prune"])), "ax": wp.vec3i(*ax), "imp_lo": _arr(ilo, f32, dev),
        "imp_hi": _arr(ihi, f32, dev), "ioff": _arr(ioff, i32, dev),
        "storage": 0 if hier.storage == "full" else 1, "ptr": hier.ptr, "poff": hier.poff,
        "boff": hier.boff, "lo": hier.lo, "hi": hier.hi, "smin": hier.smin,
        "g": _arr(p["g"], f32, dev), "tol": _arr(p["tol"], f32, dev), "bound": _arr(p["bound"], f32, dev),
        "planes": _arr(p["planes"], f32, dev), "extra": int(p["extra"]), "fma": int(bool(fma)),
        "table": _arr(p["table"], i32, dev), "tiles_x": tree.tiles_x,
        "cluster_only": int(o["leaf_samples"] == "cluster"),
        "skeys": _arr(np.resize(p["keys"], s) if len(p["keys"]) else np.zeros(1), np.uint32, dev),
        "pos": _arr(p["pos"] if len(p["pos"]) else np.zeros((1, 3)), f32, dev),
        "scale": _arr(p["scale"] if len(p["scale"]) else np.zeros(1), f32, dev),
        "shadow": wp.zeros(s, dtype=wp.int32, device=dev),
        "tests": wp.zeros(s, dtype=wp.int32, device=dev)}
    # int64: a frame's node tests can pass 2**31 (4k images, 1M triangles)
    counts = wp.zeros(N_COUNTS, dtype=wp.int64, device=dev)
    kern = traverse_lanes if form == "lanes" else traverse_warp

    def run_pass(jt, jn, level0, stop, out_cap):
        n = len(jt)
        check_int32(n + workers, "Warp traversal jobs (the int32 job counter)",
                    "use passes=1 or a smaller expand_level, or render fewer samples")
        iters = wp.zeros(max(n, 1), dtype=wp.int32, device=dev)
        out_tri = wp.zeros(max(out_cap, 1), dtype=wp.int32, device=dev)
        out_node = wp.zeros(max(out_cap, 1), dtype=wp.uint32, device=dev)
        out_n = wp.zeros(1, dtype=wp.int64, device=dev)     # counts past 2**31
        if n:
            c = common
            args = [_arr(jt, i32, dev), _arr(jn, np.uint32, dev), n, level0, stop,
                    wp.zeros(1, dtype=wp.int32, device=dev), c["levels"], c["key_bits"],
                    c["layout"], c["masks"], c["moff"], c["ta"], c["prune"], c["ax"],
                    c["imp_lo"], c["imp_hi"], c["ioff"], c["storage"], c["ptr"], c["poff"],
                    c["boff"], c["lo"], c["hi"], c["smin"], c["g"], c["tol"], c["bound"],
                    c["planes"], c["extra"], c["fma"], c["table"], c["tiles_x"],
                    c["cluster_only"], c["skeys"], c["pos"], c["scale"], c["shadow"],
                    c["tests"], iters, counts, out_tri, out_node, out_n]
            if form == "lanes":
                wp.launch_tiled(kern, dim=[workers], inputs=args, block_dim=32, device=dev)
            else:
                wp.launch(kern, dim=workers, inputs=args, device=dev)
        return iters.numpy()[:n], out_tri, out_node, int(out_n.numpy()[0])

    casters = p["casters"]
    order = np.arange(len(casters)) if job_order is None else np.asarray(job_order)
    two = o["passes"] == 2
    level_l = min(max(1, o["expand_level"]), d)
    stop = level_l if two else d + 1
    runs = []

    def first_pass(out_cap):
        """Pass 1 with a job list of ``out_cap``; returns its outputs and the list length it
        needed. A rerun (the list overflowed: counted, never truncated silently) starts
        again from the initial state."""
        if runs:
            common["masks"] = wp.clone(hier.masks)
            for k in ("ta", "shadow", "tests"):
                common[k].zero_()
            counts.zero_()
        runs.append(check_int32(out_cap, "pass-2 (triangle, node) jobs",
                                "use a smaller expand_level or render fewer samples"))
        out = run_pass(casters[order], np.zeros(len(casters), np.uint32), 0, stop, out_cap)
        return out, out[3]

    (it, out_tri, out_node, m), out_cap = retry_on_overflow(
        first_pass, max(1024, 4 * len(casters)) if two else 0)
    iters1 = np.zeros(len(casters), it.dtype)
    iters1[order] = it
    tri2 = out_tri.numpy()[:m] if two else np.zeros(0, i32)
    node2 = out_node.numpy()[:m] if two else np.zeros(0, np.uint32)
    iters2 = np.zeros(0, i32)
    if two:
        iters2, _, _, _ = run_pass(tri2, node2, level_l, d + 1, 0)
    wp.synchronize_device(dev)
    t_merge = time.perf_counter()
    final = wp.zeros(s, dtype=wp.int32, device=dev)
    ta_only = wp.zeros(s, dtype=wp.int32, device=dev)
    n_s = len(p["keys"])
    if n_s:
        wp.launch(merge, dim=n_s, inputs=[common["skeys"], d, common["ta"], hier.moff,
                                          common["shadow"], final, ta_only], device=dev)
    cn = counts.numpy()
    shadow = final.numpy()[:n_s].astype(bool)
    merge_seconds = time.perf_counter() - t_merge
    return {"merge_seconds": merge_seconds, "shadow": shadow, "ta_only": ta_only.numpy()[:n_s]
                .astype(bool), "leaf_shadow": common["shadow"].numpy()[:n_s].astype(bool),
                "tests": common["tests"].numpy()[:n_s].astype(np.int64),
                "iterations_pass1": iters1, "iterations_pass2": iters2, "pass2_triangles": tri2,
                "pass2_nodes": node2, "node_tests": int(cn[0]), "trivial_accepts": int(cn[1]),
                "trivial_rejects": int(cn[2]), "extra_plane_rejects": int(cn[3]),
                "leaf_visits": int(cn[4]), "job_list_capacity": out_cap,
                "ta_words": common["ta"].numpy(), "masks_after": common["masks"].numpy()}


def run(scene, gbuf, light, **kw):
    """``clustered_ptsv`` with the kernels (see :func:`run_details`): a ``ShadowResult``."""
    return run_details(scene, gbuf, light, **kw)[0]


def run_details(scene, gbuf, light, *, form: str = "lanes", workers: int = 64,
                job_order=None, device=None, **options):
    """``clustered_ptsv`` with the kernels: (``ShadowResult``, details) with the JAX method's
    counters (all but ``frontier_max``, which belongs to the level-synchronous JAX
    traversal) and timings ``samples`` (view samples), ``keys`` (JAX: coordinates and
    cluster keys, the build's inputs), ``setup`` (setup kernel, bias terms, casters),
    ``build``, ``traverse`` (both passes), ``merge`` (seconds; compile excluded: the
    module is loaded first). The method's ``reuse_setup`` is accepted and has no effect
    here: the setup kernel runs every call (results do not depend on it)."""
    from ..structures import cluster_hierarchy as ch
    from ..methods.clustered_ptsv import top_jobs
    from ..methods.registry import call_options
    from ..core.result import ShadowResult

    from ..core.frame import localize

    o = call_options("clustered_ptsv", options)
    if o["precision"] != "float32":
        raise ValueError("the clustered PTSV kernels run in float32 only (precision='float32')")
    local = localize(scene, gbuf, light)                # as the method (camera frame)
    scene, gbuf, light = local.scene, local.gbuf, local.light
    if o.get("bias_reject"):
        raise ValueError("the clustered PTSV kernels have no bias_reject node test")
    if o.get("plane_set", "own") != "own":
        raise ValueError("the clustered PTSV kernels use the method's own culling planes "
                         "(plane_set='own')")
    if o.get("tree_samples", "facing") != "facing":
        raise ValueError("the clustered PTSV kernels build over the light-facing samples "
                         "only (tree_samples='facing')")
    dev = init(device)
    load(dev)
    fma = xla_contracts(np.float32)
    p = prepare(scene, gbuf, light, o, dev)
    t1 = time.perf_counter()
    hier = build_hierarchy(p["tree"], p["table"], p["keys"], p["coords"], p["scale"],
                           o["storage"], form, fma, dev)
    wp.synchronize_device(dev)
    t2 = time.perf_counter()
    r = traverse(p, hier, o, form, workers, job_order, fma, dev)
    t3 = time.perf_counter()
    samples = p["samples"]
    lit = samples.scatter(~r["shadow"], fill=False)
    tree = p["tree"]
    j = np.concatenate([r["iterations_pass1"], r["iterations_pass2"]]) \
        if o["passes"] == 2 else r["iterations_pass1"]
    memory = ch.memory_report(tree, existing=sum(hier.counts))
    counters = {
        "samples": samples.count, "casters": len(p["casters"]),
        "culled_triangles": scene.num_triangles - len(p["casters"]),
        "front_face_culled": p["face_culled"],
        "tests": int(r["tests"].sum()), "tests_per_pixel": samples.scatter(r["tests"], fill=0),
        "node_tests": r["node_tests"], "trivial_accepts": r["trivial_accepts"],
        "trivial_rejects": r["trivial_rejects"], "extra_plane_rejects": r["extra_plane_rejects"],
        "leaf_visits": r["leaf_visits"], "ta_shadowed": int(r["ta_only"].sum()),
        "jobs": len(j), "pass2_jobs": len(r["iterations_pass2"]),
        "job_iterations_mean": float(j.mean()) if len(j) else 0.0,
        "job_iterations_max": int(j.max()) if len(j) else 0,
        "job_iterations_top": top_jobs(j),
        "clusters": int(hier.counts[-1]), "hierarchy_nodes": int(sum(hier.counts)),
        "hierarchy_bytes": int(memory["mask_bytes"] + (
            memory["pointer_bytes"] + 24 * sum(hier.counts) if o["storage"] == "compact"
            else memory["full_bounds_bytes"])),
        "saturated_samples": int(np.asarray(p["saturated"]).sum()),
        "shadowed": int(r["shadow"].sum()), "lit": int(lit.sum()),
    }
    tm = p["timings"]
    timings = {"samples": tm["samples"], "keys": tm["keys"], "setup": tm["setup"],
               "build": t2 - t1, "traverse": t3 - t2 - r["merge_seconds"],
               "merge": r["merge_seconds"]}
    timings["total"] = sum(timings.values())
    details = dict(r, prepared=p, hierarchy=hier)
    res = ShadowResult(lit, counters, timings, "kernels.clustered_ptsv",
                       dict(o, form=form, workers=workers))
    return res, details


__all__ = ["FORMS", "Hierarchy", "build_hierarchy", "implicit_tables", "load", "prepare",
           "run", "run_details", "tile_table", "traverse", "triangle_setup"]
