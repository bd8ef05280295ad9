"""``soft_tiled``: tiled per-triangle soft shadows (Kalbertodt 2023), and ``soft_overlap_sum``.

For every relevant pixel the shadow-casting triangles are projected into the light's
disk (``sun_disk``) and rasterized into a bitmask grid; visibility = set bits / disk
bits. Triangles reach a pixel through two culling passes:

1. **gather** (per frame): light-facing culling (option ``face_cull``), then
   view-frustum culling of *truncated cones*: first of clusters (spatially sorted runs
   of ``cluster_size`` triangles, built once per scene), then of the triangles of the
   surviving clusters. The cone of a blocker (bounding sphere c, rho) holds every point
   it can shadow: for a sun, half-angle r around the light's travel direction with its
   apex rho / sin(r) behind c; for a sphere light (L, R), the penumbra cone through
   the internal similitude centre of the two spheres, half-angle asin((R + rho) / |c - L|).
   It is truncated by the plane through the blocker's vertex closest to the light.
   The frustum test: the view frustum between the nearest and farthest relevant
   depth, as six planes (a truncated cone entirely outside one is culled) and as a
   capsule bounding it.
2. **eval** per 16x16 screen tile: irrelevant pixels (invalid, or the whole light
   below their tangent plane) are skipped; tiles without relevant pixels exit early;
   the tile's relevant samples are bounded from its depth range (the tile frustum
   between z_min and z_max) by a sphere or a capsule (option ``bound``), optionally
   per half of the depth range (``half_z``, exact bounds of the two halves recomputed);
   cluster cones, then triangle cones are culled against it into a per-tile triangle
   list of fixed ``capacity`` (the paper's shared-memory list). A tile whose list
   overflows is counted (``overflow_tiles``) and shown (``overflow_tiles_per_pixel``);
   with ``on_overflow="truncate"`` it keeps the first ``capacity`` entries (the paper,
   whose result there is wrong and flagged), with ``"full"`` it evaluates them all.

The cones and their tests live in :mod:`shadowlab.structures.cones`, the tiles, their
bounds and the lists with capacity in :mod:`shadowlab.structures.tile_lists` (settings:
:class:`~shadowlab.structures.tile_lists.CullSettings`); this module gathers, then
evaluates the lists.

The light: a sun (direction, angular radius r; disk scale s = tan r) or a sphere
(position, radius R): seen from a fragment at distance D its silhouette is the disk of
angular radius asin(R / D) around the direction to its centre, in the plane at depth
D - R^2 / D along that direction; exactly what ``raycast.soft_reference`` samples.

Vectorized JAX: active tiles, sorted by list length, run in batches of 32 (one compiled
shape), vectorized over (tiles x 256 pixels). With ``defer`` (default) a batch first runs
only the per-pixel quick reject over its lists, recording the passing entries as bits,
then rasterizes just those (per round of 256 entries; with ``compact`` each step runs only
on the lanes with pairs left, in blocks of 512 lanes; with the paper's projection
the whole batch where the pairs are spread evenly); a pixel whose grid is
empty stops. Option ``record`` picks the record pass's test: the quick reject, the
triangle's bounding sphere against the pixel's light cone (the flush then runs the quick
reject), or both. See docs/soft_tiled.md.
"""

from __future__ import annotations

import dataclasses
import functools
import math
import weakref

import jax
import jax.numpy as jnp
import numpy as np

from ..core.numerics import materialize, norms3, opaque_zero
from ..geometry.morton import encode, round_robin_layout
from ..reference.raycast import shadow_epsilon
from ..scene.caches import per_scene_cache
from ..scene.view import SphereLight
from ..structures.cones import blocker_cones, cones_in_frustum, pad_cones
from ..structures.tile_lists import (
    TILE,
    CullSettings,
    build_tile_lists,
    capsule_to_sphere,
    tile_bounds,
    tile_layout,
)
from ..core.timing import StageTimer
from ..structures import sun_disk as sd
from ..core.capacity import bucket, check_int32, wide_add, wide_total
from ..core.frame import precision_mode
from .interface import MethodError
from .registry import Option, register
from ..core.result import ShadowResult

BATCH_TILES = 32        # tiles per eval call (32 x 256 pixels vectorized)
DEFER_WORDS = 8         # defer=True: 32-slot words of the tile list per round (bits per pixel)
FLUSH_BLOCK = 512       # compact flush: lanes per block (each runs until its own longest)
#: compact flush: a rasterizer step's fixed cost in lanes' worth of its per-lane work, per
#: projection (measured, docs/soft_tiled.md "Flush schedule"); 0: always the blocks
FLUSH_STEP_LANES = {"paper": 768, "homogeneous": 0}
#: record="sphere": the kernel widens each bounding sphere by this fraction of the
#: centre's light-frame offset (|x| + |y| + |z|), which covers the float32 rounding of the
#: offset, its rotation into the light frame and the cone's sine and cosine (each a few
#: units of 6e-8 of that offset); the host adds the rounding of the centre itself
SPHERE_REL_PAD = 1e-5


# ------------------------------------------------------------------ clusters (per scene)

_CLUSTER_CACHE: "weakref.WeakKeyDictionary" = per_scene_cache()


def build_clusters(scene, size: int) -> np.ndarray:
    """Triangle ids [C, size] of spatially sorted runs (Morton order of centroids);
    the last run is padded with -1."""
    per_scene = _CLUSTER_CACHE.setdefault(scene, {})
    if size in per_scene:
        return per_scene[size]
    tri = scene.triangles
    cen = tri.mean(axis=1)
    lo, hi = cen.min(0), cen.max(0)
    q = np.floor((cen - lo) / np.maximum(hi - lo, 1e-30) * 1023.999).astype(np.int64)
    keys = encode(np.clip(q, 0, 1023).T, round_robin_layout((10, 10, 10)))
    order = np.argsort(keys, kind="stable")
    n = len(order)
    c = -(-n // size)
    ids = np.full(c * size, -1, np.int64)
    ids[:n] = order
    per_scene[size] = ids.reshape(c, size)
    return per_scene[size]


# ------------------------------------------------------------------ per-pixel setup

def _orthonormal(w: np.ndarray):
    helper = np.where(np.abs(w[..., :1]) < 0.9, [1.0, 0.0, 0.0], [0.0, 1.0, 0.0])
    e1 = np.cross(helper, w)
    e1 /= np.linalg.norm(e1, axis=-1, keepdims=True)
    return e1, np.cross(w, e1)


def pixel_frames(pos, nrm, light: SphereLight, disk_scale: str):
    """Per-pixel light frame (float64, NumPy).

    Args:
        pos, nrm: [n, 3] positions and unit normals.
    Returns:
        frame [n, 3, 3] (rows e1, e2, w; w towards the light's centre), s [n] (disk
        scale: tan or sin of the angular radius), z_light [n] (depth of the silhouette
        disk's plane along w; inf for a sun), sin_a [n], cos_a [n] (sine and cosine of
        the angular radius).
    """
    n = len(pos)
    if light.is_sun:
        w = np.broadcast_to(-light.direction, (n, 3))
        r = math.radians(light.angular_radius_deg)
        sin_a = np.full(n, math.sin(r))
        z_light = np.full(n, np.inf)
    else:
        to_c = light.position - pos
        dist = norms3(to_c)
        w = to_c / np.maximum(dist, 1e-300)[:, None]
        sin_a = np.minimum(light.radius / np.maximum(dist, 1e-300), 1.0)
        z_light = dist - light.radius ** 2 / np.maximum(dist, 1e-300)
    cos_a = np.sqrt(np.maximum(1 - sin_a ** 2, 1e-30))
    s = sin_a / cos_a if disk_scale == "tan" else sin_a
    e1, e2 = _orthonormal(np.asarray(w, float))
    frame = np.stack([e1, e2, w], axis=1)
    return frame, s, z_light, sin_a, cos_a


def padded_spheres(tri: np.ndarray) -> np.ndarray:
    """float64 [n, 4]: the smallest bounding sphere of each triangle [n, 3, 3] (centre,
    radius), the radius widened by 1e-6 of (radius + sqrt(3) max|centre_i|) so that it
    still encloses the triangle after the centre and the vertices are rounded to float32
    (half a unit, 6e-8, of their largest coordinates). The smallest sphere: the
    circumsphere when the triangle is acute, else the sphere on its longest edge."""
    a, b, c = tri[:, 0], tri[:, 1], tri[:, 2]
    ab, ac = b - a, c - a
    n = np.cross(ab, ac)
    nn = np.einsum("ij,ij->i", n, n)
    # circumcentre a + (n x (|ac|^2 ab - |ab|^2 ac)) / (2 |n|^2), where n != 0
    num = np.cross(n, np.einsum("ij,ij->i", ac, ac)[:, None] * ab
                   - np.einsum("ij,ij->i", ab, ab)[:, None] * ac)
    with np.errstate(divide="ignore", invalid="ignore"):
        circ = a + num / (2 * nn)[:, None]
    edges = np.stack([b - a, c - b, a - c], 1)                   # [n, 3, 3]
    lens = np.einsum("ijk,ijk->ij", edges, edges)
    longest = np.argmax(lens, 1)
    mids = np.stack([(a + b) / 2, (b + c) / 2, (c + a) / 2], 1)
    mid = mids[np.arange(len(tri)), longest]
    # obtuse or right (or degenerate): the longest edge's ball holds the third vertex
    opposite = tri[np.arange(len(tri)), (longest + 2) % 3]
    on_edge = (np.einsum("ij,ij->i", opposite - mid, opposite - mid)
               <= lens[np.arange(len(tri)), longest] / 4) | ~(nn > 0)
    centre = np.where(on_edge[:, None], mid, circ)
    radius = np.sqrt(np.max(np.einsum("ijk,ijk->ij", tri - centre[:, None], tri - centre[:, None]),
                            1))
    radius += 1e-6 * (radius + np.abs(centre).max(1) * math.sqrt(3))
    return np.concatenate([centre, radius[:, None]], 1)


def sphere_meets_cone(ball, pos, frame, nrm, sin_a, cos_a, eps, z_light=None):
    """The record test of ``record="sphere"``/``"both"`` (array code, any broadcastable
    shapes): False where the ball certainly misses what a pixel's disk can see, so the
    pair covers no disk cell with the homogeneous projection.

    Args:
        ball: 4 arrays (centre x, y, z, radius; world units, frame-local).
        pos: 3 arrays, the pixel's position; frame: 9 arrays, its light frame (rows e1,
            e2, w; w towards the light's centre); nrm: 3 arrays, its normal in that
            frame. sin_a, cos_a: sine and cosine of the light's angular radius a.
        eps: the receiver bias (height above the tangent plane). z_light: depth of a
            sphere light's silhouette plane along w (None for a sun).
    Returns:
        bool: the ball meets the cone of half-angle a around w from ``pos`` (its
        centre's distance from the axis times cos a minus its depth times sin a is at
        most the radius: the cone lies on one side of that line in every plane
        through the axis), reaches in front of the pixel, above its tangent plane by
        more than ``eps`` and before the silhouette plane. The radius is widened by
        ``SPHERE_REL_PAD`` of the centre's light-frame offset for float32 rounding.
    """
    dv = [ball[i] - pos[i] for i in range(3)]
    dl = [dv[0] * frame[3 * j] + dv[1] * frame[3 * j + 1] + dv[2] * frame[3 * j + 2]
          for j in range(3)]
    r = ball[3] + SPHERE_REL_PAD * (jnp.abs(dl[0]) + jnp.abs(dl[1]) + jnp.abs(dl[2]))
    perp = jnp.sqrt(dl[0] * dl[0] + dl[1] * dl[1])
    hgt = dl[0] * nrm[0] + dl[1] * nrm[1] + dl[2] * nrm[2]
    ok = (perp * cos_a - dl[2] * sin_a <= r) & (dl[2] + r > 0) & (hgt + r > eps)
    if z_light is not None:
        ok &= dl[2] - r < z_light
    return ok


def frustum_planes(camera, zmin: float, zmax: float) -> np.ndarray:
    """float64 [6, 4]: inside where n . x + d >= 0 (sides, near at zmin, far at zmax)."""
    right, up, back = camera.basis()
    t = math.tan(math.radians(camera.fov_y_deg) / 2)
    ta = t * camera.aspect
    fwd = -back
    normals = [fwd * ta + right, fwd * ta - right, fwd * t + up, fwd * t - up]
    planes = []
    for n in normals:
        n = n / np.linalg.norm(n)
        planes.append(np.append(n, -n @ camera.eye))
    planes.append(np.append(fwd, -fwd @ camera.eye - zmin))
    planes.append(np.append(-fwd, fwd @ camera.eye + zmax))
    return np.asarray(planes)


# ------------------------------------------------------------------ eval kernel

def _defers(defer: bool, mode: str) -> bool:
    """Whether the eval kernel runs the deferred record-then-flush form (bitmask only)."""
    return defer and mode == "bitmask"


@functools.lru_cache(maxsize=None)
def _eval_kernel(grid_name: str, chunk: int, projection: str, sphere: bool, horizon: bool,
                 mode: str, defer: bool = True, compact: bool = True, record: str = "exact"):
    g = sd.grid(grid_name)
    disk = [np.uint32(wd) for wd in g.disk_mask()]
    defer = _defers(defer, mode)
    words_per_round = DEFER_WORDS
    record = record if defer else "exact"

    @jax.jit
    def run(tiles, offsets, counts, trips, pix, tri, spheres, entries, entry_half, eps):
        """Visibility of the pixels of ``tiles`` [G].

        pix: per-tile pixel arrays, component axis first: pos [3, Nt, 256], frame
        [9, Nt, 256] (rows e1, e2, w), nrm [3, Nt, 256] (light frame), s, zl, and the
        sine and cosine of the light's angular radius sa, ca [Nt, 256], half [Nt, 256]
        int32, rel [Nt, 256] bool. tri [9, Tg] vertex coordinates; spheres [4, Tg] the
        triangles' padded bounding spheres (centre, radius; read with
        ``record="sphere"`` or ``"both"``); entries/entry_half [L]: the flat tile lists
        (tile t's at
        offsets[t] .. offsets[t] + counts[t]). Returns vis [G, 256], the counts of
        tests, rasterized, near-clamp and recorded pairs [G, 256] (int32) and the
        rasterizer lanes executed with ``defer`` (steps x lanes, summed over the steps;
        int32 [2], two words: ``core.capacity.wide_add``; zeros without ``defer``, whose
        count the host computes).
        """
        pos = [pix["pos"][i][tiles] for i in range(3)]              # [G, 256] each
        fr = [pix["frame"][i][tiles] for i in range(9)]
        nrm = tuple(pix["nrm"][i][tiles] for i in range(3))
        s, zl = pix["s"][tiles], pix["zl"][tiles]
        sin_a, cos_a = pix["sa"][tiles], pix["ca"][tiles]
        phalf, rel = pix["half"][tiles], pix["rel"][tiles]
        dtype = s.dtype
        shape = s.shape
        # one opaque zero (NaN eps spoils everything anyway) for the sun_disk primitives'
        # products: they round the same in every program (and as the Warp kernel)
        zr = opaque_zero(eps, jnp.int32)
        words0 = [jnp.full(shape, wd, jnp.uint32) for wd in disk]
        if mode == "bitmask" and horizon:
            below = sd.edge_outside_list(*sd.horizon_edge_list(nrm, s, zr), g, zr)
            words0 = [wd & ~b for wd, b in zip(words0, sd.pack_list(below, g))]
        blocked0 = jnp.zeros(shape, dtype)
        if mode == "overlap" and horizon:
            # disk area below the horizon line s n_x x + s n_y y + n_z = 0 (a segment)
            ln = jnp.sqrt((s * nrm[0]) ** 2 + (s * nrm[1]) ** 2)
            hgt = jnp.clip(nrm[2] / jnp.maximum(ln, 1e-30), -1.0, 1.0)
            blocked0 = (jnp.arccos(hgt) - hgt * jnp.sqrt(1 - hgt * hgt)) / math.pi
        zero = jnp.zeros(shape, jnp.int32)
        tri_rows = tri.T                                                   # [Tg, 9]

        # the pixels' own data; the flush runs on lanes gathered from it (same keys)
        px_all = {"pos": pos, "fr": fr, "nrm": nrm, "s": s, "zl": zl}

        def light_frame(vx, px):
            """Vertices (9 arrays, broadcastable to the lanes of ``px``) -> d: 3
            light-frame tuples."""
            pos, fr = px["pos"], px["fr"]
            d = []
            for v in range(3):
                dv = [vx[3 * v + i] - pos[i] for i in range(3)]
                d.append(tuple(dv[0] * fr[3 * c] + dv[1] * fr[3 * c + 1]
                               + dv[2] * fr[3 * c + 2] for c in range(3)))
            return d

        def projected(d, px):
            q = [sd.project_paper_list(d[v][0], d[v][1], d[v][2], px["s"], zr)
                 for v in range(3)]
            return [q[v][0] for v in range(3)], [q[v][1] for v in range(3)]

        def quick_reject(d, qx, qy, px):
            """bool (lanes of ``px``): the pair passes the per-pixel quick reject; near:
            the clamp acts."""
            s, zl = px["s"], px["zl"]
            z = [d[v][2] for v in range(3)]
            hgt = [sd._dot(d[v], px["nrm"]) for v in range(3)]
            quick = ~((z[0] <= 0) & (z[1] <= 0) & (z[2] <= 0))
            quick &= ~((hgt[0] <= eps) & (hgt[1] <= eps) & (hgt[2] <= eps))
            if sphere:
                quick &= ~((z[0] >= zl) & (z[1] >= zl) & (z[2] >= zl))
            inbox = ~(((qx[0] > 1) & (qx[1] > 1) & (qx[2] > 1))
                      | ((qx[0] < -1) & (qx[1] < -1) & (qx[2] < -1))
                      | ((qy[0] > 1) & (qy[1] > 1) & (qy[2] > 1))
                      | ((qy[0] < -1) & (qy[1] < -1) & (qy[2] < -1)))
            if projection == "paper" or mode == "overlap":
                quick &= inbox
            else:   # the projected box is exact only with every vertex in front
                front = ((z[0] * s > sd.PAPER_CLAMP) & (z[1] * s > sd.PAPER_CLAMP)
                         & (z[2] * s > sd.PAPER_CLAMP))
                quick &= inbox | ~front
            # the paper's clamp (or abs()) acts on some vertex of this triangle
            near = ((z[0] * s < sd.PAPER_CLAMP) | (z[1] * s < sd.PAPER_CLAMP)
                    | (z[2] * s < sd.PAPER_CLAMP))
            return quick, near

        def keep_words(d, qx, qy, mask, px):
            """The words to AND into the grid (every bit kept where ~mask)."""
            if projection == "paper":
                edges, ok = sd.triangle_edges_list(qx, qy, zr)
            else:
                edges, ok = sd.homogeneous_edges_list(d, px["s"], px["nrm"], eps,
                                                      px["zl"] if sphere else None, zr)
            # Each grid word is its own loop fusion on XLA/CPU, and each recomputed the
            # vertex gather, light-frame transform and edge setup: compute the edge
            # functions once (their products are opaque, so no FMA spans the boundary).
            flat = jnp.broadcast_arrays(*(x for e in edges for x in e), mask & ok)
            flat = materialize(*flat)
            edges = [tuple(flat[3 * i: 3 * i + 3]) for i in range(len(edges))]
            return sd.pack_list(sd.polygon_keep_list(edges, g, flat[-1], zr), g)

        def raster_pair(e, mask, px, gate=False):
            """Keep words of triangle e (per lane: [G, 256], or [n] lanes of the flush)
            where mask; ``px``: the lanes' pixel data. Every path goes through here with
            per-lane vertex gathers, so they compile to the same arithmetic: XLA
            contracts a * b + c to an FMA within a fusion, and a differently fused copy
            can round a cell centre on an edge the other way. With ``gate`` the exact
            quick reject runs here too (``record="sphere"``: the record pass ran only the
            sphere test); returns (keep words, rasterized mask, near-clamp mask)."""
            v = tri_rows[e]                         # [..., 9]: one gather of 9 floats
            d = light_frame([v[..., i] for i in range(9)], px)
            qx, qy = projected(d, px)
            if not gate:
                return keep_words(d, qx, qy, mask, px), mask, mask
            quick, near = quick_reject(d, qx, qy, px)
            mask = mask & quick
            return keep_words(d, qx, qy, mask, px), mask, mask & near

        def sphere_passes(e):
            """bool [G, 256]: :func:`sphere_meets_cone` for triangle e (per pixel
            [G, 1])."""
            return sphere_meets_cone([spheres[i][e] for i in range(4)], pos, fr, nrm,
                                     sin_a, cos_a, eps, zl if sphere else None)

        def chunk_entries(j):
            """The chunk's list entries: live [G, K], triangle [G, K], half bits [G, K]."""
            slot = j * chunk + jnp.arange(chunk, dtype=jnp.int32)          # [K]
            live = slot[None, :] < counts[:, None]                          # [G, K]
            idx = jnp.where(live, offsets[:, None] + slot[None, :], 0)
            return live, entries[idx], entry_half[idx]

        def chunk_visits(j, alive, counts, test="exact"):
            """Visit the entries of chunk j in order, lazily: yields (k, ent, qx, qy, use,
            counts) per entry k, counts = (tests, rasterized, near clamps, recorded)
            int32 [G, 256] with entry k added. ``use``: it passed ``test``: "exact", the
            quick reject (then also counted as rasterized); "sphere", the bounding-sphere
            test (qx, qy are then None; the flush runs the quick reject; only then is
            ``recorded`` counted apart, since otherwise it equals rasterized); "both",
            both (counted as rasterized)."""
            live, ent, eh = chunk_entries(j)
            tests, rast, clamp, rec = counts
            for k in range(chunk):
                in_half = ((eh[:, k, None] >> phalf) & 1) == 1              # [G, 256]
                # no skip of the pixel's own triangle by index: ``gbuf.triangle`` numbers
                # the triangles of the scene the G-buffer was rendered from, not of
                # ``scene`` (a caster-culled subset renumbers them, and the skip then hit
                # a true occluder); the own triangle (and any coplanar one) fails the
                # quick reject's height test, as in the reference
                act = live[:, k, None] & rel & in_half & alive
                tests = tests + act.astype(jnp.int32)
                if test == "sphere":
                    qx = qy = None
                    use = act & sphere_passes(ent[:, k, None])
                else:
                    d = light_frame([tri[i][ent[:, k], None] for i in range(9)], px_all)
                    qx, qy = projected(d, px_all)
                    quick, near = quick_reject(d, qx, qy, px_all)
                    use = act & quick
                    if test == "both":
                        use &= sphere_passes(ent[:, k, None])
                    # once for the counters and the record bits (one fusion each else)
                    use, near = materialize(use, near)
                    rast = rast + use.astype(jnp.int32)
                    clamp = clamp + (use & near).astype(jnp.int32)
                if test == "sphere":
                    rec = rec + use.astype(jnp.int32)
                yield k, ent, qx, qy, use, (tests, rast, clamp, rec)

        if not defer:
            # every visited pair is rasterized; the quick reject only gates the result
            def body(j, state):
                words, blocked, counts = state[0], state[1], state[2:]
                for k, ent, qx, qy, use, counts in chunk_visits(j, True, counts):
                    if mode == "overlap":
                        pts = jnp.stack([jnp.stack(jnp.broadcast_arrays(qx[v], qy[v]), -1)
                                         for v in range(3)], -2)
                        area = sd.overlap_area(pts) / math.pi
                        blocked = blocked + jnp.where(use, area, 0.0).astype(dtype)
                        continue
                    keep = raster_pair(jnp.broadcast_to(ent[:, k, None], shape), use, px_all)[0]
                    words = [wd & kp for wd, kp in zip(words, keep)]
                return (words, blocked) + counts

            words, blocked, tests, rast, clamp, rec = jax.lax.fori_loop(
                0, trips, body, (words0, blocked0, zero, zero, zero, zero))
            if mode == "overlap":
                vis = jnp.clip(1.0 - blocked, 0.0, 1.0)
            else:
                vis = (sd.popcount_list(words).astype(dtype) / g.disk_bits).astype(dtype)
            # every step rasterizes on every lane of the batch: trips x chunk x lanes,
            # which the host computes exactly (an int32 product could wrap)
            lanes = jnp.zeros(2, jnp.int32)
            return jnp.where(rel, vis, 0.0), tests, rast, clamp, rast, lanes

        # Deferred: a first pass over the list only runs the per-pixel quick reject and
        # records the entries passing it as bits (bit b of word w: list slot 32 w + b of
        # the round); the word index is the same for every pixel, so recording is one
        # shift-or. Then every pixel pops its set bits, one per step for the whole batch,
        # and rasterizes only those: max(passing) steps per round instead of the round's
        # length. Rounds hold ``words_per_round`` x 32 slots; after each, a pixel whose
        # grid is empty stops (nothing can change it) and the batch stops when no pixel
        # is left.
        per_word = 32 // chunk
        n_words = (jnp.max(counts) + 31) // 32
        word_idx = jnp.arange(words_per_round, dtype=jnp.int32)[:, None, None]
        one = jnp.uint32(1)

        def ctz(x):
            """Trailing zeros of uint32 x (32 for x = 0)."""
            return jax.lax.population_count((x & (~x + one)) - one).astype(jnp.int32)

        def record_word(wi, state):
            """Run the record test on the 32 slots of word wi (global); store their bits."""
            base, counts, bits, summary, alive = state

            def step(st, carry):
                cur, counts = carry
                j = wi * per_word + st
                for k, _, _, _, use, counts in chunk_visits(j, alive, counts, record):
                    shift = (st * chunk + k).astype(jnp.uint32)
                    cur = cur | jax.lax.shift_left(use.astype(jnp.uint32), shift)
                return cur, counts

            cur, counts = jax.lax.fori_loop(0, per_word, step,
                                            (jnp.zeros(shape, jnp.uint32), counts))
            local = wi - base
            bits = jnp.where(word_idx == local, cur[None], bits)
            summary = summary | jax.lax.shift_left((cur != 0).astype(jnp.uint32),
                                                   local.astype(jnp.uint32))
            return base, counts, bits, summary, alive

        def flush(words, base, bits, summary):
            """Rasterize every recorded pair of the round (base: its first word).

            Every lane pops one recorded pair per step. Without ``compact`` all lanes of
            the batch run until the lane with the most pairs is done. With it, the lanes
            are sorted by their number of pairs (descending) and run in blocks of
            ``FLUSH_BLOCK`` consecutive lanes of that order, one block after the other,
            each until its own first (largest) lane is done (the blocks after the first
            empty one are skipped). With the paper's projection, whose step is cheap per
            lane, a round whose pairs are spread evenly runs the whole batch at once
            instead, where that costs less with a step costing its lanes plus
            ``FLUSH_STEP_LANES`` (its fixed part, which the blocks pay n / 512 times per
            step of the whole batch). The kernel holds one copy of the rasterizer step per
            width, whatever the batch size. No lane stops before its pairs are done, and
            a lane's steps do not depend on the others (the grid is an AND of its pairs'
            keep words), so the words are those of the full run.
            With ``record="sphere"`` each popped pair first runs the exact quick reject.
            Returns the words, the rasterized and near-clamp counts of the flush [G, 256]
            (zero unless ``record="sphere"``) and the lanes executed (steps x lanes,
            int32 [])."""
            todo = sum(jax.lax.population_count(bits[w]).astype(jnp.int32)
                       for w in range(words_per_round))
            n = todo.size

            def lane_of(a):
                return a.reshape(-1)

            # per-lane data the steps read (bits: [words_per_round, lanes])
            data = {"bits": bits.reshape(words_per_round, n),
                    "off": lane_of(jnp.broadcast_to(offsets[:, None], shape)),
                    "px": jax.tree_util.tree_map(lambda a: lane_of(jnp.broadcast_to(a, shape)),
                                                 px_all)}
            # the rasterized and near-clamp counts of the flush (sphere record only)
            gated = record == "sphere"
            state = ([lane_of(wd) for wd in words], lane_of(summary),
                     jnp.zeros(n, jnp.uint32), jnp.zeros(n, jnp.int32),
                     *([jnp.zeros(n, jnp.int32)] * (2 if gated else 0)))
            todo = lane_of(todo)

            def step_on(lanes):
                def step(_, carry):
                    words, summary, cur, cur_w = carry[:4]
                    need = cur == 0
                    w_new = jnp.minimum(ctz(summary), words_per_round - 1)
                    loaded = jnp.take_along_axis(lanes["bits"], w_new[None], 0)[0]
                    cur = jnp.where(need & (summary != 0), loaded, cur)
                    cur_w = jnp.where(need, w_new, cur_w)
                    summary = jnp.where(need, summary & (summary - one), summary)
                    has = cur != 0
                    slot = (base + cur_w) * 32 + ctz(cur)
                    cur = cur & (cur - one)
                    idx = jnp.where(has, lanes["off"] + slot, 0)
                    keep, used, near = raster_pair(entries[idx], has, lanes["px"], gate=gated)
                    counts = ()
                    if gated:
                        counts = (carry[4] + used.astype(jnp.int32),
                                  carry[5] + near.astype(jnp.int32))
                    return ([wd & kp for wd, kp in zip(words, keep)], summary, cur, cur_w,
                            *counts)
                return step

            def full_width(state):
                steps = jnp.max(todo)
                return jax.lax.fori_loop(0, steps, step_on(data), state), n * steps

            block = min(FLUSH_BLOCK, n)
            assert n % block == 0, (n, block)
            n_blocks = n // block

            def in_blocks(args):
                state, order, ranked = args
                lanes, state = jax.tree_util.tree_map(lambda a: a[..., order], (data, state))

                def run_block(carry):
                    b, state, executed = carry
                    lo = b * block

                    def part(a):
                        return jax.lax.dynamic_slice_in_dim(a, lo, block, axis=a.ndim - 1)

                    # ranked is descending: the block's first lane has the most pairs
                    steps = ranked[lo]
                    done = jax.lax.fori_loop(0, steps,
                                             step_on(jax.tree_util.tree_map(part, lanes)),
                                             jax.tree_util.tree_map(part, state))
                    state = jax.tree_util.tree_map(
                        lambda a, d: jax.lax.dynamic_update_slice_in_dim(a, d, lo, a.ndim - 1),
                        state, done)
                    return b + 1, state, executed + block * steps

                def more_blocks(carry):
                    b = carry[0]
                    return (b < n_blocks) & (ranked[jnp.minimum(b, n_blocks - 1) * block] > 0)

                _, state, executed = jax.lax.while_loop(more_blocks, run_block,
                                                        (jnp.int32(0), state, jnp.int32(0)))
                # back to lane order: the words and counts only (the rest is not read)
                def unsort(o):
                    return jnp.zeros_like(o).at[order].set(o)
                return ([unsort(w) for w in state[0]], *state[1:4],
                        *map(unsort, state[4:])), executed

            step_lanes = FLUSH_STEP_LANES[projection]
            if compact:
                order = jnp.argsort(-todo, stable=True)
                ranked = todo[order]
                args = (state, order, ranked)
                if step_lanes == 0:
                    state, executed = in_blocks(args)
                else:
                    # blocks only where their steps cost less than the whole batch's, a
                    # step costing its lanes plus ``step_lanes``
                    whole = ranked[0].astype(jnp.float32) * (n + step_lanes)
                    split = (jnp.sum(ranked[::block]).astype(jnp.float32)
                             * (block + step_lanes))
                    state, executed = jax.lax.cond(whole <= split, lambda a: full_width(a[0]),
                                                   in_blocks, args)
            else:
                state, executed = full_width(state)
            out, out_counts = list(state[0]), list(state[4:])
            if not gated:
                out_counts = [jnp.zeros(n, jnp.int32)] * 2
            return ([o.reshape(shape) for o in out], [c.reshape(shape) for c in out_counts],
                    executed)

        def round_(state):
            base, words, counts, alive, steps = state
            end = jnp.minimum(base + words_per_round, n_words)
            _, counts, bits, summary, _ = jax.lax.fori_loop(
                base, end, record_word,
                (base, counts, jnp.zeros((words_per_round,) + shape, jnp.uint32),
                 jnp.zeros(shape, jnp.uint32), alive))
            words, (rast, clamp), executed = flush(words, base, bits, summary)
            tests, rast0, clamp0, rec = counts
            alive = functools.reduce(jnp.logical_or, [wd != 0 for wd in words])
            return (end, words, (tests, rast0 + rast, clamp0 + clamp, rec), alive,
                    wide_add(steps, executed))

        def more(state):
            return (state[0] < n_words) & jnp.any(state[3] & rel)

        alive0 = functools.reduce(jnp.logical_or, [wd != 0 for wd in words0])
        state = jax.lax.while_loop(more, round_, (jnp.int32(0), words0, (zero,) * 4,
                                                  alive0, jnp.zeros(2, jnp.int32)))
        _, words, (tests, rast, clamp, rec), _, lanes = state
        vis = (sd.popcount_list(words).astype(dtype) / g.disk_bits).astype(dtype)
        return (jnp.where(rel, vis, 0.0), tests, rast, clamp,
                rec if record == "sphere" else rast, lanes)

    return run


# ------------------------------------------------------------------ the method

@dataclasses.dataclass(frozen=True, eq=False)
class Gathered:
    """The blockers that survive the per-frame gather (G groups, n triangles).

    Attributes:
        triangles: int64 [n] scene triangle ids; members: int64 [G, k] indices into
            ``triangles`` (-1 = none); group_cones, triangle_cones: padded cones of the
            groups and triangles (``structures.cones``); clusters: int64 [C, k] the
            scene's groups; light_facing: triangles left by light-facing culling; pad:
            world-space padding of the depth bounds.
    """

    triangles: np.ndarray
    members: np.ndarray
    group_cones: dict
    triangle_cones: dict
    clusters: np.ndarray
    light_facing: int
    pad: float


def _gather(timer, scene, light, cam, depth, relevant, eps, culling: CullSettings,
            dtype) -> Gathered:
    """Light-facing culling, then view-frustum culling of group and triangle cones
    between the nearest and farthest relevant depth (depth, relevant: [Nt, 256])."""
    tri_all = scene.triangles                                    # float64 [T, 3, 3]
    n_tri = len(tri_all)
    samples = int(relevant.sum())
    with timer.stage("gather"):
        # light-facing culling (the paper culls triangles facing the light)
        e1 = tri_all[:, 1] - tri_all[:, 0]
        e2 = tri_all[:, 2] - tri_all[:, 0]
        ng = np.cross(e1, e2)
        area2 = np.linalg.norm(ng, axis=1)
        live = area2 > 0
        ng = ng / np.maximum(area2, 1e-300)[:, None]
        if light.is_sun:
            facing = ng @ -light.direction
            margin = math.sin(math.radians(light.angular_radius_deg))
        else:
            facing = np.einsum("ij,ij->i", ng, light.position - tri_all[:, 0])
            margin = light.radius
        if culling.face_cull == "front":
            live &= ~(facing > margin)                           # faces all of the light
        elif culling.face_cull == "back":
            live &= ~(facing < -margin)
        after_facing = int(live.sum())
        clusters = build_clusters(scene, culling.cluster_size)           # [C, k]
        members = np.where(clusters >= 0, clusters, -1)
        members = np.where(live[np.maximum(members, 0)] & (members >= 0), members, -1)
        nonempty = (members >= 0).any(1)
        members = members[nonempty]
        rel_depth = depth[relevant]
        if samples:
            zmin, zmax = float(rel_depth.min()), float(rel_depth.max())
        else:
            zmin = zmax = 1.0
        pad = 1e-5 * scene.diagonal + 2 * eps
        # whole-screen capsule: the view frustum between zmin and zmax
        t = math.tan(math.radians(cam.fov_y_deg) / 2)
        hd = t * math.hypot(1.0, cam.aspect)
        back = cam.basis()[2]
        s0 = cam.eye - zmin * back
        s1 = cam.eye - zmax * back
        r0, r1 = zmin * hd + pad, zmax * hd + pad
        planes = frustum_planes(cam, zmin - pad, zmax + pad)

    def to_j(cone):
        return {k: jnp.asarray(v if v.dtype == bool else v.astype(dtype))
                for k, v in cone.items()}

    def gather_test(cone):
        if not culling.gather_cull:
            return np.ones(len(cone["t0"]), bool)
        args = (to_j(cone), jnp.asarray(planes, dtype), jnp.asarray(s0, dtype),
                jnp.asarray(s1, dtype), jnp.asarray(r0, dtype), jnp.asarray(r1, dtype))
        return np.asarray(timer.run("gather_test", cones_in_frustum, *args))

    with timer.stage("gather"):
        cl_cone = pad_cones(blocker_cones(tri_all, members, light))
    keep_cl = gather_test(cl_cone)[: len(members)] if samples else np.zeros(len(members), bool)
    with timer.stage("gather"):
        members = members[keep_cl]
        cand = members[members >= 0]
        tri_cone = pad_cones(blocker_cones(tri_all[cand], None, light))
    keep_tri = gather_test(tri_cone)[: len(cand)] if len(cand) else np.zeros(0, bool)
    with timer.stage("gather"):
        gathered = cand[keep_tri]                            # original triangle ids
        local = np.full(n_tri, -1, np.int64)
        local[gathered] = np.arange(len(gathered))
        g_members = np.where(members >= 0, local[np.maximum(members, 0)], -1)
        g_nonempty = (g_members >= 0).any(1)
        g_members = g_members[g_nonempty]
        g_cl_cone = pad_cones(blocker_cones(tri_all, np.where(
            g_members >= 0, gathered[np.maximum(g_members, 0)], -1), light))
        g_tri_cone = pad_cones(blocker_cones(tri_all[gathered], None, light))
    return Gathered(gathered, g_members, g_cl_cone, g_tri_cone, clusters, after_facing, pad)


def soft_tiled_impl(scene, gbuf, light, **kwargs):
    """Visibility of every pixel (see the module docstring).

    ``culling`` holds the gather and tile-list settings; the rest configure the per-pixel
    evaluation (``mode``: "bitmask" rasterizes into the disk grid, "overlap" sums
    analytic overlap areas). Returns a ``ShadowResult`` whose ``lit`` is float [H, W]
    visibility in [0, 1]. Its ``total`` is the whole call's wall time, compile apart:
    host work between the named stages (gathers, compactions, copies between host and
    device, the batch loop) is the stage ``host``.
    """
    timer = StageTimer()
    with timer.remainder("host"):
        vis_img, counters = _soft_tiled(timer, scene, gbuf, light, **kwargs)
    timings = dict(timer.times, total=timer.total)
    return ShadowResult(vis_img, counters, timings)


def _soft_tiled(timer, scene, gbuf, light, *, culling: CullSettings, precision, shadow_eps,
                grid, rotate, seed, projection, disk_scale, horizon, chunk, mode, method,
                defer=False, compact=True, record="exact"):
    """(visibility float [H, W], counters) of :func:`soft_tiled_impl`; stages into
    ``timer``."""
    cam = gbuf.camera
    h, w = gbuf.shape
    eps = shadow_epsilon(scene, shadow_eps)
    if record != "exact" and (projection != "homogeneous" or not defer):
        why = ("the paper projection's clamp and abs() can bring a triangle outside the "
               "light cone into the disk, so the cone test would not be conservative"
               if projection != "homogeneous" else
               "the test belongs to the deferred record pass")
        raise MethodError(f"method {method!r}: option record={record!r} needs "
                          f"projection='homogeneous' and defer=True (got projection="
                          f"{projection!r}, defer={defer!r}): {why}")
    with timer.stage("setup"):
        tri_all = scene.triangles                                # float64 [T, 3, 3]
        n_tri = len(tri_all)
        layout = tile_layout(h, w)
        n_tiles = len(layout)
        flat = np.maximum(layout, 0)
        inside = layout >= 0
        pos = gbuf.position.reshape(-1, 3)[flat]                 # [Nt, 256, 3]
        nrm = gbuf.normal.reshape(-1, 3)[flat]
        depth = gbuf.depth.reshape(-1)[flat]
        valid = gbuf.valid.reshape(-1)[flat] & inside
        frame, s, z_light, sin_a, cos_a = pixel_frames(pos.reshape(-1, 3), nrm.reshape(-1, 3), light,
                                                disk_scale)
        frame = frame.reshape(n_tiles, TILE * TILE, 3, 3)
        s = s.reshape(n_tiles, -1)
        z_light = z_light.reshape(n_tiles, -1)
        n_dot_w = np.einsum("tpi,tpi->tp", nrm, frame[..., 2, :])
        # relevant: valid and some of the light's disk above the tangent plane
        relevant = valid & (n_dot_w > -sin_a.reshape(n_tiles, -1))
        if rotate:
            ang = np.asarray(sd.pixel_angle(jnp.asarray(flat.astype(np.uint32)), seed,
                                            dtype=jnp.float32), np.float64)
            c, sn = np.cos(ang)[..., None], np.sin(ang)[..., None]
            e1, e2 = frame[..., 0, :].copy(), frame[..., 1, :].copy()
            frame[..., 0, :] = c * e1 + sn * e2
            frame[..., 1, :] = -sn * e1 + c * e2
        nrm_l = np.einsum("tpci,tpi->tpc", frame, nrm)
        samples = int(relevant.sum())

    with precision_mode(precision) as dtype:
        gath = _gather(timer, scene, light, cam, depth, relevant, eps, culling, dtype)
        gathered, g_members = gath.triangles, gath.members
        n_gather_cl, n_gather = len(g_members), len(gathered)

        # ---- eval pass, culling part: per tile, clusters then triangles
        with timer.stage("tile_bounds"):
            bounds, half = tile_bounds(cam, depth, relevant, culling.half_z, gath.pad)
            if culling.bound == "sphere":
                bounds = capsule_to_sphere(bounds)
            active = relevant.any(1)
        lists = build_tile_lists(timer, gath.group_cones, gath.triangle_cones, g_members,
                                 bounds, active, culling, dtype)
        tri_g, starts, counts = lists.entry, lists.starts, lists.counts

        # ---- eval pass, rasterization: tiles grouped by chunk count
        with timer.stage("eval_setup"):
            pix = {"pos": np.moveaxis(pos, -1, 0),
                   "frame": np.moveaxis(frame.reshape(n_tiles, TILE * TILE, 9), -1, 0),
                   "nrm": np.moveaxis(nrm_l, -1, 0), "s": s,
                   "zl": np.where(np.isfinite(z_light), z_light, 0.0),
                   "sa": sin_a.reshape(n_tiles, -1),
                   "ca": cos_a.reshape(n_tiles, -1)}
            pix = {k: jnp.asarray(np.ascontiguousarray(v, dtype)) for k, v in pix.items()}
            pix["half"] = jnp.asarray(half.astype(np.int32))
            pix["rel"] = jnp.asarray(relevant)
            tri_g_arr = np.zeros((bucket(max(n_gather, 1), minimum=64, steps=8), 3, 3), dtype)
            tri_g_arr[:n_gather] = tri_all[gathered]
            L = check_int32(bucket(max(len(tri_g), 1), minimum=1024, steps=8),
                            "soft_tiled tile-list entries (read at int32 offsets)",
                            "keep tile_cull on, or render fewer pixels or casters")
            ent = np.zeros(L, np.int32)
            ent[:len(tri_g)] = tri_g
            ehalf = np.zeros(L, np.int32)
            ehalf[:len(tri_g)] = lists.half_bits
            tri_soa = np.ascontiguousarray(tri_g_arr.reshape(-1, 9).T)
            spheres = np.zeros((4, len(tri_g_arr)), dtype)
            if record != "exact":
                spheres[:, :n_gather] = padded_spheres(tri_all[gathered]).T
            args_common = (pix, jnp.asarray(tri_soa), jnp.asarray(spheres), jnp.asarray(ent),
                           jnp.asarray(ehalf), jnp.asarray(dtype(eps)))
            kernel = _eval_kernel(grid, chunk, projection, not light.is_sun, horizon, mode, defer,
                                  compact, record)
            deferred = _defers(defer, mode)
            nchunks = -(-counts // chunk)
            vis = np.zeros((n_tiles, TILE * TILE))
            tests = np.zeros((n_tiles, TILE * TILE), np.int64)
            rast = np.zeros((n_tiles, TILE * TILE), np.int64)
            clamped = np.zeros((n_tiles, TILE * TILE), np.int64)
            recorded = 0
            raster_lanes = 0
            # tiles sorted by chunk count, in batches of a fixed size: one compiled shape,
            # and every batch loops only as long as its longest list
            work = np.flatnonzero(active)
            work = work[np.argsort(-nchunks[work], kind="stable")]
            batch = min(BATCH_TILES, bucket(max(len(work), 1), minimum=4))
        for lo in range(0, len(work), batch):
            members_t = work[lo: lo + batch]
            tiles = np.zeros(batch, np.int32)
            tiles[: len(members_t)] = members_t
            offs = np.zeros(batch, np.int32)
            offs[: len(members_t)] = starts[members_t]
            cnts = np.zeros(batch, np.int32)
            cnts[: len(members_t)] = counts[members_t]
            trips = jnp.asarray(int(nchunks[members_t].max()), jnp.int32)
            v, te, ra, cl, rc, st = timer.run("eval", kernel, jnp.asarray(tiles),
                                              jnp.asarray(offs), jnp.asarray(cnts), trips,
                                              *args_common)
            n = len(members_t)
            vis[members_t] = np.asarray(v)[:n]
            tests[members_t] = np.asarray(te)[:n]
            rast[members_t] = np.asarray(ra)[:n]
            clamped[members_t] = np.asarray(cl)[:n]
            recorded += int(np.asarray(rc)[:n].sum())
            raster_lanes += (int(wide_total(st)) if deferred
                             else int(nchunks[members_t].max()) * chunk * batch * TILE * TILE)

    with timer.stage("output"):
        def to_image(values, fill=0):
            out = np.full(h * w, fill, dtype=values.dtype)
            sel = layout >= 0
            out[layout[sel]] = values[sel]
            return out.reshape(h, w)

        vis_img = to_image(np.where(relevant, vis, 0.0))
        lengths = lists.lengths
        per_tile = np.repeat(lengths[:, None], TILE * TILE, 1)
        over_map = np.repeat(lists.overflow[:, None], TILE * TILE, 1).astype(np.int64)
    counters = {
        "samples": samples,
        "casters": n_gather,
        "culled_triangles": n_tri - n_gather,
        "tests": int(tests.sum()),
        "tests_per_pixel": to_image(tests),
        "soft_clusters": int(len(gath.clusters)),
        "light_facing_survivors": gath.light_facing,
        "gather_clusters": n_gather_cl,
        "gather_triangles": n_gather,
        "active_tiles": int(active.sum()),
        "tiles": n_tiles,
        "tile_cluster_pairs": int(lists.cluster_pairs),
        "tile_cluster_survivors": int(lists.cluster_survivors),
        "tile_triangle_pairs": int(lists.triangle_pairs),
        "tile_triangles": int(lengths.sum()),
        "tile_triangles_max": int(lengths.max()) if n_tiles else 0,
        "tile_list_lengths": lengths.astype(np.int64),
        "tile_triangles_per_pixel": to_image(per_tile.astype(np.int64)),
        "overflow_tiles": lists.overflow_tiles,
        "overflow_tiles_per_pixel": to_image(over_map),
        "dropped_entries": lists.dropped_entries,
        "rasterized_triangles": int(rast.sum()),
        "rasterized_per_pixel": to_image(rast),
        "near_clamp_per_pixel": to_image(clamped),
        "raster_lanes": raster_lanes,
        "recorded_pairs": recorded,
    }
    return vis_img, counters


def split_culling(opts: dict) -> tuple[CullSettings, dict]:
    """The options of a soft method as (culling settings, the other options)."""
    names = {f.name for f in dataclasses.fields(CullSettings)}
    culling = CullSettings(**{k: v for k, v in opts.items() if k in names})
    return culling, {k: v for k, v in opts.items() if k not in names}


GRID_OPTION = Option("16x16", "bitmask grid: 16x16 (8 words, 208 disk cells) or 31 columns x "
                     "N rows", allowed=sd.GRID_NAMES)
COMMON_SOFT = {
    "disk_scale": Option("tan", "disk-space scale: 'tan' of the angular radius (exact "
                         "silhouette cone) or the paper's 'sin'", allowed=("tan", "sin")),
    "horizon": Option(True, "clear the disk below the receiver's tangent plane (the "
                      "reference counts it as blocked); False = the paper", allowed=(True, False)),
    "face_cull": Option("none", "gather: 'none' keeps every triangle (exact, also for "
                        "two-sided soup); 'front' culls triangles facing all of the light "
                        "(the paper; loses occluders where a grazing receiver's bias skips "
                        "the entry face, and on soup), 'back' the opposite",
                        allowed=("none", "front", "back")),
    "gather_cull": Option(True, "view-frustum culling of cluster and triangle cones",
                          allowed=(True, False)),
    "tile_cull": Option(True, "per-tile cone culling (off: every tile lists every gathered "
                        "triangle)", allowed=(True, False)),
    "cluster_cull": Option(True, "per-tile cluster level before triangles",
                           allowed=(True, False)),
    "cluster_size": Option(64, "triangles per cluster (Morton-sorted runs)",
                           allowed=(16, 32, 64, 128, 256)),
    "bound": Option("capsule", "bounding volume of a tile's samples from its depth range",
                    allowed=("sphere", "capsule")),
    "half_z": Option(False, "split each tile's depth range in two halves with exact bounds",
                     allowed=(True, False)),
    "capacity": Option(2048, "per-tile triangle list capacity (the paper's shared-memory "
                       "list; 2048 x 4 bytes = 8 KiB)", kind=int, minimum=1),
    "on_overflow": Option("full", "a tile whose list overflows (counted and shown either "
                          "way): 'full' evaluates its whole list (exact), 'truncate' only the "
                          "first `capacity` entries (the paper; too bright there)",
                          allowed=("full", "truncate")),
    "chunk": Option(4, "list entries per unrolled loop step", allowed=(1, 2, 4, 8)),
}


#: the paper's own choices where they differ from the (accurate) defaults, shared by
#: both soft methods; docs/soft_tiled.md lists each difference and its cost
PAPER_CULLING = {"face_cull": "front", "on_overflow": "truncate", "disk_scale": "sin",
                 "horizon": False}
PAPER_PRESETS = {"soft_tiled": {"paper": {"projection": "paper", **PAPER_CULLING}},
                 "soft_overlap_sum": {"paper": dict(PAPER_CULLING)}}

#: what both soft methods declare to the registry
SOFT_DECLARATION = {
    "kind": "soft",
    "stages": ("setup", "gather", "gather_test", "tile_bounds", "tile_cull", "tile_lists",
               "eval_setup", "eval", "output", "host"),
    "counters": ("samples", "casters", "culled_triangles", "tests", "tests_per_pixel",
                 "soft_clusters", "light_facing_survivors", "gather_clusters",
                 "gather_triangles", "active_tiles", "tiles", "tile_cluster_pairs",
                 "tile_cluster_survivors", "tile_triangle_pairs", "tile_triangles",
                 "tile_triangles_max", "tile_list_lengths", "tile_triangles_per_pixel",
                 "overflow_tiles", "overflow_tiles_per_pixel", "dropped_entries",
                 "rasterized_triangles", "rasterized_per_pixel", "near_clamp_per_pixel",
                 "raster_lanes", "recorded_pairs")}


@register("soft_tiled", **SOFT_DECLARATION,
          doc="tiled per-triangle soft shadows: sun-disk bitmask rasterizer with cone "
              "culling per 16x16 tile", paper="Kalbertodt 2023",
          presets=PAPER_PRESETS["soft_tiled"],
          options={"grid": GRID_OPTION,
                   "rotate": Option(True, "random grid rotation per pixel (against banding)",
                                    allowed=(True, False)),
                   "seed": Option(0, "seed of the per-pixel rotation hash", kind=int,
                                  minimum=0),
                   "projection": Option("homogeneous", "'homogeneous': exact 3-D edge "
                                        "functions; 'paper': divide by max(1e-4, s |z|) with "
                                        "abs() (wrong where a caster nears the receiver)",
                                        allowed=("homogeneous", "paper")),
                   "defer": Option(True, "rasterize only the pairs passing the per-pixel "
                                   "quick reject (queued per pixel) and stop a pixel whose "
                                   "grid is empty; False = rasterize every visited pair "
                                   "and gate the result (same visibility)",
                                   allowed=(True, False)),
                   "record": Option("exact", "defer: the record pass's test, the "
                                    "per-pixel quick reject ('exact', the paper's), the "
                                    "triangle's bounding sphere against the pixel's light "
                                    "cone ('sphere': cheaper per pair, looser near the "
                                    "receiver; the flush then runs the quick reject on the "
                                    "pairs it pops) or both tests ('both'); same "
                                    "visibility; 'sphere' and 'both' need "
                                    "projection='homogeneous' and defer",
                                    allowed=("exact", "sphere", "both")),
                   "compact": Option(True, "defer: each flush step runs only on the lanes "
                                     "with recorded pairs left (lanes sorted by their pair "
                                     f"count, blocks of {FLUSH_BLOCK} that each run until "
                                     "their own longest lane is done; with the paper's "
                                     "projection the whole batch where the pairs are "
                                     "spread evenly); False = every "
                                     "lane of the batch until the longest is done (same "
                                     "visibility and counters except raster_lanes)",
                                     allowed=(True, False)),
                   **COMMON_SOFT})
def soft_tiled(scene, gbuf, light, **opts):
    culling, rest = split_culling(opts)
    return soft_tiled_impl(scene, gbuf, light, culling=culling, mode="bitmask",
                           method="soft_tiled", **rest)


@register("soft_overlap_sum", **SOFT_DECLARATION,
          doc="naive comparison: sum of analytic disk-triangle overlap areas (double-counts "
              "overlapping occluders)", paper="Kalbertodt 2023",
          presets=PAPER_PRESETS["soft_overlap_sum"],
          options=dict(COMMON_SOFT))
def soft_overlap_sum(scene, gbuf, light, **opts):
    culling, rest = split_culling(opts)
    return soft_tiled_impl(scene, gbuf, light, culling=culling, mode="overlap",
                           method="soft_overlap_sum", grid="16x16", rotate=False, seed=0,
                           projection="paper", **rest)
