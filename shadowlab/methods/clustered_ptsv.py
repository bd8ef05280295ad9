"""``clustered_ptsv``: per-triangle shadow volumes over a view-sample cluster hierarchy.

Sintorn, Kämpe, Olsson, Assarsson 2014. Stages (timed separately):

1. ``build``: post-perspective sample coordinates, cluster keys (eq. 1), child masks
   and explicit boxes (``cluster_hierarchy``).
2. ``setup``: the four world-space shadow-volume planes (the same jitted setup as
   ``brute_force``, so leaf tests are bit-identical to it), their post-perspective
   versions, and the three extra culling planes.
3. ``traverse``: level-synchronous traversal of (triangle, node) jobs in
   fixed-capacity frontiers (power-of-two buckets sized from exact counts, so nothing
   is ever truncated): each job tests its node's 32 children (trivial reject / trivial
   accept / intersect); intersected children form the next frontier; at the leaves
   every view sample of the 8 x 8 tile is tested with the exact world-space test of
   ``brute_force`` (a test-and-set).
4. ``merge``: samples inside a trivially accepted node are shadowed.

Stage 3 runs the generic engine :mod:`shadowlab.engines.traversal` with the node and
leaf tests of this module (:class:`PlaneNodeTests`), over any
:class:`~.cluster_hierarchy.TreeLayout`; ``ptsv`` (the 2011 baseline) runs the same
engine and tests over its 2D tile tree.

Conservative node tests. A node is rejected only if its box is outside a plane by
more than a tolerance covering float rounding of the post-perspective plane
evaluation and of the world-space sample test; it is accepted only if its box is
inside the three edge planes by that tolerance and every sample in it passes the
bias criterion (using the node's minimum bias scale ``smin``). Leaf tests are the
exact per-sample test, so the lit mask equals ``brute_force``'s.

Job order and pruning (order-dependent counts): jobs are the casters in ascending
triangle index; without pruning all jobs traverse in one level-synchronous wave.
With ``prune=True`` casters are processed in waves of ``wave`` jobs in that order;
nodes accepted in a wave are removed from the tree (their bit cleared in the parent's
mask) before the next wave starts, and within a wave before the next level. In the
two-pass mode pass 1 (levels < L) runs over all triangle waves first, then pass 2
runs over the (triangle, node) jobs in the order pass 1 produced them. The result is
deterministic.
"""

from __future__ import annotations

import dataclasses
import functools

import jax
import jax.numpy as jnp
import numpy as np

from ..geometry.caster_culling import CULL_SIDES, without_culled_faces
from ..engines.traversal import child_words, traverse
from ..geometry.morton import decode
from ..scene.view import hard_light
from ..core.timing import StageTimer
from ..structures import cluster_hierarchy as ch
from ..core.capacity import pad
from ..geometry.triangle_setup import shadow_volume_planes as world_setup
from ..core.frame import (
    BIAS_MODES,
    localize,
    bucket,
    caster_terms,
    precision_mode,
    view_samples,
)
from .registry import Option, register
from ..core.result import ShadowResult
from ..geometry.volume_planes import _MARGIN_ULPS, post_perspective_planes
from ..scene.caches import per_scene_cache

TOP_JOBS = 1024
#: per scene: the traversal's frontier buckets that sufficed (``engines.traversal``); a
#: bucket grown for one scene would make every other hold its memory
_BUCKETS = per_scene_cache()
#: per frame-local scene: (key, (casters' scene, face-culled count, planes, valid)) of the
#: latest light set up with ``reuse_setup`` (``scene.caches.drop`` forgets it, as it
#: forgets Embree's BVH)
_SETUPS = per_scene_cache()


# --------------------------------------------------------------------------- setup

# --------------------------------------------------------------------------- traversal

def _explicit_axes(tree: ch.TreeLayout, bounds: str) -> tuple[bool, bool, bool]:
    if tree.kind == "ptsv":
        return (False, False, True)          # 2D tile rectangle, explicit depth range
    return (True, True, True) if bounds == "explicit" else (False, False, False)


def shape_tree(tree: ch.TreeLayout) -> ch.TreeLayout:
    """``tree`` without its camera-dependent floats: the static key of compiled kernels
    (frames and scenes at one resolution share them; the floats are passed as data)."""
    return dataclasses.replace(tree, near=0.0, far=0.0, log_ratio=0.0, p00=0.0, p11=0.0,
                               saturates=False)


def tree_params(tree: ch.TreeLayout, dtype) -> np.ndarray:
    """The camera-dependent floats of ``tree`` in the working dtype (what a Python float
    static becomes when it meets a ``dtype`` array, so results are bit-identical)."""
    return np.array([tree.near, tree.log_ratio, tree.p00, tree.p11], dtype)


def _with_params(shape: ch.TreeLayout, params) -> ch.TreeLayout:
    return dataclasses.replace(shape, near=params[0], log_ratio=params[1], p00=params[2],
                               p11=params[3])


def _tile_of(tree: ch.TreeLayout, leaf):
    coords = decode(leaf, tree.layout, len(tree.bits), xp=jnp)
    return coords[1].astype(jnp.int32) * tree.tiles_x + coords[0].astype(jnp.int32)


@functools.partial(jax.jit, static_argnames=("shape", "axes", "level"))
def _node_boxes(shape: ch.TreeLayout, axes: tuple, level: int, params, keys, lo, hi):
    """The boxes the node test reads for the level-``level`` entries: lo, hi [capacity, 3]
    with each implicit axis (``axes[k]`` False) replaced by :func:`~.cluster_hierarchy.
    implicit_bounds` of the entry's key (uint32 [capacity]; padding rows give boxes that
    are never read). Done once per frame for the existing nodes instead of once per
    tested child: decoding a child's key into its tile and slice range cost about 70 %
    of PTSV's node test (9.5 against 2.7 ns per child on fuzzy 100k, 1024x1024). The
    same expressions on the same keys, so the bits are those the test computed itself."""
    ilo, ihi = ch.implicit_bounds(_with_params(shape, params), level, keys, lo.dtype)
    ax = jnp.asarray(axes)
    return jnp.where(ax, lo, ilo), jnp.where(ax, hi, ihi)


def node_boxes(hier: ch.Hierarchy, shape: ch.TreeLayout, params, axes: tuple) -> tuple:
    """Per level 1..D, the (lo, hi) boxes of :func:`_node_boxes`: the hierarchy's explicit
    boxes where every axis is explicit, else merged with the implicit ones."""
    if all(axes):
        return tuple(zip(hier.lo, hier.hi))
    out = []
    for level, (lo, hi) in enumerate(zip(hier.lo, hier.hi), start=1):
        keys = (jnp.arange(lo.shape[0], dtype=jnp.uint32) if hier.keys is None
                else hier.keys[level - 1])
        out.append(_node_boxes(shape, axes, level, params, keys, lo, hi))
    return tuple(out)


def _test_children(cfg, level, a, tri, node, valid, accepted):
    """Classify the 32 children of every frontier job at ``level`` (a traced int: one
    body serves every level; per-level arrays are concatenated, ``a["off"]`` holds the
    offsets). Algorithm 1, lines 10-19, for all jobs at once. The boxes ``a["lo"]``,
    ``a["hi"]`` hold every axis, explicit or implicit (:func:`node_boxes`). Returns bool
    [N, 32] (exists, accept, reject, extra_reject, intersect)."""
    storage, extra, prune = cfg["storage"], cfg["extra"], cfg["prune"]
    g, tol, bound, off = a["g"], a["tol"], a["bound"], a["off"]
    dtype = g.dtype
    u = jnp.finfo(dtype).eps
    node_i = node.astype(jnp.int32)
    word = a["masks"][off["masks"][level] + node_i]
    c = jnp.arange(32, dtype=jnp.uint32)
    exists = (((word[:, None] >> c[None, :]) & jnp.uint32(1)) == 1) & valid[:, None]
    if prune:                                  # accepted children are cleared from the mask
        exists &= ~accepted[off["masks"][level] + node_i]
    if storage == "full":                      # the child's key
        idx = off["boxes"][level] + ((node[:, None] << 5) | c[None, :]).astype(jnp.int32)
    else:                       # compact: the parent's start plus the set bits below c
        below = word[:, None] & ((jnp.uint32(1) << c[None, :]) - jnp.uint32(1))
        rank = jax.lax.population_count(below).astype(jnp.int32)
        idx = off["boxes"][level] + jnp.where(
            exists, a["start"][off["masks"][level] + node_i][:, None] + rank, 0)
    blo, bhi, sm = a["lo"][idx], a["hi"][idx], a["smin"][idx]
    # plane r at the box: the extreme corners per axis; written per row on [N, 32]
    # arrays (minor axes of size 3 or 7 vectorize poorly). Summed as (x + q) + y, then the
    # constant: the order XLA's size-3 reduction used in the first version, kept so the
    # float32 counters are unchanged (the float64 loop in the tests sums x, y, q)
    gt = g[tri]                                            # [N, 7, 4]
    tt = tol[tri]                                          # [N, 7]
    lx, ly, lq = blo[..., 0], blo[..., 1], blo[..., 2]     # [N, 32]
    hx, hy, hq = bhi[..., 0], bhi[..., 1], bhi[..., 2]

    def extremes(r):
        g0, g1, g2, g3 = (gt[:, r, k][:, None] for k in range(4))
        ax, bx = g0 * lx, g0 * hx
        ay, by = g1 * ly, g1 * hy
        aq, bq = g2 * lq, g2 * hq
        vmax = (jnp.maximum(ax, bx) + jnp.maximum(aq, bq)) + jnp.maximum(ay, by) + g3
        vmin = (jnp.minimum(ax, bx) + jnp.minimum(aq, bq)) + jnp.minimum(ay, by) + g3
        return vmax, vmin

    rej_edge = jnp.zeros(lx.shape, bool)
    acc_edge = jnp.ones(lx.shape, bool)
    for r in range(3):
        vmax, vmin = extremes(r)
        t = tt[:, r][:, None]
        rej_edge |= vmax < -t
        acc_edge &= vmin >= t
    vmax, vmin = extremes(3)
    cmax = vmax + tt[:, 3][:, None]
    cmin = vmin - tt[:, 3][:, None]
    pos_scale = sm > 0
    rej_cap = pos_scale & (cmin > 0)
    lim = bound[tri][:, None]
    if cfg["bias_reject"]:
        # every sample's world cap value is >= cmin / q >= cmin / q_lo (cmin <= 0 here), so
        # with scale <= smax (all samples) its biased value is >= (cmin / q_lo) smax
        lq = blo[..., 2]
        rej_cap |= pos_scale & (lq > 0) & (
            (cmin / lq) * a["smax"] * (1 + _MARGIN_ULPS * u) > lim * (1 - _MARGIN_ULPS * u))
    acc_cap = pos_scale & (cmax < 0) & (
        (cmax / hq) * sm * (1 - _MARGIN_ULPS * u) < lim * (1 + _MARGIN_ULPS * u))
    basic_reject = rej_edge | rej_cap
    accept = exists & ~basic_reject & acc_edge & acc_cap
    if extra:
        rej_x = jnp.zeros(lx.shape, bool)
        for r in range(4, 7):
            rej_x |= extremes(r)[0] < -tt[:, r][:, None]
        extra_reject = exists & ~basic_reject & ~accept & rej_x
    else:
        extra_reject = jnp.zeros_like(accept)
    intersect = exists & ~basic_reject & ~accept & ~extra_reject
    return exists, accept, basic_reject, extra_reject, intersect


def _leaf_chunk(cfg, a, tri, leaf, ok, tile_shadow, tile_tests):
    """Test-and-set of leaf jobs (tri, leaf) [C]: every sample of the leaf's tile (or of
    its cluster), with the exact world-space test of ``brute_force``; the tile's samples
    are gathered once per job (tile-major arrays) and OR-reduced per sample by a row
    scatter-max into [tiles, P]."""
    tile = _tile_of(cfg["tree"], leaf)
    x, y, z = a["tile_x"][tile], a["tile_y"][tile], a["tile_z"][tile]   # [C, P]
    m = a["tile_valid"][tile] & ok[:, None]
    if cfg["cluster_only"]:
        m &= a["tile_key"][tile] == leaf[:, None]
    pl = a["planes"][tri]
    e0 = x * pl[:, 0:1] + y * pl[:, 1:2] + z * pl[:, 2:3] + pl[:, 3:4]
    e1 = x * pl[:, 4:5] + y * pl[:, 5:6] + z * pl[:, 6:7] + pl[:, 7:8]
    e2 = x * pl[:, 8:9] + y * pl[:, 9:10] + z * pl[:, 10:11] + pl[:, 11:12]
    cap = x * pl[:, 12:13] + y * pl[:, 13:14] + z * pl[:, 14:15] + pl[:, 15:16]
    inside = (e0 >= 0) & (e1 >= 0) & (e2 >= 0) & (
        cap * a["tile_scale"][tile] < a["bound"][tri][:, None])
    tile_shadow = tile_shadow.at[tile].max(inside & m)
    tile_tests = tile_tests.at[tile].add(m.astype(jnp.int32))
    return tile_shadow, tile_tests


# smallest triangle / sample buckets: small scenes and images share compiled kernels
MIN_TRIANGLES = 2048
MIN_SAMPLES = 4096
# the traversal's first frontier bucket, in entries per job (``frontier_per_job``): the
# peak frontier of a default frame measured 3.5-12x its jobs for the cluster tree and
# 6.4-23x for PTSV's tile tree on the procedural scenes at 256x256, 2.8-4.2x and 6.1-8.6x
# on sphere_grid at 99k and 1M triangles at 1024x1024 (docs/clustered_ptsv.md)
FRONTIER_PER_JOB = {"cluster": 4, "ptsv": 8}


@dataclasses.dataclass(frozen=True)
class PlaneNodeTests:
    """The shadow-volume node and leaf tests, as :class:`~shadowlab.engines.traversal.
    NodeTests` for the traversal engine: items are triangles, nodes the hierarchy's keys,
    ``data`` the dict of :func:`flat_hierarchy` plus the planes, tolerances, bounds and
    tile-major samples (see ``run_traversal_method``). The leaf state is (tile_shadow
    bool [tiles, P], tile_tests int32 [tiles, P])."""

    shape: ch.TreeLayout
    storage: str
    extra: bool
    prune: bool
    cluster_only: bool
    bias_reject: bool
    # a bucket prior only (FRONTIER_PER_JOB): the same kernels whatever its value
    frontier_per_job: int = dataclasses.field(compare=False)

    counters = ("node_tests", "trivial_accepts", "trivial_rejects", "extra_plane_rejects")

    @property
    def levels(self) -> int:
        return self.shape.levels

    def prepare(self, data):
        cfg = dict(tree=self.shape, storage=self.storage, extra=self.extra, prune=self.prune,
                   cluster_only=self.cluster_only, bias_reject=self.bias_reject)
        return cfg, data

    def children(self, ctx, level, tri, node, valid, accepted):
        cfg, a = ctx
        exists, accept, basic, extra_rej, inter = _test_children(cfg, level, a, tri, node,
                                                                 valid, accepted)
        words = child_words(exists, accept, exists & (basic | extra_rej), extra_rej, inter)
        counts = jnp.stack([jnp.sum(jax.lax.population_count(w), dtype=jnp.int32)
                            for w in words[:4]])
        return words[1], words[4], counts

    def leaves(self, ctx, tri, leaf, ok, state):
        cfg, a = ctx
        return _leaf_chunk(cfg, a, tri, leaf, ok, *state)


def level_offsets(tree: ch.TreeLayout) -> tuple[list[int], int]:
    """First row of each mask level 0..D-1 in the concatenated masks (and in the
    accepted-children array, a row of 32 per inner node), and the total rows."""
    rows, total = [], 0
    for level in range(tree.levels):
        rows.append(total)
        total += tree.nodes(level)
    return rows, total


def flat_hierarchy(hier: ch.Hierarchy, boxes: tuple) -> dict:
    """The hierarchy, with the node test's ``boxes`` (per level 1..D (lo, hi), see
    :func:`node_boxes`), as concatenated arrays plus per-level offset tables, so one loop
    body can serve every level (``off``: masks / accepted rows, start counts and boxes of
    the child level)."""
    rows, _ = level_offsets(hier.tree)
    box_off, b = [], 0
    for lo, _ in boxes:
        box_off.append(b)
        b += lo.shape[0]
    off = dict(masks=jnp.asarray(rows, jnp.int32), boxes=jnp.asarray(box_off, jnp.int32))
    return dict(masks=jnp.concatenate(hier.masks),
                start=None if hier.start is None else jnp.concatenate(hier.start),
                lo=jnp.concatenate([lo for lo, _ in boxes]),
                hi=jnp.concatenate([hi for _, hi in boxes]),
                smin=jnp.concatenate(hier.smin), off=off)


@functools.partial(jax.jit, static_argnames=("shape",))
def _finish(shape, keys, valid, slot, accepted, tile_shadow, tile_tests):
    """Per sample: shadowed by a leaf test or inside a trivially accepted node (merge),
    trivially-accepted-only, and test-and-sets. ``accepted`` is bool [rows, 32] (a row
    per inner node of every level, see :func:`level_offsets`)."""
    ta = jnp.zeros(keys.shape, bool)
    flat = accepted.reshape(-1)
    rows = level_offsets(shape)[0]
    for level in range(1, shape.levels + 1):
        ta |= flat[32 * rows[level - 1] + (keys >> shape.shift(level)).astype(jnp.int32)]
    ta &= valid
    leaf = tile_shadow.reshape(-1)[slot] & valid
    tests = jnp.where(valid, tile_tests.reshape(-1)[slot], 0)
    return leaf | ta, ta & ~leaf, tests


# --------------------------------------------------------------------------- pipeline

@functools.partial(jax.jit, static_argnames=("shape",))
def _sample_stage(shape, params, pos, scale, view, index, count):
    """Per sample (all [S], S the sample capacity; rows >= count are padding): coordinates
    [S, 3], keys (uint32), saturated, valid, and its slot in the tile-major arrays; the
    tile-major copies of the samples (x, y, z, bias scale, key, valid: [tiles, P] each, P
    pixels per leaf tile), so a leaf job gathers its tile's samples as rows; and the
    largest q and |world coordinate| of the samples (the tolerances' qmax and pmax, 1 if
    there is no sample). ``index``: int32 [S] flat pixel index."""
    tree = _with_params(shape, params)
    s = pos.shape[0]
    valid = jnp.arange(s) < count
    px, py = index % tree.width, index // tree.width
    coords = ch.sample_coords(tree, pos, view)
    coords = jnp.where(valid[:, None], coords, coords[0])
    keys, saturated = ch.sample_keys(tree, px, py, coords)
    slot, table = ch.tile_slots(tree, px, py, valid)
    sc = jnp.minimum(table, s - 1)
    p = pos[sc]
    tile_arrays = dict(tile_x=p[..., 0], tile_y=p[..., 1], tile_z=p[..., 2],
                       tile_scale=scale[sc], tile_key=keys[sc], tile_valid=table < s)
    # max |x| of the rounded positions = the rounded max |x| (rounding is monotonic)
    qmax = jnp.where(count > 0, jnp.max(jnp.where(valid, coords[:, 2], 0)), 1)
    smax = jnp.max(jnp.where(valid, scale, 0))
    pmax = jnp.where(count > 0, jnp.max(jnp.abs(pos)), 1)
    return dict(coords=coords, keys=keys, saturated=saturated & valid, valid=valid, slot=slot,
                table=table, tiles=tile_arrays, qmax=qmax.astype(pos.dtype),
                pmax=pmax.astype(pos.dtype), smax=smax)


def top_jobs(iterations: np.ndarray, k: int = TOP_JOBS) -> np.ndarray:
    """int64 [k]: the k largest per-job iteration counts, descending, zero-padded."""
    out = np.zeros(k, np.int64)
    x = np.asarray(iterations, np.int64)
    if len(x) > k:                      # the k largest by selection, not a whole sort
        x = np.partition(x, len(x) - k)[len(x) - k:]
    top = np.sort(x)[::-1]
    out[: len(top)] = top
    return out


def run_traversal_method(scene, gbuf, light, *, kind: str, precision: str, shadow_eps: float,
                         bias: str, bounds: str = "explicit", storage: str = "compact",
                         culling_planes: bool = True, passes: int = 1, expand_level: int = 3,
                         prune: bool = False, wave: int = 512, front_face_culling: bool = True,
                         cull_side: str = "averted", bias_reject: bool = False,
                         leaf_samples: str = "tile", z_bits: int = 0,
                         depth_slices: str = "clamp", tree_samples: str = "facing",
                         plane_set: str = "own", reuse_setup: bool = False,
                         method: str = "clustered_ptsv", options: dict | None = None):
    """The whole pipeline for ``kind`` = "cluster" (2014) or "ptsv" (2011).

    Returns:
        (ShadowResult, details) where details holds the full per-job iteration arrays
        ``iterations_pass1`` [casters] (in caster order), ``iterations_pass2`` [jobs],
        ``pass2_triangles`` / ``pass2_nodes`` [jobs], ``casters`` [C] triangle ids (of
        ``details["scene"]``: the frame-local scene, or its subset without the
        face-culled triangles),
        the ``tree`` layout, the ``memory`` report, and the arrays the traversal used
        (``hierarchy``, ``g``, ``tol``, ``bound``, ``planes``, ``scale``, ``keys``,
        ``table``, per-sample ``tests``) for analysis and tests.
    """
    timer = StageTimer()
    # frame-local inputs (a no-op when compute_shadows has localized them already)
    local = localize(scene, gbuf, light)
    scene, gbuf, light = local.scene, local.gbuf, local.light
    with timer.stage("samples"):
        samples = view_samples(gbuf, light)
        facing = None                       # tree_samples="facing": every sample faces
        if tree_samples == "all":
            samples, facing = _all_valid_samples(gbuf, samples)
    camera = gbuf.camera
    light_h = hard_light(light).homogeneous
    all_triangles = scene.num_triangles
    # capacity buckets learnt per frame-local scene (a moving light gives a new subset
    # every frame, so not per subset)
    buckets = _BUCKETS.setdefault(scene, {})
    with precision_mode(precision) as dtype:
        tree = (ch.cluster_layout(camera, z_bits, depth_slices) if kind == "cluster"
                else ch.ptsv_layout(camera))
        key = (light_h.astype(np.float64).tobytes(), np.dtype(dtype).str,
               bool(front_face_culling), cull_side)
        held = _SETUPS.get(scene) if reuse_setup else None
        if held is not None and held[0] == key:
            scene, face_culled, planes, valid = held[1]
        else:
            held_by, face_culled = scene, 0
            if front_face_culling:
                # dropped before the triangle setup: the setup and the post-perspective
                # planes cover the kept triangles only; the casters keep their order
                with timer.stage("setup"):
                    scene, face_culled = without_culled_faces(scene, light_h, cull_side)
            tri = pad(scene.triangles, bucket(scene.num_triangles, minimum=MIN_TRIANGLES),
                      dtype=dtype)
            planes, valid = timer.run("setup", world_setup, jnp.asarray(tri),
                                      jnp.asarray(light_h.astype(dtype)))
            if reuse_setup:
                _SETUPS[held_by] = (key, (scene, face_culled, planes, valid))
        with timer.stage("setup"):
            valid, _, scale, bound = caster_terms(scene, samples, light_h, planes, valid,
                                                  shadow_eps, bias, dtype)
            casters = np.flatnonzero(valid).astype(np.int32)
            s_cap = bucket(samples.count, minimum=MIN_SAMPLES)
            pos = jnp.asarray(samples.padded_position(dtype, s_cap))
            scale_d = jnp.asarray(samples.padded(scale, dtype, s_cap))
        shape = shape_tree(tree)
        params = jnp.asarray(tree_params(tree, dtype))
        axes = _explicit_axes(tree, bounds)
        with timer.stage("build"):
            index = np.zeros(s_cap, np.int32)
            index[: samples.count] = samples.index
            view = jnp.asarray(camera.view_matrix().astype(dtype))
            sst = _sample_stage(shape, params, pos, scale_d, view, jnp.asarray(index),
                                samples.count)
            coords, keys, svalid = sst["coords"], sst["keys"], sst["valid"]
            tiles, table, slot = sst["tiles"], sst["table"], sst["slot"]
            hier = dataclasses.replace(ch.build(shape, keys, svalid, coords, scale_d, storage,
                                                tile_keys=tiles["tile_key"],
                                                tile_valid=tiles["tile_valid"]), tree=tree)
            boxes = node_boxes(hier, shape, params, axes)
            jax.block_until_ready((boxes, tiles))
        with timer.stage("setup"):
            own = "silhouette" if kind == "ptsv" else "culling"
            extra = (own if plane_set == "own" else PLANE_SETS[plane_set]) \
                if culling_planes else "none"
            inv_view = jnp.asarray(np.linalg.inv(camera.view_matrix()).astype(dtype))
            g, tol = post_perspective_planes(planes, inv_view, sst["qmax"],
                                             sst["pmax"], extra=extra, p00=tree.p00,
                                             p11=tree.p11)
            jax.block_until_ready(g)
        levels = tree.levels
        level_l = min(max(1, expand_level), levels)
        with timer.stage("traverse"):
            arrays = dict(flat_hierarchy(hier, boxes), g=g, tol=tol,
                          bound=jnp.asarray(bound), planes=planes, smax=sst["smax"], **tiles)
            accepted = jnp.zeros((level_offsets(tree)[1], 32), bool)
            p_tiles = tree.tiles_x * tree.tiles_y
            tests_spec = PlaneNodeTests(shape, storage, extra != "none", bool(prune),
                                        leaf_samples == "cluster", bool(bias_reject),
                                        FRONTIER_PER_JOB[kind])
            run = traverse(tests_spec, arrays, arrays["off"]["masks"], casters,
                           accepted, (jnp.zeros((p_tiles, tree.tile_pixels), bool),
                                      jnp.zeros((p_tiles, tree.tile_pixels), jnp.int32)),
                           passes=passes, expand_level=level_l,
                           wave=wave if prune else None, prune=bool(prune),
                           buckets=buckets, timer=timer)
            tile_shadow, tile_tests = run.leaf_state
            jax.block_until_ready(tile_shadow)
        iters1, iters2 = run.iterations_pass1, run.iterations_pass2
        with timer.stage("merge"):
            shadow_d, ta_d, tests_d = _finish(shape, keys, svalid, slot, run.accepted,
                                              tile_shadow, tile_tests)
            shadow_all = np.asarray(shadow_d)[: samples.count]
            ta_only = np.asarray(ta_d)[: samples.count]
            tests = np.asarray(tests_d)[: samples.count].astype(np.int64)
    lit = samples.scatter(~shadow_all if facing is None else ~shadow_all & facing,
                          fill=False)
    job_iters = np.concatenate([iters1, iters2]) if passes == 2 else iters1
    counts_h = [int(c) for c in jax.device_get(hier.counts)]
    memory = ch.memory_report(tree, existing=sum(counts_h))
    counters = {
        "samples": samples.count,
        "casters": int(len(casters)),
        "culled_triangles": all_triangles - int(len(casters)),
        "front_face_culled": face_culled,
        "tests": int(tests.sum()),
        "tests_per_pixel": samples.scatter(tests, fill=0),
        **{name: int(c) for name, c in zip(PlaneNodeTests.counters, run.counts)},
        "leaf_visits": int(run.leaf_visits),
        "ta_shadowed": int(ta_only.sum()),
        "jobs": int(len(job_iters)),
        "pass2_jobs": int(len(iters2)),
        "job_iterations_mean": float(job_iters.mean()) if len(job_iters) else 0.0,
        "job_iterations_max": int(job_iters.max()) if len(job_iters) else 0,
        "job_iterations_top": top_jobs(job_iters),
        "frontier_max": int(run.frontier_max),
        "clusters": counts_h[-1],
        "hierarchy_nodes": sum(counts_h),
        "hierarchy_bytes": int(memory["mask_bytes"] + (
            memory["pointer_bytes"] + 24 * sum(counts_h) if storage == "compact"
            else memory["full_bounds_bytes"])),
        "saturated_samples": int(np.asarray(sst["saturated"]).sum()),
        "shadowed": int(shadow_all.sum()),
        "lit": int(lit.sum()),
    }
    timings = dict(timer.times, total=timer.total)
    details = {"iterations_pass1": iters1, "iterations_pass2": iters2,
               "pass2_triangles": run.pass2_items, "pass2_nodes": run.pass2_nodes,
               "casters": casters, "scene": scene,
               "tree": tree, "memory": memory, "hierarchy": hier, "g": g, "tol": tol,
               "bound": bound, "planes": planes, "scale": scale_d, "keys": keys,
               "table": table, "axes": axes, "extra": extra, "smax": sst["smax"],
               "bias_reject": bool(bias_reject),
               "tests": tests, "sample_count": samples.count}
    return ShadowResult(lit, counters, timings), details


def _all_valid_samples(gbuf, facing_samples):
    """Every valid pixel as a sample (the 2011 build over the full depth buffer), and
    bool [S] whether it faces the light (the others are unlit whatever the traversal
    finds). Built like :func:`view_samples` from the G-buffer, without its light test."""
    idx = np.flatnonzero(gbuf.valid)
    facing = np.zeros(gbuf.valid.size, bool)
    facing[facing_samples.index] = True
    samples = dataclasses.replace(facing_samples, index=idx,
                                  position=gbuf.position.reshape(-1, 3)[idx],
                                  normal=gbuf.normal.reshape(-1, 3)[idx])
    return samples, facing[idx]


#: The papers' own configuration (Sintorn et al. 2014, Fig. 6 and Algorithm 1; Sintorn
#: et al. 2011): light front-face culling of the triangles facing the light, the bias
#: behind the caster's plane, and trivially accepted nodes removed from the tree. For
#: ``ptsv`` the paper comparisons also build the tile tree over the full depth buffer
#: (every valid pixel, ``tree_samples="all"``). The defaults stay the exact
#: configuration; differences and costs: docs/clustered_ptsv.md ("The papers'
#: configuration"). They are registered as each method's ``preset="paper"``.
PAPER_OPTIONS = {
    "clustered_ptsv": {"front_face_culling": True, "cull_side": "facing", "bias": "cap",
                       "prune": True},
    "ptsv": {"front_face_culling": True, "cull_side": "facing", "bias": "cap",
             "prune": True, "tree_samples": "all"},
}


#: option ``plane_set`` -> the extra rows of ``post_perspective_planes``
PLANE_SETS = {"per_vertex": "culling", "silhouette": "silhouette"}

BOOL = (True, False)
COMMON_TRAVERSAL_OPTIONS = {
    "bias": Option("receiver", "self-shadowing bias: 'receiver' (as the reference) or 'cap' "
                   "(eps behind the caster's plane, as the papers)", allowed=BIAS_MODES),
    "culling_planes": Option(True, "extra culling planes (2014: three per-vertex half-vector "
                             "planes; ptsv: the 2D silhouette edges)", allowed=BOOL),
    "passes": Option(1, "1: one job per triangle; 2: expand to expand_level, then finish the "
                     "(triangle, node) jobs", allowed=(1, 2)),
    "expand_level": Option(3, "tree level L where pass 1 stops (clamped to 1..D)", kind=int,
                           minimum=1),
    "prune": Option(False, "clear trivially accepted nodes from the tree (counts then depend "
                    "on the documented job order)", allowed=BOOL),
    "wave": Option(512, "jobs per wave when pruning (accepts of earlier waves are visible to "
                   "later ones)", kind=int, minimum=1),
    "front_face_culling": Option(True, "drop one side of closed objects' triangles (which: "
                                 "cull_side; with the default 'averted' side the lit mask is "
                                 "the same as without, in about half the work on closed "
                                 "scenes)", allowed=BOOL),
    "cull_side": Option("averted", "with front_face_culling: drop the triangles facing away "
                        "from the light ('averted': exact with the bias) or facing it "
                        "('facing': the papers' choice; loses shadows where a receiver is "
                        "within the bias below a closed object)", allowed=CULL_SIDES),
    "bias_reject": Option(False, "also reject nodes whose samples all lie in front of the "
                          "caster's cap within the bias (not in the papers; needs the largest "
                          "bias scale of all samples; cuts a receiver's traversal of its own "
                          "surface)", allowed=BOOL),
    "leaf_samples": Option("tile", "at a leaf test every sample of the tile (paper) or only "
                           "the samples of that cluster", allowed=("tile", "cluster")),
    "plane_set": Option("own", "which extra culling planes: the method's own ('own': 2014 "
                        "per-vertex planes for clustered_ptsv, 2D silhouette edges for ptsv), "
                        "or either set on either tree for a head-to-head comparison",
                        allowed=("own", "per_vertex", "silhouette")),
    "tree_samples": Option("facing", "samples the tree is built over and tested at the "
                           "leaves: the valid light-facing ones ('facing', tighter bounds) or "
                           "every valid pixel ('all': the 2011 full depth buffer; the others "
                           "stay unlit)", allowed=("facing", "all")),
    "reuse_setup": Option(False, "keep the light's triangle setup (face culling and every "
                          "caster's world-space shadow-volume planes) for the next call with "
                          "the same scene, light, precision and culling (a static light and "
                          "geometry: it depends on neither camera nor samples; 64 bytes per "
                          "caster); off: every call sets up, as the papers time a frame",
                          allowed=BOOL),
}


#: what clustered_ptsv and ptsv declare to the registry
TRAVERSAL_DECLARATION = {
    "kind": "exact", "stages": ("samples", "setup", "build", "traverse", "merge"),
    "static_options": {"reuse_setup": True},
    "counters": ("samples", "casters", "culled_triangles", "front_face_culled", "tests",
                 "tests_per_pixel", "node_tests", "trivial_accepts", "trivial_rejects",
                 "extra_plane_rejects", "leaf_visits", "ta_shadowed", "jobs", "pass2_jobs",
                 "job_iterations_mean", "job_iterations_max", "job_iterations_top",
                 "frontier_max", "clusters", "hierarchy_nodes", "hierarchy_bytes",
                 "saturated_samples", "shadowed", "lit")}


@register("clustered_ptsv",
          doc="per-triangle shadow volumes over a view-sample cluster hierarchy",
          paper="Sintorn et al. 2014", **TRAVERSAL_DECLARATION,
          presets={"paper": PAPER_OPTIONS["clustered_ptsv"]},
          options={**COMMON_TRAVERSAL_OPTIONS,
                   "bounds": Option("explicit", "node boxes implicit from keys or explicit "
                                    "(min/max of the node's samples)",
                                    allowed=("implicit", "explicit")),
                   "storage": Option("compact", "explicit box storage: full tree or pointers "
                                     "+ compact list", allowed=("full", "compact")),
                   "z_bits": Option(0, "depth-slice bits of the key (0: auto, 9 at 1024^2; "
                                    "the whole key has at most 30 bits)",
                                    kind=int, minimum=0, maximum=30),
                   "depth_slices": Option("clamp", "eq. (1) slices with an open-ended top "
                                          "slice, or 'scaled' so [near, far] fits",
                                          allowed=ch.DEPTH_SLICE_MODES)})
def clustered_ptsv(scene, gbuf, light, **opts):
    result, _ = run_traversal_method(scene, gbuf, light, kind="cluster",
                                     method="clustered_ptsv", options=opts, **opts)
    return result
