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

The traversal engine here is generic over :class:`~.cluster_hierarchy.TreeLayout`;
``ptsv`` (the 2011 baseline) runs the same engine over its 2D tile tree.

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

import functools

import jax
import jax.numpy as jnp
import numpy as np

from ..scene.view import hard_light
from ..timing import StageTimer
from . import cluster_hierarchy as ch
from .brute_force import setup as world_setup
from .common import BIAS_MODES, bias_terms, bucket, cap_bias, precision_mode, view_samples
from .registry import Option, register
from .result import ShadowResult

TOP_JOBS = 1024
_ADJACENT = ((0, 2), (0, 1), (1, 2))     # edge planes meeting at vertex 0, 1, 2
_MARGIN_ULPS = 64


# --------------------------------------------------------------------------- setup

@functools.partial(jax.jit, static_argnames=("extra", "p00", "p11"))
def post_perspective_planes(planes, inv_view, qmax, pmax, *, extra: str, p00: float,
                            p11: float):
    """Planes in (nx, ny, q, 1) space and their rounding tolerances.

    A world plane W (row vector) becomes the view-space plane W' = W inv(V); for a
    point with view coordinates (x, y, -w), NDC nx = p00 x / w, ny = p11 y / w and
    q = 1 / w:  W . p / w = (W'0 / p00) nx + (W'1 / p11) ny + W'3 q - W'2.  The sign
    is that of the world test (w > 0), and the form is affine in (nx, ny, q), so box
    corners give exact extremes.

    Extra rows (``extra``):
      - "culling" (2014): per vertex, the sum of its two adjacent edge-plane
        equations: the plane through the vertex and the light whose normal is the half
        vector of the two (unit) normals. Any point inside both planes is inside it,
        so it never rejects a shadowed point. Skipped (a never-rejecting row) when the
        normals nearly cancel (|n_a + n_b| < 1e-3: degenerate or edge-on wedges).
      - "silhouette" (2011 PTSV's 2D silhouette edges): per vertex whose two edge
        planes see the eye on opposite sides, the non-negative combination
        |E_b(eye)| E_a + |E_a(eye)| E_b, the plane through the eye and the light-vertex
        line: a 2D line on screen bounding the volume's projection.
      - "none".

    Args:
        planes: [T, 4, 4] world planes (rows: 3 edge planes, cap), working dtype.
        inv_view: [4, 4] view -> world matrix. qmax: max sample q (1 / world units).
        pmax: max |coordinate| of any sample (world units).

    Returns:
        g: [T, 7, 4] rows 0-2 edges, 3 cap, 4-6 extra. tol: [T, 7] tolerances
        (values in units of world distance / w).
    """
    dtype = planes.dtype
    u = jnp.finfo(dtype).eps
    wv = planes @ inv_view
    g = jnp.stack([wv[..., 0] / p00, wv[..., 1] / p11, wv[..., 3], -wv[..., 2]], axis=-1)
    slack = 4 * u * (jnp.sum(jnp.abs(planes[..., :3]), -1) * pmax
                     + jnp.abs(planes[..., 3])) * qmax                      # [T, 4]
    never = jnp.zeros_like(g[:, 0]).at[:, 3].set(1)
    rows, rslack = [], []
    for a, b in _ADJACENT:
        if extra == "culling":
            n = planes[:, a, :3] + planes[:, b, :3]
            ok = jnp.linalg.norm(n, axis=-1) > 1e-3
            row = g[:, a] + g[:, b]
            sl = slack[:, a] + slack[:, b]
        elif extra == "silhouette":
            ea, eb = wv[:, a, 3], wv[:, b, 3]
            ok = ea * eb < 0
            row = jnp.abs(eb)[:, None] * g[:, a] + jnp.abs(ea)[:, None] * g[:, b]
            sl = jnp.abs(eb) * slack[:, a] + jnp.abs(ea) * slack[:, b]
        else:
            ok = jnp.zeros(g.shape[0], bool)
            row, sl = never, jnp.zeros_like(slack[:, 0])
        rows.append(jnp.where(ok[:, None], row, never))
        rslack.append(jnp.where(ok, sl, 0))
    g = jnp.concatenate([g, jnp.stack(rows, axis=1)], axis=1)
    slack = jnp.concatenate([slack, jnp.stack(rslack, axis=1)], axis=1)
    mag = (jnp.abs(g[..., 0]) + jnp.abs(g[..., 1]) + jnp.abs(g[..., 2]) * qmax
           + jnp.abs(g[..., 3]))
    return g, (_MARGIN_ULPS * u * mag + slack).astype(dtype)


def front_face_culled(scene, light_h: np.ndarray) -> np.ndarray:
    """bool [T]: triangles of closed objects whose outward side faces the light.

    For a closed, consistently oriented object every blocked segment from a point
    outside it to the light leaves it through a triangle facing away from the light,
    so those suffice. The outward side is found from the sign of the object's signed
    volume; open objects keep all their triangles (culling them would lose shadows).
    """
    report = scene.report()
    closed = np.array([o.closed for o in report.objects] +
                      [False] * (scene.num_objects - len(report.objects)))
    tri = scene.triangles
    v0, v1, v2 = tri[:, 0], tri[:, 1], tri[:, 2]
    n = np.cross(v1 - v0, v2 - v0)
    vol6 = np.einsum("ij,ij->i", v0, np.cross(v1, v2))
    orient = np.sign(np.bincount(scene.object_id, weights=vol6, minlength=scene.num_objects))
    orient = np.where(orient == 0, 1.0, orient)
    facing = np.einsum("ij,ij->i", n, light_h[:3] - light_h[3] * v0) * orient[scene.object_id]
    return closed[scene.object_id] & (facing > 0)


# --------------------------------------------------------------------------- traversal

def _explicit_axes(tree: ch.TreeLayout, bounds: str) -> tuple[bool, bool, bool]:
    if tree.kind == "ptsv":
        return (False, False, True)          # 2D tile rectangle, explicit depth range
    return (True, True, True) if bounds == "explicit" else (False, False, False)


@functools.partial(jax.jit, static_argnames=("tree", "level", "axes", "storage", "extra"))
def _expand(tree, level, axes, storage, extra, n, tri, node, job, mask, ptr, lo, hi, smin,
            g, tol, bound, accepted, iters):
    """Test the 32 children of every frontier job at ``level``.

    Args:
        n: valid frontier entries; tri, node, job: [N] int32 / uint32 / int32.
        mask: uint32 [nodes(level)] child masks (pruned if pruning).
        ptr, lo, hi, smin: level + 1 storage (ptr None for "full").
        g, tol: [T, 7, 4], [T, 7]; bound: [T] bias bound.
        accepted: bool [nodes(level + 1)], nodes trivially accepted so far.
        iters: int32 [J] iterations per job.

    Returns:
        intersect bool [N, 32], counts int32 [4] (node tests, accepts, rejects, rejects
        by the extra planes only), accepted, iters.
    """
    dtype = g.dtype
    u = jnp.finfo(dtype).eps
    big_n = tri.shape[0]
    valid = jnp.arange(big_n) < n
    word = mask[node.astype(jnp.int32)]
    c = jnp.arange(32, dtype=jnp.uint32)
    child = (node[:, None] << 5) | c[None, :]
    exists = (((word[:, None] >> c[None, :]) & jnp.uint32(1)) == 1) & valid[:, None]
    child_i = child.astype(jnp.int32)
    idx = child_i if storage == "full" else jnp.maximum(ptr[child_i], 0)
    elo, ehi, sm = lo[idx], hi[idx], smin[idx]
    if not all(axes):
        ilo, ihi = ch.implicit_bounds(tree, level + 1, child, dtype)
        blo = jnp.stack([elo[..., a] if axes[a] else ilo[..., a] for a in range(3)], -1)
        bhi = jnp.stack([ehi[..., a] if axes[a] else ihi[..., a] for a in range(3)], -1)
    else:
        blo, bhi = elo, ehi
    gt = g[tri][:, None]                                   # [N, 1, 7, 4]
    tt = tol[tri][:, None]                                 # [N, 1, 7]
    lo3, hi3 = blo[..., None, :], bhi[..., None, :]        # [N, 32, 1, 3]
    a_lo, a_hi = gt[..., :3] * lo3, gt[..., :3] * hi3
    vmax = jnp.sum(jnp.maximum(a_lo, a_hi), -1) + gt[..., 3]   # [N, 32, 7]
    vmin = jnp.sum(jnp.minimum(a_lo, a_hi), -1) + gt[..., 3]
    rej_edge = jnp.any(vmax[..., :3] < -tt[..., :3], -1)
    acc_edge = jnp.all(vmin[..., :3] >= tt[..., :3], -1)
    cmax = vmax[..., 3] + tt[..., 3]
    cmin = vmin[..., 3] - tt[..., 3]
    pos_scale = sm > 0
    rej_cap = pos_scale & (cmin > 0)
    lim = bound[tri][:, None]
    acc_cap = pos_scale & (cmax < 0) & (
        (cmax / bhi[..., 2]) * sm * (1 - _MARGIN_ULPS * u) < lim * (1 + _MARGIN_ULPS * u))
    basic_reject = rej_edge | rej_cap
    accept = exists & ~basic_reject & acc_edge & acc_cap
    if extra:
        extra_reject = exists & ~basic_reject & ~accept & jnp.any(vmax[..., 4:] < -tt[..., 4:], -1)
    else:
        extra_reject = jnp.zeros_like(accept)
    intersect = exists & ~basic_reject & ~accept & ~extra_reject
    counts = jnp.stack([jnp.sum(exists), jnp.sum(accept),
                        jnp.sum(exists & (basic_reject | extra_reject)),
                        jnp.sum(extra_reject)]).astype(jnp.int32)
    oob = accepted.shape[0]
    accepted = accepted.at[jnp.where(accept, child_i, oob)].set(True, mode="drop")
    iters = iters.at[jnp.where(valid, job, iters.shape[0])].add(1, mode="drop")
    return intersect, counts, accepted, iters


@functools.partial(jax.jit, static_argnames=("size",))
def _compact(size, intersect, tri, node, job):
    """The next frontier: the intersected (job, child) pairs in order, [size] each."""
    flat = intersect.reshape(-1)
    idx = jnp.nonzero(flat, size=size, fill_value=0)[0]
    parent = idx // 32
    c = (idx % 32).astype(jnp.uint32)
    return tri[parent], (node[parent] << 5) | c, job[parent]


@jax.jit
def _pack(accepted, mask):
    """``mask`` with the bits of accepted children cleared (pruning)."""
    n = mask.shape[0]
    flat = jnp.zeros(n * 32, bool).at[: accepted.shape[0]].set(accepted)
    bits = flat.reshape(n, 32).astype(jnp.uint32)
    weights = jnp.left_shift(jnp.uint32(1), jnp.arange(32, dtype=jnp.uint32))
    return mask & ~jnp.sum(bits * weights, axis=1, dtype=jnp.uint32)


def _tile_of(tree: ch.TreeLayout, leaf):
    from ..geometry.morton import decode
    coords = decode(leaf, tree.layout, len(tree.bits), xp=jnp)
    return coords[1].astype(jnp.int32) * tree.tiles_x + coords[0].astype(jnp.int32)


@functools.partial(jax.jit, static_argnames=("tree", "chunk", "cluster_only"))
def _leaf_tests(tree, chunk, cluster_only, n, tri, leaf, job, table, skeys, pos, scale,
                planes, bound, shadow, tests, iters):
    """Test every sample of each leaf job's tile (test-and-set), in chunks.

    Args:
        tri, leaf, job: [M] leaf jobs (M % chunk == 0), n valid.
        table: int32 [tiles, P] sample ids per tile (S = no sample).
        skeys: uint32 [S] sample keys; pos [S, 3]; scale [S]; planes [T, 16]; bound [T].
        shadow: bool [S]; tests: int32 [S]; iters: int32 [J].
    """
    s = pos.shape[0]

    def body(i, carry):
        shadow, tests = carry
        t = jax.lax.dynamic_slice_in_dim(tri, i * chunk, chunk)
        k = jax.lax.dynamic_slice_in_dim(leaf, i * chunk, chunk)
        ok = (i * chunk + jnp.arange(chunk)) < n
        sids = table[_tile_of(tree, k)]                       # [C, P]
        sc = jnp.minimum(sids, s - 1)
        p = pos[sc]
        pl = planes[t]
        px, py, pz = p[..., 0], p[..., 1], p[..., 2]
        e0 = px * pl[:, 0:1] + py * pl[:, 1:2] + pz * pl[:, 2:3] + pl[:, 3:4]
        e1 = px * pl[:, 4:5] + py * pl[:, 5:6] + pz * pl[:, 6:7] + pl[:, 7:8]
        e2 = px * pl[:, 8:9] + py * pl[:, 9:10] + pz * pl[:, 10:11] + pl[:, 11:12]
        cap = px * pl[:, 12:13] + py * pl[:, 13:14] + pz * pl[:, 14:15] + pl[:, 15:16]
        inside = (e0 >= 0) & (e1 >= 0) & (e2 >= 0) & (cap * scale[sc] < bound[t][:, None])
        m = ok[:, None] & (sids < s)
        if cluster_only:
            m &= skeys[sc] == k[:, None]
        tgt = jnp.where(m, sids, s)
        shadow = shadow.at[tgt].max(inside & m, mode="drop")
        tests = tests.at[tgt].add(1, mode="drop")
        return shadow, tests

    shadow, tests = jax.lax.fori_loop(0, tri.shape[0] // chunk, body, (shadow, tests))
    valid = jnp.arange(tri.shape[0]) < n
    iters = iters.at[jnp.where(valid, job, iters.shape[0])].add(1, mode="drop")
    return shadow, tests, iters


@functools.partial(jax.jit, static_argnames=("tree",))
def _merge(tree, skeys, valid, accepted):
    """bool [S]: samples inside a node accepted at any level 1..D."""
    shadow = jnp.zeros(skeys.shape, bool)
    for level in range(1, tree.levels + 1):
        shadow |= accepted[level - 1][(skeys >> tree.shift(level)).astype(jnp.int32)]
    return shadow & valid


class _Traversal:
    """Host driver of the level-synchronous traversal (see the module docstring)."""

    def __init__(self, hier, axes, extra, g, tol, bound, planes, pos, scale, skeys, table,
                 prune, cluster_only):
        self.h, self.tree = hier, hier.tree
        self.axes, self.extra = axes, extra
        self.g, self.tol, self.bound, self.planes = g, tol, bound, planes
        self.pos, self.scale, self.skeys, self.table = pos, scale, skeys, table
        self.prune, self.cluster_only = prune, cluster_only
        d = self.tree.levels
        self.masks = list(hier.masks)
        self.accepted = [jnp.zeros(self.tree.nodes(level), bool) for level in range(1, d + 1)]
        self.shadow = jnp.zeros(pos.shape[0], bool)
        self.tests = jnp.zeros(pos.shape[0], jnp.int32)
        self.counts = np.zeros(4, np.int64)
        self.leaf_visits = 0
        self.frontier_max = 0

    def _storage(self, level):
        h = self.h
        ptr = h.ptr[level] if h.ptr is not None else None
        return ptr, h.lo[level], h.hi[level], h.smin[level]

    def run(self, tri, node, job, n, level, stop):
        """Traverse frontier (tri, node, job) [n valid] from ``level``, adding node visits
        to ``self.iters`` (per job); returns the frontier reached at level ``stop``
        (tri, node, n), or None when stop > D (the leaves were tested)."""
        d = self.tree.levels
        while True:
            self.frontier_max = max(self.frontier_max, n)
            if level == stop:
                return tri, node, n
            if n == 0:
                return None
            if level == d:
                chunk = min(tri.shape[0], 1024)
                self.leaf_visits += n
                self.shadow, self.tests, self.iters = _leaf_tests(
                    self.tree, chunk, self.cluster_only, n, tri, node, job, self.table,
                    self.skeys, self.pos, self.scale, self.planes, self.bound, self.shadow,
                    self.tests, self.iters)
                return None
            ptr, lo, hi, smin = self._storage(level)
            inter, counts, acc, self.iters = _expand(
                self.tree, level, self.axes, self.h.storage, self.extra, n, tri, node, job,
                self.masks[level], ptr, lo, hi, smin, self.g, self.tol, self.bound,
                self.accepted[level], self.iters)
            self.accepted[level] = acc
            self.counts += np.asarray(counts)
            if self.prune:
                self.masks[level] = _pack(acc, self.h.masks[level])
            m = int(jnp.sum(inter))
            size = bucket(m, minimum=2048)
            tri, node, job = _compact(size, inter, tri, node, job)
            n = m
            level += 1


def _waves(total: int, wave: int | None):
    if not wave or total <= wave:
        return [(0, total)]
    return [(lo, min(lo + wave, total)) for lo in range(0, total, wave)]


def _frontier(values: np.ndarray, keys: np.ndarray | None, lo: int, hi: int):
    n = hi - lo
    size = bucket(n, minimum=2048)
    tri = np.zeros(size, np.int32)
    tri[:n] = values[lo:hi]
    key = np.zeros(size, np.uint32)
    if keys is not None:
        key[:n] = keys[lo:hi]
    job = np.zeros(size, np.int32)
    job[:n] = np.arange(lo, hi)
    return jnp.asarray(tri), jnp.asarray(key), jnp.asarray(job), n


def traverse(trav: _Traversal, casters: np.ndarray, *, passes: int, expand_level: int,
             wave: int | None):
    """Run pass 1 (and pass 2 for ``passes=2``).

    Returns:
        iterations per pass-1 job (one per caster, in ``casters`` order) int [C], and
        per pass-2 job int [J] (empty for one pass), plus the pass-2 jobs'
        (triangle, node key) arrays [J].
    """
    d = trav.tree.levels
    stop = expand_level if passes == 2 else d + 1
    trav.iters = jnp.zeros(bucket(len(casters), minimum=256), jnp.int32)
    collected = []
    for lo, hi in _waves(len(casters), wave):
        tri, key, job, n = _frontier(casters, None, lo, hi)
        out = trav.run(tri, key, job, n, 0, stop)
        if passes == 2 and out is not None:
            t, k, m = out
            collected.append((np.asarray(t)[:m], np.asarray(k)[:m]))
    iters1 = np.asarray(trav.iters)[: len(casters)]
    tri2 = np.concatenate([c[0] for c in collected]) if collected else np.zeros(0, np.int32)
    key2 = np.concatenate([c[1] for c in collected]) if collected else np.zeros(0, np.uint32)
    trav.iters = jnp.zeros(bucket(len(tri2), minimum=256), jnp.int32)
    if passes == 2:
        for lo, hi in _waves(len(tri2), wave):
            tri, key, job, n = _frontier(tri2, key2, lo, hi)
            trav.run(tri, key, job, n, expand_level, d + 1)
    iters2 = np.asarray(trav.iters)[: len(tri2)]
    return iters1, iters2, tri2, key2


# --------------------------------------------------------------------------- pipeline

@functools.partial(jax.jit, static_argnames=("tree",))
def _sample_stage(tree, pos, view, px, py, count):
    """Coordinates [S, 3], keys [S] uint32, saturated [S] bool, valid [S] bool."""
    coords = ch.sample_coords(tree, pos, view)
    valid = jnp.arange(pos.shape[0]) < count
    coords = jnp.where(valid[:, None], coords, coords[0])
    keys, saturated = ch.sample_keys(tree, px, py, coords)
    return coords, keys, saturated & valid, valid


def tile_table(tree: ch.TreeLayout, px: np.ndarray, py: np.ndarray, capacity: int) -> np.ndarray:
    """int32 [tiles, tile_pixels]: the sample id at each pixel of each leaf tile
    (``capacity`` = no sample). px, py: int [S] pixel coordinates of the samples."""
    tw, th = tree.tile
    table = np.full((tree.tiles_x * tree.tiles_y, tw * th), capacity, np.int32)
    table[(py // th) * tree.tiles_x + px // tw, (py % th) * tw + px % tw] = np.arange(len(px))
    return table


def top_jobs(iterations: np.ndarray, k: int = TOP_JOBS) -> np.ndarray:
    """int64 [k]: the k largest per-job iteration counts, descending, zero-padded."""
    out = np.zeros(k, np.int64)
    top = np.sort(np.asarray(iterations, np.int64))[::-1][:k]
    out[: len(top)] = top
    return out


def run_traversal_method(scene, gbuf, light, *, kind: str, precision: str, shadow_eps: float,
                         bias: str, bounds: str = "explicit", storage: str = "compact",
                         culling_planes: bool = True, passes: int = 1, expand_level: int = 3,
                         prune: bool = False, wave: int = 512, front_face_culling: bool = False,
                         leaf_samples: str = "tile", z_bits: int = 0,
                         depth_slices: str = "clamp", method: str = "clustered_ptsv",
                         options: dict | None = None):
    """The whole pipeline for ``kind`` = "cluster" (2014) or "ptsv" (2011).

    Returns:
        (ShadowResult, details) where details holds the full per-job iteration arrays
        ``iterations_pass1`` [casters] (in caster order), ``iterations_pass2`` [jobs],
        ``pass2_triangles`` / ``pass2_nodes`` [jobs], ``casters`` [C] triangle ids,
        the ``tree`` layout, the ``memory`` report, and the arrays the traversal used
        (``hierarchy``, ``g``, ``tol``, ``bound``, ``planes``, ``scale``, ``keys``,
        ``table``, per-sample ``tests``) for analysis and tests.
    """
    timer = StageTimer()
    with timer.stage("samples"):
        samples = view_samples(gbuf, light)
    camera = gbuf.camera
    light_h = hard_light(light).homogeneous
    h, w = gbuf.shape
    with precision_mode(precision) as dtype:
        tree = (ch.cluster_layout(camera, z_bits, depth_slices) if kind == "cluster"
                else ch.ptsv_layout(camera))
        t_cap = bucket(scene.num_triangles, minimum=16)
        tri = np.zeros((t_cap, 3, 3), dtype=dtype)
        tri[: scene.num_triangles] = scene.triangles
        planes, valid = timer.run("setup", world_setup, jnp.asarray(tri),
                                  jnp.asarray(light_h.astype(dtype)))
        with timer.stage("setup"):
            valid = np.array(valid)
            valid[scene.num_triangles:] = False
            planes4 = np.asarray(planes).reshape(-1, 4, 4)
            scale, bound = bias_terms(samples, light_h, planes4, cap_bias(scene, shadow_eps),
                                      bias)
            bound = np.where(valid, bound, -np.inf).astype(dtype)
            culled = np.zeros(t_cap, bool)
            if front_face_culling:
                culled[: scene.num_triangles] = front_face_culled(scene, light_h)
            casters = np.flatnonzero(valid & ~culled).astype(np.int32)
            s_cap = bucket(samples.count)
            pos = jnp.asarray(samples.padded_position(dtype, s_cap))
            scale_d = jnp.asarray(samples.padded(scale, dtype, s_cap))
        with timer.stage("build"):
            px = (samples.index % w).astype(np.int32)
            py = (samples.index // w).astype(np.int32)
            pxp = np.zeros(s_cap, np.int32)
            pyp = np.zeros(s_cap, np.int32)
            pxp[: samples.count], pyp[: samples.count] = px, py
            view = jnp.asarray(camera.view_matrix().astype(dtype))
            coords, keys, saturated, svalid = _sample_stage(
                tree, pos, view, jnp.asarray(pxp), jnp.asarray(pyp), samples.count)
            hier = ch.build(tree, keys, svalid, coords, scale_d, storage)
            table = jnp.asarray(tile_table(tree, px, py, s_cap))
            jax.block_until_ready(hier.lo)
        with timer.stage("setup"):
            qmax = float(jnp.max(jnp.where(svalid, coords[:, 2], 0))) if samples.count else 1.0
            pmax = float(np.abs(samples.position).max()) if samples.count else 1.0
            extra = ("silhouette" if kind == "ptsv" else "culling") if culling_planes else "none"
            inv_view = jnp.asarray(np.linalg.inv(camera.view_matrix()).astype(dtype))
            g, tol = post_perspective_planes(planes.reshape(-1, 4, 4), inv_view,
                                             jnp.asarray(qmax, dtype), jnp.asarray(pmax, dtype),
                                             extra=extra, p00=tree.p00, p11=tree.p11)
            jax.block_until_ready(g)
        levels = tree.levels
        level_l = min(max(1, expand_level), levels)
        with timer.stage("traverse"):
            trav = _Traversal(hier, _explicit_axes(tree, bounds), extra != "none", g, tol,
                              jnp.asarray(bound), planes, pos, scale_d, keys, table, prune,
                              leaf_samples == "cluster")
            iters1, iters2, tri2, key2 = traverse(
                trav, casters, passes=passes, expand_level=level_l,
                wave=wave if prune else None)
            jax.block_until_ready(trav.shadow)
        with timer.stage("merge"):
            ta = _merge(tree, keys, svalid, tuple(trav.accepted))
            shadow_all = np.asarray(trav.shadow | ta)[: samples.count]
            ta_only = np.asarray(ta & ~trav.shadow)[: samples.count]
            tests = np.asarray(trav.tests)[: samples.count].astype(np.int64)
    lit = samples.scatter(~shadow_all, fill=False)
    job_iters = np.concatenate([iters1, iters2]) if passes == 2 else iters1
    memory = ch.memory_report(tree, existing=sum(hier.counts))
    counters = {
        "samples": samples.count,
        "casters": int(len(casters)),
        "culled_triangles": scene.num_triangles - int(len(casters)),
        "front_face_culled": int(culled[: scene.num_triangles].sum()),
        "tests": int(tests.sum()),
        "tests_per_pixel": samples.scatter(tests, fill=0),
        "node_tests": int(trav.counts[0]),
        "trivial_accepts": int(trav.counts[1]),
        "trivial_rejects": int(trav.counts[2]),
        "extra_plane_rejects": int(trav.counts[3]),
        "leaf_visits": int(trav.leaf_visits),
        "ta_shadowed": int(ta_only.sum()),
        "jobs": int(len(job_iters)),
        "pass2_jobs": int(len(iters2)),
        "job_iterations_mean": float(job_iters.mean()) if len(job_iters) else 0.0,
        "job_iterations_max": int(job_iters.max()) if len(job_iters) else 0,
        "job_iterations_top": top_jobs(job_iters),
        "frontier_max": int(trav.frontier_max),
        "clusters": int(hier.clusters),
        "hierarchy_nodes": int(sum(hier.counts)),
        "hierarchy_bytes": int(memory["mask_bytes"] + (
            memory["pointer_bytes"] + 24 * sum(hier.counts) if storage == "compact"
            else memory["full_bounds_bytes"])),
        "saturated_samples": int(np.asarray(saturated).sum()),
        "shadowed": int(shadow_all.sum()),
        "lit": int(lit.sum()),
    }
    timings = dict(timer.times, total=timer.total)
    details = {"iterations_pass1": iters1, "iterations_pass2": iters2,
               "pass2_triangles": tri2, "pass2_nodes": key2, "casters": casters,
               "tree": tree, "memory": memory, "hierarchy": hier, "g": g, "tol": tol,
               "bound": bound, "planes": planes, "scale": scale_d, "keys": keys,
               "table": table, "axes": _explicit_axes(tree, bounds), "extra": extra,
               "tests": tests, "sample_count": samples.count}
    return ShadowResult(lit, counters, timings, method, dict(options or {})), details


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
    "front_face_culling": Option(False, "drop light-facing triangles of closed objects",
                                 allowed=BOOL),
    "leaf_samples": Option("tile", "at a leaf test every sample of the tile (paper) or only "
                           "the samples of that cluster", allowed=("tile", "cluster")),
}


@register("clustered_ptsv",
          doc="per-triangle shadow volumes over a view-sample cluster hierarchy",
          paper="Sintorn et al. 2014",
          options={**COMMON_TRAVERSAL_OPTIONS,
                   "bounds": Option("explicit", "node boxes implicit from keys or explicit "
                                    "(min/max of the node's samples)",
                                    allowed=("implicit", "explicit")),
                   "storage": Option("compact", "explicit box storage: full tree or pointers "
                                     "+ compact list", allowed=("full", "compact")),
                   "z_bits": Option(0, "depth-slice bits of the key (0: auto, 9 at 1024^2)",
                                    kind=int, minimum=0),
                   "depth_slices": Option("clamp", "eq. (1) slices with an open-ended top "
                                          "slice, or 'scaled' so [near, far] fits",
                                          allowed=ch.DEPTH_SLICE_MODES)})
def clustered_ptsv(scene, gbuf, light, **opts):
    result, _ = run_traversal_method(scene, gbuf, light, kind="cluster",
                                     method="clustered_ptsv", options=opts, **opts)
    return result
