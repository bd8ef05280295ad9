"""TOP trees (ternary object partitioning) over triangle shadow volumes, with depth.

The tree of Partitioned Shadow Volumes (Gerhards et al. 2015) with the additions of
Deep PSV (Mora et al. 2016): a depth per shadow volume and an ancestor link for the
stackless query. See docs/psv.md for every choice the papers leave open.

Layout (structure of arrays, ``C`` = shadow-volume capacity, ``N = 4 * C`` nodes):

- Shadow volume ``r`` (the caster of insertion rank ``r``) owns nodes ``4r .. 4r+3``:
  three edge planes (edges v0v1, v1v2, v2v0) and the cap. Every caster gets its four
  nodes whether or not it is merged (a caster found inside another shadow volume is
  dropped, its nodes stay unused), so capacities are exact and node indices are the
  same in every build.
- ``plane`` [N, 4]: the planes of ``geometry.planes.shadow_volume_planes`` unchanged:
  edge planes are >= 0 inside the volume, the cap is > 0 on the light's side.
- The *negative* child (inside the volume) of node ``i`` is ``i + 1`` for an edge node;
  the negative child of a cap is the shadow leaf. ``pos`` [N] and ``inter`` [N] are the
  positive (outside) and intersection children, node indices or -1 for a leaf. A child
  link always points at the first node ``4s`` of a shadow volume.
- ``wedge`` [N]: for an edge node, a bound on ``|plane(p)| / dist(p)`` over every point
  ``p`` inside a shadow volume of its intersection subtree (``dist`` the distance to
  the light, 1 for a directional light); -inf without an intersection child.
- Per shadow volume [C]: ``depth`` (the smallest light-to-triangle distance over every
  triangle that passed through the volume's first node during the build, in "key"
  units, see :func:`light_key`), ``anc`` (the ancestor link: the node whose
  intersection subtree holds the volume, -1 = none), ``level`` (nodes on the path from
  the root to the volume's first node), ``status`` (0 unused, 1 merged, 2 dropped).

Classification of a triangle against a node plane uses the signs of its three vertex
values with a margin ``margin`` (world units): positive (outside) when all values are
``< -margin``, negative when all are ``> margin`` (a cap: all ``< -(margin +
cap_extra)``, dropped), intersection otherwise. With ``margin = 0`` this is the
paper's plain sign test. The vertex values are computed with non-contracted
multiplications (no fused multiply-add) so that the NumPy sequential build and the
JAX parallel build classify bit-identically.
"""

from __future__ import annotations

import dataclasses
import functools

import jax
import jax.numpy as jnp
import numpy as np

STATUS_UNUSED, STATUS_MERGED, STATUS_DROPPED = 0, 1, 2
ORDERS = ("random", "mesh", "distance")
WEDGES = ("conservative", "vertex", "off")


# --------------------------------------------------------------------------- geometry

def point_triangle_distance(p: np.ndarray, tri: np.ndarray) -> np.ndarray:
    """float64 [T]: exact Euclidean distance from point p [3] to triangles tri [T, 3, 3].

    The closest point is found by Voronoi regions of the triangle (vertices, edges,
    face), all in float64; degenerate triangles fall back to the nearest edge.
    """
    p = np.asarray(p, np.float64)
    a, b, c = (np.asarray(tri[:, i], np.float64) for i in range(3))

    def seg(x, y):
        d = y - x
        dd = np.einsum("ij,ij->i", d, d)
        t = np.clip(np.einsum("ij,ij->i", p - x, d) / np.where(dd > 0, dd, 1), 0, 1)
        q = x + t[:, None] * d
        return np.linalg.norm(p - q, axis=1)

    edge = np.minimum(np.minimum(seg(a, b), seg(b, c)), seg(c, a))
    n = np.cross(b - a, c - a)
    nn = np.einsum("ij,ij->i", n, n)
    ok = nn > 0
    safe = np.where(ok, nn, 1)
    # Barycentric test of the projection of p on the plane.
    w = p - a
    s1 = np.einsum("ij,ij->i", np.cross(b - a, w), n)
    s2 = np.einsum("ij,ij->i", np.cross(c - b, p - b), n)
    s3 = np.einsum("ij,ij->i", np.cross(a - c, p - c), n)
    inside = ok & (s1 >= 0) & (s2 >= 0) & (s3 >= 0)
    face = np.abs(np.einsum("ij,ij->i", w, n)) / np.sqrt(safe)
    return np.where(inside, face, edge)


def light_key(points: np.ndarray, light_h: np.ndarray) -> np.ndarray:
    """float64 [...]: the depth-test key of points [..., 3]: distance to a point light,
    or ``-dot(towards_light, p)`` for a directional light (smaller = nearer the light)."""
    if light_h[3] != 0:
        return np.linalg.norm(points - light_h[:3], axis=-1)
    return -(points @ light_h[:3])


def triangle_key(tri: np.ndarray, light_h: np.ndarray) -> np.ndarray:
    """float64 [T]: the smallest key over each triangle tri [T, 3, 3] (exact)."""
    if light_h[3] != 0:
        return point_triangle_distance(light_h[:3], tri)
    return np.min(-(tri @ light_h[:3]), axis=1)


# --------------------------------------------------------------------------- the tree

@dataclasses.dataclass(frozen=True, eq=False)
class TopTree:
    """A built TOP tree (NumPy arrays, see the module docstring for the layout).

    Attributes:
        plane: [N, 4] dtype; pos, inter: int32 [N]; wedge: [N] dtype.
        depth: [C] dtype (key units, rounded down by ``margin``); anc, level, status:
            int32 [C]; tri: int32 [C], the scene triangle of each rank (-1 = padding).
        bound: [C] dtype, the cap bias bound of each volume (``common.bias_terms``).
        root: first node of the root volume, -1 for an empty tree.
        count: casters inserted (ranks 0 .. count-1); rounds: parallel build rounds.
        margin: classification margin (world units) used.
    """

    plane: np.ndarray
    pos: np.ndarray
    inter: np.ndarray
    wedge: np.ndarray
    depth: np.ndarray
    anc: np.ndarray
    level: np.ndarray
    status: np.ndarray
    tri: np.ndarray
    bound: np.ndarray
    root: int
    count: int
    rounds: int
    margin: float

    @property
    def capacity(self) -> int:
        return int(self.depth.shape[0])

    def stats(self) -> dict:
        """Tree size and shape: merged/dropped volumes, nodes, depth, intersections."""
        merged = self.status == STATUS_MERGED
        lv = self.level[merged]
        return {
            "tree_nodes": 4 * int(merged.sum()),
            "merged_triangles": int(merged.sum()),
            "dropped_triangles": int((self.status == STATUS_DROPPED).sum()),
            "tree_depth": int(lv.max()) + 4 if lv.size else 0,
            "tree_depth_mean": float(lv.mean()) + 4 if lv.size else 0.0,
            "intersection_triangles": int((merged & (self.anc >= 0)).sum()),
            "build_rounds": int(self.rounds),
        }

    def same_as(self, other: "TopTree") -> list[str]:
        """Names of the fields that differ from ``other`` (empty when identical)."""
        out = []
        for f in ("plane", "pos", "inter", "wedge", "depth", "anc", "level", "status", "tri"):
            if not np.array_equal(getattr(self, f), getattr(other, f)):
                out.append(f)
        if self.root != other.root:
            out.append("root")
        return out


@dataclasses.dataclass(frozen=True, eq=False)
class BuildInput:
    """Casters in insertion order, padded to capacity C (arrays in the working dtype).

    Attributes:
        planes: [C, 4, 4]; verts: [C, 3, 3]; key: [C] smallest light key of each
            triangle (float64 rounded down, minus margin); inv_dist: [C] 1 / distance
            from the light to the triangle (1 for a directional light);
            inv_vdist: [C, 3] 1 / distance of each vertex (1 for directional);
            bound: [C] cap bias bound; tri: int32 [C] scene triangle (-1 = padding).
        count: number of casters; margin, cap_extra: classification margins.
    """

    planes: np.ndarray
    verts: np.ndarray
    key: np.ndarray
    inv_dist: np.ndarray
    inv_vdist: np.ndarray
    bound: np.ndarray
    tri: np.ndarray
    count: int
    margin: float
    cap_extra: float


def insertion_order(n: int, order: str, seed: int, key: np.ndarray | None = None) -> np.ndarray:
    """int64 [n]: positions 0..n-1 in insertion order ("random" seeded, "mesh", or
    "distance": nearest the light first, ties by position)."""
    if order == "random":
        return np.random.default_rng(seed).permutation(n)
    if order == "mesh":
        return np.arange(n)
    if order == "distance":
        return np.argsort(key, kind="stable")
    raise ValueError(f"unknown insertion order {order!r}; allowed: {', '.join(ORDERS)}")


def make_input(tri: np.ndarray, planes: np.ndarray, bound: np.ndarray, tri_index: np.ndarray,
               light_h: np.ndarray, dtype, margin: float, cap_extra: float, order: str,
               seed: int, capacity: int) -> BuildInput:
    """Order the casters and pad them to ``capacity``.

    Args:
        tri: float64 [K, 3, 3] caster corners; planes: [K, 4, 4] their planes (dtype);
        bound: [K] cap bias bounds; tri_index: [K] scene triangle ids; light_h [4].
    """
    k = tri.shape[0]
    key = triangle_key(tri, light_h)
    perm = insertion_order(k, order, seed, key)
    c = capacity
    out_p = np.zeros((c, 4, 4), dtype)
    out_v = np.zeros((c, 3, 3), dtype)
    out_k = np.full(c, np.inf, dtype)
    out_id = np.ones(c, dtype)
    out_iv = np.ones((c, 3), dtype)
    out_b = np.full(c, -np.inf, dtype)
    out_t = np.full(c, -1, np.int32)
    out_p[:k] = planes[perm]
    out_v[:k] = tri[perm]
    # Depth keys rounded down (conservative for the "closer than the subtree" skip).
    kk = key[perm] - margin
    kd = kk.astype(dtype)
    kd = np.where(kd.astype(np.float64) > kk, np.nextafter(kd, dtype(-np.inf)), kd)
    out_k[:k] = kd
    if light_h[3] != 0:
        d = triangle_key(tri[perm], light_h)
        out_id[:k] = 1.0 / np.maximum(d, 1e-30)
        vd = np.linalg.norm(tri[perm] - light_h[:3], axis=-1)
        out_iv[:k] = 1.0 / np.maximum(vd, 1e-30)
    out_b[:k] = bound[perm]
    out_t[:k] = tri_index[perm]
    return BuildInput(out_p, out_v, out_k, out_id, out_iv, out_b, out_t, k, float(margin),
                      float(cap_extra))


# --------------------------------------------------------------------------- classification

def _opaque(v, zero):
    """v unchanged, but opaque to fused multiply-add contraction (zero: int 0 at run time)."""
    it = jnp.int64 if v.dtype == jnp.float64 else jnp.int32
    return jax.lax.bitcast_convert_type(jax.lax.bitcast_convert_type(v, it) | zero.astype(it),
                                        v.dtype)


def _values(xp, mul, plane, verts):
    """Vertex values [..., 3] of verts [..., 3, 3] against plane [..., 4] (fixed order)."""
    vx, vy, vz = verts[..., 0], verts[..., 1], verts[..., 2]
    a, b, c, d = (plane[..., i:i + 1] for i in range(4))
    return ((mul(vx, a) + mul(vy, b)) + mul(vz, c)) + d


def _classify(xp, mul, vals, is_cap, margin, cap_extra):
    """0 positive, 1 negative (inside / dropped for a cap), 2 intersection; vals [..., 3]."""
    hi = xp.min(vals, axis=-1)
    lo = xp.max(vals, axis=-1)
    edge_code = xp.where(hi > margin, 1, xp.where(lo < -margin, 0, 2))
    cap_code = xp.where(lo < -(margin + cap_extra), 1, xp.where(hi > margin, 0, 2))
    return xp.where(is_cap, cap_code, edge_code)


def _wedge_candidate(xp, mul, vals, inv_dist, inv_vdist, wedge):
    if wedge == "vertex":
        return xp.max(mul(xp.abs(vals), inv_vdist), axis=-1)
    return mul(xp.max(xp.abs(vals), axis=-1), inv_dist)


# --------------------------------------------------------------------------- sequential build

def build_sequential(inp: BuildInput, wedge: str = "conservative") -> TopTree:
    """Plain sequential insertion in rank order (NumPy, one triangle at a time).

    The reference the parallel build must equal node for node. Slow (a Python loop
    over every node visit): meant for tests and small scenes.
    """
    dt = inp.planes.dtype.type
    c = inp.key.shape[0]
    n = 4 * c
    plane = inp.planes.reshape(n, 4)
    pos = np.full(n, -1, np.int32)
    inter = np.full(n, -1, np.int32)
    wedge_v = np.full(n, -np.inf, dt)
    depth = np.full(c, np.inf, dt)
    anc = np.full(c, -1, np.int32)
    level = np.full(c, -1, np.int32)
    status = np.zeros(c, np.int32)
    margin = dt(inp.margin)
    cap_extra = dt(inp.cap_extra)
    root = -1
    mul = np.multiply
    for r in range(inp.count):
        verts = inp.verts[r]
        key = inp.key[r]
        if root < 0:
            root, level[r], status[r] = 4 * r, 0, STATUS_MERGED
            continue
        node, steps, last = root, 0, -1
        while True:
            sv = node >> 2
            depth[sv] = min(depth[sv], key)
            steps += 1
            vals = _values(np, mul, plane[node], verts)
            is_cap = (node & 3) == 3
            code = int(_classify(np, mul, vals, is_cap, margin, cap_extra))
            if code == 1:
                if is_cap:
                    status[r] = STATUS_DROPPED
                    break
                node += 1
                continue
            if code == 2:
                last = node
                if not is_cap and wedge != "off":
                    cand = _wedge_candidate(np, mul, vals, inp.inv_dist[r], inp.inv_vdist[r],
                                            wedge)
                    wedge_v[node] = max(wedge_v[node], cand)
                links = inter
            else:
                links = pos
            if links[node] < 0:
                links[node] = 4 * r
                status[r], level[r], anc[r] = STATUS_MERGED, steps, last
                break
            node = int(links[node])
    for r in range(inp.count):        # a volume's own triangle passes its first node
        if status[r] == STATUS_MERGED:
            depth[r] = min(depth[r], inp.key[r])
    return TopTree(plane.copy(), pos, inter, wedge_v, depth, anc, level, status,
                   inp.tri.copy(), inp.bound.copy(), root, inp.count, inp.count, inp.margin)


# --------------------------------------------------------------------------- parallel build

def _build_impl(planes, verts, key, inv_dist, inv_vdist, count, margin, cap_extra, zero,
                    *, wedge):
    """Round-based deterministic build (see :func:`build_parallel`)."""
    c = key.shape[0]
    n = 4 * c
    dt = planes.dtype
    plane = planes.reshape(n, 4)
    rank = jnp.arange(c, dtype=jnp.int32)
    mul = lambda a, b: _opaque(a * b, zero)  # noqa: E731
    big = jnp.int32(2 ** 31 - 1)
    root_key = 2 * n                          # the claim key of the empty root slot

    st = dict(
        pos=jnp.full(n, -1, jnp.int32), inter=jnp.full(n, -1, jnp.int32),
        wedge=jnp.full(n, -jnp.inf, dt), depth=jnp.full(c, jnp.inf, dt),
        anc=jnp.full(c, -1, jnp.int32), level=jnp.full(c, -1, jnp.int32),
        status=jnp.zeros(c, jnp.int32),
        pending=rank < count,
        cur=jnp.full(c, -1, jnp.int32),       # node to visit next; -1 = claim the root
        claim=jnp.where(rank < count, root_key, -1).astype(jnp.int32),
        last=jnp.full(c, -1, jnp.int32), steps=jnp.zeros(c, jnp.int32),
        root=jnp.int32(-1), rounds=jnp.int32(0))

    def descend_step(s):
        act = s["pending"] & (s["claim"] < 0)
        node = jnp.where(act, s["cur"], 0)
        sv = node >> 2
        depth = s["depth"].at[jnp.where(act, sv, c)].min(key, mode="drop")
        vals = _values(jnp, mul, plane[node], verts)
        is_cap = (node & 3) == 3
        code = _classify(jnp, mul, vals, is_cap, margin, cap_extra)
        steps = s["steps"] + act
        drop = act & (code == 1) & is_cap
        down = act & (code == 1) & ~is_cap
        isect = act & (code == 2)
        wcand = _wedge_candidate(jnp, mul, vals, inv_dist, inv_vdist, wedge)
        wmask = isect & ~is_cap & (wedge != "off")
        wedge_v = s["wedge"].at[jnp.where(wmask, node, n)].max(wcand, mode="drop")
        child = jnp.where(code == 2, s["inter"][node], s["pos"][node])
        side = act & (code != 1)
        claim = jnp.where(side & (child < 0), 2 * node + (code == 2), s["claim"])
        cur = jnp.where(down, node + 1, jnp.where(side & (child >= 0), child, s["cur"]))
        last = jnp.where(isect, node, s["last"])
        status = jnp.where(drop, STATUS_DROPPED, s["status"])
        return dict(s, depth=depth, wedge=wedge_v, steps=steps, claim=claim, cur=cur,
                    last=last, status=status, pending=s["pending"] & ~drop)

    def descend_cond(s):
        return jnp.any(s["pending"] & (s["claim"] < 0))

    def round_body(s):
        s = jax.lax.while_loop(descend_cond, descend_step, s)
        stop = s["pending"]                               # all pending now hold a claim
        ck = jnp.where(stop, s["claim"], root_key + 1)
        win = jnp.full(root_key + 2, big, jnp.int32).at[ck].min(rank)
        wr = win[ck]
        won = stop & (wr == rank)
        first = 4 * rank
        node = ck >> 1
        is_int = (ck & 1) == 1
        idx_p = jnp.where(won & ~is_int & (ck < root_key), node, n)
        idx_i = jnp.where(won & is_int & (ck < root_key), node, n)
        pos = s["pos"].at[idx_p].set(first, mode="drop")
        inter = s["inter"].at[idx_i].set(first, mode="drop")
        root = jnp.where(jnp.any(won & (ck == root_key)), 4 * win[root_key], s["root"])
        anc = jnp.where(won, s["last"], s["anc"])
        level = jnp.where(won, s["steps"], s["level"])
        status = jnp.where(won, STATUS_MERGED, s["status"])
        lost = stop & ~won
        cur = jnp.where(lost, 4 * wr, s["cur"])
        claim = jnp.where(lost, -1, jnp.where(won, -1, s["claim"]))
        return dict(s, pos=pos, inter=inter, root=root.astype(jnp.int32), anc=anc, level=level,
                    status=status, pending=s["pending"] & ~won, cur=cur, claim=claim,
                    rounds=s["rounds"] + 1)

    s = jax.lax.while_loop(lambda s: jnp.any(s["pending"]), round_body, st)
    merged = s["status"] == STATUS_MERGED
    depth = jnp.where(merged, jnp.minimum(s["depth"], key), s["depth"])
    return (s["pos"], s["inter"], s["wedge"], depth, s["anc"], s["level"], s["status"],
            s["root"], s["rounds"])


@functools.lru_cache(maxsize=None)
def _build_kernel(wedge: str):
    return jax.jit(functools.partial(_build_impl, wedge=wedge))


def build_parallel(inp: BuildInput, wedge: str = "conservative", timer=None) -> TopTree:
    """Deterministic parallel build in rounds (JAX, vectorized over triangles).

    Each round every pending triangle descends the current tree from where it stopped
    (updating the depth of every volume it enters and the wedge of every edge plane it
    straddles) until it reaches an empty child slot, which it claims. The lowest rank
    among a slot's claimants is merged there; the others continue from the new
    volume's first node in the next round. A triangle's path only depends on the
    lower-ranked triangles merged on it, so the result equals sequential insertion in
    rank order node for node (checked in tests/test_top_tree.py).
    """
    import contextlib
    stage = timer.stage("build_setup") if timer is not None else contextlib.nullcontext()
    dt = inp.planes.dtype.type
    with stage:
        args = (jnp.asarray(inp.planes), jnp.asarray(inp.verts), jnp.asarray(inp.key),
                jnp.asarray(inp.inv_dist), jnp.asarray(inp.inv_vdist), jnp.int32(inp.count),
                jnp.asarray(dt(inp.margin)), jnp.asarray(dt(inp.cap_extra)), jnp.int32(0))
    kernel = _build_kernel(wedge)
    out = timer.run("build", kernel, *args) if timer is not None else kernel(*args)
    stage = timer.stage("build_setup") if timer is not None else contextlib.nullcontext()
    with stage:
        pos, inter, wedge_v, depth, anc, level, status, root, rounds = (np.asarray(o)
                                                                        for o in out)
        return TopTree(inp.planes.reshape(-1, 4).copy(), pos, inter, wedge_v, depth, anc,
                       level, status, inp.tri.copy(), inp.bound.copy(), int(root), inp.count,
                       int(rounds), inp.margin)
