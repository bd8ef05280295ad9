"""Per-tile blocker lists with a fixed capacity, filled by cone tests.

The screen is cut into ``TILE`` x ``TILE`` pixel tiles, stored tile-major: tile t =
ty * tiles_x + tx holds the pixels (16 ty + i, 16 tx + j) at slot 16 i + j. The
relevant samples of a tile are bounded, per depth half, by a capsule from the tile's
depth range (:func:`tile_bounds`, optionally made a sphere by :func:`capsule_to_sphere`).
:func:`build_tile_lists` culls the blockers' cones (:mod:`.cones`) against every active
tile, first a group (cluster) level, then the triangles of the surviving groups, and
stores the survivors as one flat array sorted by tile (tile t's entries at
``starts[t] .. starts[t] + lengths[t]``), each with the depth halves it may shadow.

Capacity: a list holds at most ``capacity`` entries (the paper's shared-memory list).
A longer list is never cut silently: it is flagged (``overflow``); with
``on_overflow="truncate"`` only its first ``capacity`` entries are evaluated
(``counts``) and the rest are counted as dropped, with ``"full"`` all are evaluated.
"""

from __future__ import annotations

import dataclasses
import functools
import math

import jax
import jax.numpy as jnp
import numpy as np

from ..core.capacity import bucket
from ..core.sorting import stable_argsort
from .cones import cone_hits_capsule

TILE = 16               # tile side in pixels
FACE_CULL = ("none", "front", "back")
BOUNDS = ("sphere", "capsule")
ON_OVERFLOW = ("truncate", "full")


@dataclasses.dataclass(frozen=True)
class CullSettings:
    """How blockers are culled into the per-tile lists (the soft methods' options).

    Attributes:
        face_cull: gather: 'front' drops triangles facing all of the light, 'back' the
            opposite, 'none' keeps both.
        gather_cull: view-frustum culling of group and triangle cones (per frame).
        tile_cull: per-tile cone culling (off: every tile lists every gathered triangle).
        cluster_cull: a per-tile group level before the triangles (needs tile_cull).
        cluster_size: triangles per group (spatially sorted runs).
        bound: a tile's samples bounded by a 'sphere' or a 'capsule'.
        half_z: bound each half of a tile's depth range on its own.
        capacity: entries per tile list (>= 1).
        on_overflow: 'truncate' evaluates the first ``capacity`` entries of a longer
            list, 'full' all of them; either way the tile is flagged and counted.
    """

    face_cull: str
    gather_cull: bool
    tile_cull: bool
    cluster_cull: bool
    cluster_size: int
    bound: str
    half_z: bool
    capacity: int
    on_overflow: str

    def __post_init__(self):
        for name, allowed in (("face_cull", FACE_CULL), ("bound", BOUNDS),
                              ("on_overflow", ON_OVERFLOW)):
            if getattr(self, name) not in allowed:
                raise ValueError(f"{name} must be one of {allowed}, not "
                                 f"{getattr(self, name)!r}")
        if int(self.capacity) < 1 or int(self.cluster_size) < 1:
            raise ValueError("capacity and cluster_size must be >= 1")

    @property
    def halves(self) -> int:
        """Depth halves tested per tile: 2 with ``half_z``, else 1."""
        return 2 if self.half_z else 1


@dataclasses.dataclass(frozen=True, eq=False)
class TileLists:
    """The per-tile lists of :func:`build_tile_lists` (E entries over Nt tiles).

    Attributes:
        tile: int64 [E] tile of each entry, ascending (stable: within a tile, entries
            keep the group-major, member-minor order of the tests).
        entry: int64 [E] the blocker (index into the triangle cones).
        half_bits: int32 [E] bit h set: the entry may shadow depth half h of its tile.
        starts: int64 [Nt] first entry of each tile; lengths: int64 [Nt] full list
            lengths; counts: int64 [Nt] entries to evaluate (lengths capped at the
            capacity with ``on_overflow="truncate"``).
        overflow: bool [Nt] lengths > capacity.
        cluster_pairs, cluster_survivors: (tile, group) pairs tested / kept;
        triangle_pairs: (tile, triangle) pairs tested.
    """

    tile: np.ndarray
    entry: np.ndarray
    half_bits: np.ndarray
    starts: np.ndarray
    lengths: np.ndarray
    counts: np.ndarray
    overflow: np.ndarray
    cluster_pairs: int
    cluster_survivors: int
    triangle_pairs: int

    @property
    def overflow_tiles(self) -> int:
        return int(self.overflow.sum())

    @property
    def dropped_entries(self) -> int:
        """Entries past the capacity that are not evaluated (0 with 'full')."""
        return int((self.lengths - self.counts).sum())


def build_tile_lists(timer, group_cones: dict, triangle_cones: dict, members: np.ndarray,
                     bounds: np.ndarray, active: np.ndarray, settings: CullSettings,
                     dtype) -> TileLists:
    """Cull blocker cones into per-tile lists with capacity.

    Run inside the working precision (``precision_mode``): the cone tests run in
    ``dtype`` on the device.

    Args:
        timer: a ``StageTimer`` (stages ``tile_lists`` and ``tile_cull``).
        group_cones: cones of G groups (padded to >= G, see ``cones.pad_cones``).
        triangle_cones: cones of the triangles (padded likewise).
        members: int [G, k] triangle indices of each group (-1 = none).
        bounds: float64 [Nt, 2, 8] per tile and depth half the capsule (s0 xyz, r0,
            s1 xyz, r1), world units; r0 < 0 marks an empty half.
        active: bool [Nt] tiles with relevant samples (the others get empty lists).
        settings: tile_cull, cluster_cull, half_z, capacity and on_overflow are used.
    """
    n_tiles = len(active)
    n_groups = len(members)
    act_tiles = np.flatnonzero(active)
    with timer.stage("tile_lists"):
        tiles_p = np.repeat(act_tiles, n_groups)
        cl_p = np.tile(np.arange(n_groups), len(act_tiles))
    jb = jnp.asarray(bounds.astype(dtype))
    cluster_pairs = len(tiles_p)
    if settings.cluster_cull and settings.tile_cull and len(tiles_p):
        hit = _run_pairs(timer, group_cones, cl_p, tiles_p, jb, dtype, settings.halves)
        keep = hit.any(1)
        tiles_p, cl_p, cl_half = tiles_p[keep], cl_p[keep], hit[keep]
    else:
        cl_half = np.ones((len(tiles_p), 2), bool)
    cluster_survivors = len(tiles_p)
    with timer.stage("tile_lists"):
        reps = (members[cl_p] >= 0).sum(1)
        tri_t, tri_g = _expand(tiles_p, cl_p, members)
        tri_h = np.repeat(cl_half, reps, axis=0)
    triangle_pairs = len(tri_t)
    if settings.tile_cull and len(tri_t):
        hit = _run_pairs(timer, triangle_cones, tri_g, tri_t, jb, dtype,
                         settings.halves) & tri_h
        keep = hit.any(1)
        tri_t, tri_g, tri_h = tri_t[keep], tri_g[keep], hit[keep]
    with timer.stage("tile_lists"):
        order = stable_argsort(tri_t)
        tri_t, tri_g, tri_h = tri_t[order], tri_g[order], tri_h[order]
        lengths = np.bincount(tri_t, minlength=n_tiles)
        starts = np.concatenate([[0], np.cumsum(lengths)[:-1]])
        overflow = lengths > settings.capacity
        counts = (np.minimum(lengths, settings.capacity) if settings.on_overflow == "truncate"
                  else lengths)
        half_bits = (tri_h[:, 0].astype(np.int32) | (tri_h[:, 1].astype(np.int32) << 1))
    return TileLists(tri_t, tri_g, half_bits, starts, lengths, counts, overflow,
                     cluster_pairs, cluster_survivors, triangle_pairs)


def tile_layout(h: int, w: int):
    """int64 [Nt, 256]: flat pixel index of each tile slot (-1 outside the image)."""
    ty, tx = -(-h // TILE), -(-w // TILE)
    yy = (np.arange(ty)[:, None, None, None] * TILE + np.arange(TILE)[None, None, :, None])
    xx = (np.arange(tx)[None, :, None, None] * TILE + np.arange(TILE)[None, None, None, :])
    yy, xx = np.broadcast_arrays(yy, xx)
    idx = np.where((yy < h) & (xx < w), yy * w + xx, -1)
    return idx.reshape(ty * tx, TILE * TILE)


def tile_bounds(camera, depth: np.ndarray, relevant: np.ndarray, half_z: bool, pad: float):
    """Bounding capsules of each tile's relevant samples.

    Args:
        depth, relevant: [Nt, 256] view depths and flags (tile-major layout).
    Returns:
        float64 [Nt, 2, 8]: per depth half (near, far) the capsule (s0, r0, s1, r1):
        the tile's frustum between the half's min and max depth, its cross-section at
        depth z bounded by the disk of radius z * hd around the tile's centre ray.
        Without ``half_z`` half 0 holds the whole range and half 1 is empty
        (r0 = -1). Also returns half [Nt, 256] int (0 near, 1 far).
    """
    h, w = camera.height, camera.width
    ty, tx = -(-h // TILE), -(-w // TILE)
    t = math.tan(math.radians(camera.fov_y_deg) / 2)
    right, up, back = camera.basis()
    x0 = np.arange(tx) * TILE
    y0 = np.arange(ty) * TILE
    xe = np.minimum(x0 + TILE, w)
    ye = np.minimum(y0 + TILE, h)

    def ndc_x(px):
        return (px / w * 2 - 1) * t * camera.aspect

    def ndc_y(py):
        return (1 - py / h * 2) * t

    cx = np.stack([ndc_x(x0), ndc_x(xe)], -1)                  # [tx, 2]
    cy = np.stack([ndc_y(y0), ndc_y(ye)], -1)                  # [ty, 2]
    mx = cx.mean(-1)
    my = cy.mean(-1)
    hx = 0.5 * np.abs(cx[:, 1] - cx[:, 0])
    hy = 0.5 * np.abs(cy[:, 1] - cy[:, 0])
    rc = (mx[None, :, None] * right + my[:, None, None] * up - back).reshape(-1, 3)  # [Nt, 3]
    hd = np.sqrt(hx[None, :] ** 2 + hy[:, None] ** 2).reshape(-1)
    inf = np.where(relevant, depth, np.inf)
    sup = np.where(relevant, depth, -np.inf)
    zmin, zmax = inf.min(1), sup.max(1)
    if half_z:
        mid = np.where(relevant.any(1), 0.5 * (np.minimum(zmin, 1e300) + np.maximum(zmax, -1e300)),
                       0.0)
        half = (depth > mid[:, None]).astype(np.int64)
    else:
        half = np.zeros(depth.shape, np.int64)
    out = np.zeros((len(rc), 2, 8))
    for k in range(2):
        sel = relevant & (half == k)
        lo = np.where(sel, depth, np.inf).min(1)
        hi = np.where(sel, depth, -np.inf).max(1)
        ok = sel.any(1)
        lo = np.where(ok, lo, 1.0)
        hi = np.where(ok, hi, 1.0)
        out[:, k, 0:3] = camera.eye + lo[:, None] * rc
        out[:, k, 3] = np.where(ok, lo * hd * (1 + 1e-6) + pad, -1.0)
        out[:, k, 4:7] = camera.eye + hi[:, None] * rc
        out[:, k, 7] = np.where(ok, hi * hd * (1 + 1e-6) + pad, -1.0)
        # the depth planes' slab is a little thicker than the pixel positions
        out[:, k, 0:3] -= pad * rc / np.linalg.norm(rc, axis=1, keepdims=True)
        out[:, k, 4:7] += pad * rc / np.linalg.norm(rc, axis=1, keepdims=True)
    return out, half


def capsule_to_sphere(b: np.ndarray) -> np.ndarray:
    """The smallest sphere holding each capsule [..., 8], as a capsule with s0 = s1."""
    s0, r0, s1, r1 = b[..., 0:3], b[..., 3], b[..., 4:7], b[..., 7]
    d = np.linalg.norm(s1 - s0, axis=-1)
    r = 0.5 * (d + r0 + r1)
    r = np.maximum(r, np.maximum(r0, r1))
    t = np.where(d > 0, (r - r0) / np.maximum(d, 1e-300), 0.0)
    c = s0 + np.clip(t, 0, 1)[..., None] * (s1 - s0)
    out = b.copy()
    out[..., 0:3] = c
    out[..., 4:7] = c
    out[..., 3] = np.where(r0 < 0, -1.0, r)
    out[..., 7] = np.where(r0 < 0, -1.0, r)
    return out


def _pair_test(cone, tile_of, bounds, halves=2):
    """bool [P, 2]: cone p against the depth halves of tile tile_of[p].

    bounds: [Nt, 2, 8] = (s0 xyz, r0, s1 xyz, r1) per half; r0 < 0 marks an empty half.
    Without half-z (``halves=1``) half 1 is empty and not tested.
    """
    out = []
    for half in range(2):
        if half >= halves:
            out.append(jnp.zeros(tile_of.shape, bool))
            continue
        bb = bounds[:, half][tile_of]                          # [P, 8]
        hit = cone_hits_capsule(cone, bb[:, 0:3], bb[:, 4:7], bb[:, 3], bb[:, 7])
        out.append(hit & (bb[:, 3] >= 0))
    return jnp.stack(out, -1)


_PAIR_TESTS = {h: jax.jit(functools.partial(_pair_test, halves=h)) for h in (1, 2)}


def _run_pairs(timer, cone, which, tile_of, bounds, dtype, halves):
    """bool [P, 2]: cone ``which[p]`` against tile ``tile_of[p]``'s two halves."""
    n = len(which)
    cap = bucket(n, minimum=1024, steps=8)
    w = np.zeros(cap, np.int64)
    w[:n] = which
    t = np.zeros(cap, np.int64)
    t[:n] = tile_of
    c = {k: jnp.asarray(v[w] if v.dtype == bool else v[w].astype(dtype)) for k, v in cone.items()}
    out = timer.run("tile_cull", _PAIR_TESTS[halves], c, jnp.asarray(t.astype(np.int32)),
                    bounds)
    return np.asarray(out)[:n]


def _expand(tile_of: np.ndarray, group: np.ndarray, members: np.ndarray):
    """Pairs (tile, member) for every (tile, group) pair: members [C, k] (-1 = none)."""
    m = members[group]                                         # [P, k]
    t = np.repeat(tile_of, m.shape[1])
    m = m.reshape(-1)
    ok = m >= 0
    return t[ok], m[ok]
