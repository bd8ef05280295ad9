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
- ``plane`` [N, 4]: the planes of ``geometry.triangle_setup.shadow_volume_planes`` unchanged:
  edge planes are >= 0 inside the volume, the cap is > 0 on the light's side.
- The *negative* child (inside the volume) of node ``i`` is ``i + 1`` for an edge node;
  the negative child of a cap is the shadow leaf. ``pos`` [N] and ``inter`` [N] are the
  positive (outside) and intersection children, node indices or -1 for a leaf. A child
  link always points at the first node ``4s`` of a shadow volume.
- ``wedge`` [N]: for an edge node, a bound on ``|plane(p)| / dist(p)`` over every point
  ``p`` inside a shadow volume of its intersection subtree (``dist`` the distance to
  the light, 1 for a directional light); -inf without an intersection child. With
  ``wedge="signed"`` it bounds ``plane(p) / dist(p)`` from above and ``wedge_lo`` [N]
  from below (+inf without an intersection child): an interval, not a symmetric bound.
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

from ..core.capacity import bucket, pad
from ..core.numerics import materialize, norms3, opaque_multiplier, ordered_dot

STATUS_UNUSED, STATUS_MERGED, STATUS_DROPPED = 0, 1, 2
ORDERS = ("random", "mesh", "distance")
WEDGES = ("conservative", "signed", "vertex", "off")


# --------------------------------------------------------------------------- geometry

def point_triangle_distance(p: np.ndarray, tri: np.ndarray) -> np.ndarray:
    """float64 [T]: exact Euclidean distance from point p [3] to triangles tri [T, 3, 3].

    The closest point is found by Voronoi regions of the triangle (vertices, edges,
    face), all in float64; degenerate triangles fall back to the nearest edge. Written
    on coordinate arrays [T] (no [T, 3] temporaries: 3x faster than einsum/cross).
    """
    p = np.asarray(p, np.float64)
    t = np.asarray(tri, np.float64)
    # Coordinates relative to p: a, b, c [3 x T].
    a = [t[:, 0, i] - p[i] for i in range(3)]
    b = [t[:, 1, i] - p[i] for i in range(3)]
    c = [t[:, 2, i] - p[i] for i in range(3)]

    def dot(u, v):
        return u[0] * v[0] + u[1] * v[1] + u[2] * v[2]

    def sub(u, v):
        return [u[0] - v[0], u[1] - v[1], u[2] - v[2]]

    def cross(u, v):
        return [u[1] * v[2] - u[2] * v[1], u[2] * v[0] - u[0] * v[2], u[0] * v[1] - u[1] * v[0]]

    def seg2(x, y):                     # squared distance from the origin to segment xy
        d = sub(y, x)
        dd = dot(d, d)
        tt_ = np.clip(-dot(x, d) / np.where(dd > 0, dd, 1), 0, 1)
        q = [x[i] + tt_ * d[i] for i in range(3)]
        return dot(q, q)

    edge = np.sqrt(np.minimum(np.minimum(seg2(a, b), seg2(b, c)), seg2(c, a)))
    ab, bc, ca = sub(b, a), sub(c, b), sub(a, c)
    n = cross(ab, sub(c, a))
    nn = dot(n, n)
    ok = nn > 0
    safe = np.where(ok, nn, 1)
    # Barycentric test of the projection of p (the origin) on the plane.
    s1 = dot(cross(ab, [-a[0], -a[1], -a[2]]), n)
    s2 = dot(cross(bc, [-b[0], -b[1], -b[2]]), n)
    s3 = dot(cross(ca, [-c[0], -c[1], -c[2]]), n)
    inside = ok & (s1 >= 0) & (s2 >= 0) & (s3 >= 0)
    face = np.abs(dot(a, n)) / np.sqrt(safe)
    return np.where(inside, face, edge)


def light_key(points: np.ndarray, light_h: np.ndarray) -> np.ndarray:
    """float64 [...]: the depth-test key of points [..., 3]: distance to a point light,
    or ``-dot(towards_light, p)`` for a directional light (smaller = nearer the light)."""
    if light_h[3] != 0:
        return norms3(points, origin=light_h[:3])
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
        wedge_lo: [N] dtype, the lower end of the signed wedge interval (``wedge`` is
            its upper end) for ``wedge="signed"``; None for the other modes.
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
    wedge_lo: np.ndarray | None = None

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
        if (self.wedge_lo is None) != (other.wedge_lo is None) or (
                self.wedge_lo is not None and not np.array_equal(self.wedge_lo, other.wedge_lo)):
            out.append("wedge_lo")
        if self.root != other.root:
            out.append("root")
        return out

    def check_wedge(self, wedge: str) -> None:
        """Raise ValueError unless a query's ``wedge`` mode reads this tree's wedge field
        as built: a signed tree holds packed intervals, the others a plain bound."""
        if (wedge == "signed") != (self.wedge_lo is not None):
            raise ValueError(f"PSV query: wedge={wedge!r} does not match the tree (built with "
                             f"{'a signed' if self.wedge_lo is not None else 'a symmetric'} "
                             "wedge): query a tree with the wedge it was built with")

    def renumbered(self, volumes: np.ndarray) -> "TopTree":
        """The same tree with shadow volume ``volumes[i]`` renumbered ``i``.

        ``volumes``: int [C], a permutation of the volume ids (for instance
        :func:`breadth_first_volumes`). Every per-node and per-volume field moves with
        its volume and every link (``pos``, ``inter``, ``anc``, ``root``) is remapped, so
        a query visits the same nodes in the same order; only the ids change. Volume
        ids are then no longer insertion ranks (``count`` still counts the casters).
        """
        c = self.capacity
        volumes = np.asarray(volumes, np.int64)
        new_id = np.full(c, -1, np.int64)
        new_id[volumes] = np.arange(volumes.size)
        if volumes.shape != (c,) or (c and new_id.min() < 0):
            raise ValueError(f"volumes must be a permutation of the {c} volume ids; "
                             f"got shape {volumes.shape}")
        # new id of every old node, and -1 at index -1, so that a link of -1 stays -1
        relink = np.empty(4 * c + 1, np.int32)
        relink[:-1] = (4 * new_id[:, None] + np.arange(4)).ravel()
        relink[-1] = -1

        def per_node(a):           # gathered in blocks of a volume's four nodes
            return np.take(a.reshape(c, 4, *a.shape[1:]), volumes, axis=0).reshape(a.shape)

        return dataclasses.replace(
            self, plane=per_node(self.plane), pos=relink[per_node(self.pos)],
            inter=relink[per_node(self.inter)], wedge=per_node(self.wedge),
            wedge_lo=None if self.wedge_lo is None else per_node(self.wedge_lo),
            depth=self.depth[volumes], anc=relink[self.anc[volumes]],
            level=self.level[volumes], status=self.status[volumes], tri=self.tri[volumes],
            bound=self.bound[volumes], root=int(relink[self.root]))


def breadth_first_volumes(tree: TopTree) -> np.ndarray:
    """int64 [C]: the tree's shadow volumes breadth-first from the root volume, then
    the volumes it does not hold (dropped casters, padding) in rank order.

    The children of a volume are taken node by node (edge nodes, then the cap), each
    node's positive child before its intersection child. Renumbered in this order
    (:meth:`TopTree.renumbered`), the volumes near the root, which every query visits,
    share cache lines and pages, and the volumes of one level lie together.
    """
    c = tree.capacity
    if tree.root < 0:
        return np.arange(c, dtype=np.int64)
    children = np.stack([tree.pos.reshape(c, 4), tree.inter.reshape(c, 4)],
                        axis=2).reshape(c, 8)
    levels, front, reached = [], np.array([tree.root >> 2], np.int64), 1
    while front.size:
        levels.append(front)
        below = children[front].ravel()
        front = below[below >= 0].astype(np.int64) >> 2
        reached += front.size
        if reached > c:
            break
    held = np.concatenate(levels)
    outside = np.ones(c, bool)
    outside[held] = False
    if reached > c or held.size + np.count_nonzero(outside) != c:
        raise RuntimeError("TOP tree: a shadow volume is reached twice from the root "
                           "(a corrupt tree: every volume has one parent link)")
    return np.concatenate([held, np.flatnonzero(outside)])


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
    tp = tri[perm]                    # float64 [K, 3, 3], gathered once
    out_v[:k] = tp
    # Depth keys rounded down (conservative for the "closer than the subtree" skip).
    kk = key[perm] - margin
    kd = kk.astype(dtype)
    kd = np.where(kd.astype(np.float64) > kk, np.nextafter(kd, dtype(-np.inf)), kd)
    out_k[:k] = kd
    if light_h[3] != 0:
        d = key[perm]                 # the point-light key is the triangle's distance
        out_id[:k] = 1.0 / np.maximum(d, 1e-30)
        vd = np.sqrt(sum((tp[..., i] - light_h[i]) ** 2 for i in range(3)))
        out_iv[:k] = 1.0 / np.maximum(vd, 1e-30)
    out_b[:k] = bound[perm]
    out_t[:k] = tri_index[perm]
    return BuildInput(out_p, out_v, out_k, out_id, out_iv, out_b, out_t, k, float(margin),
                      float(cap_extra))


# --------------------------------------------------------------------------- classification

def _values(xp, mul, plane, verts):
    """Vertex values [..., 3] of verts [..., 3, 3] against plane [..., 4] (fixed order)."""
    vx, vy, vz = verts[..., 0], verts[..., 1], verts[..., 2]
    a, b, c, d = (plane[..., i:i + 1] for i in range(4))
    return ordered_dot((vx, vy, vz), (a, b, c), mul) + d


def _classify(xp, mul, vals, is_cap, margin, cap_extra):
    """0 positive, 1 negative (inside / dropped for a cap), 2 intersection; vals [..., 3]."""
    hi = xp.min(vals, axis=-1)
    lo = xp.max(vals, axis=-1)
    edge_code = xp.where(hi > margin, 1, xp.where(lo < -margin, 0, 2))
    cap_code = xp.where(lo < -(margin + cap_extra), 1, xp.where(hi > margin, 0, 2))
    return xp.where(is_cap, cap_code, edge_code)


def _wedge_candidate(xp, mul, vals, inv_dist, inv_vdist, wedge):
    """A straddling triangle's wedge candidate: the bound (upper end for "signed")."""
    if wedge == "vertex":
        return xp.max(mul(xp.abs(vals), inv_vdist), axis=-1)
    if wedge == "signed":
        return mul(xp.maximum(xp.max(vals, axis=-1), 0), inv_dist)
    return mul(xp.max(xp.abs(vals), axis=-1), inv_dist)


def _wedge_lo_candidate(xp, mul, vals, inv_dist):
    """The signed wedge's lower end for a straddling triangle (docs/psv.md, "Wedge")."""
    return mul(xp.minimum(xp.min(vals, axis=-1), 0), inv_dist)


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
    wedge_lo = np.full(n, np.inf, dt) if wedge == "signed" else None
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
                    if wedge_lo is not None:
                        wedge_lo[node] = min(wedge_lo[node],
                                             _wedge_lo_candidate(np, mul, vals, inp.inv_dist[r]))
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
                   inp.tri.copy(), inp.bound.copy(), root, inp.count, inp.count, inp.margin,
                   wedge_lo)


# --------------------------------------------------------------------------- parallel build

def _round_impl(st, lanes, nlive, planes, verts, key, inv_dist, inv_vdist, margin, cap_extra,
                zero, *, wedge):
    """One build round for the pending triangles ``lanes`` (see :func:`build_parallel`).

    ``st``: wedge [N + 1] (and wedge_lo [N + 1] for "signed"), depth [C + 1] and the
    claim table [2N + 1] (every entry
    ``big`` between rounds), each with a scratch entry at the end; donated, updated in
    place. The winners' links (pos, inter, anc, level, status) are set by the host.
    ``lanes``: rank, cur (first node of the volume to descend), last, steps [B], sorted
    by rank; lanes ``>= nlive`` are padding.
    """
    c = key.shape[0]
    n = 4 * c
    b = lanes["rank"].shape[0]
    lane = jnp.arange(b, dtype=jnp.int32)
    live = lane < nlive
    mul = opaque_multiplier(zero)
    big = jnp.int32(2 ** 31 - 1)
    r = lanes["rank"]
    cur = lanes["cur"]
    w = cur >> 2

    def g(arr, i):
        return arr.at[i].get(mode="promise_in_bounds")

    # The volume being descended was merged in the previous round, so its children are
    # all empty: each pending triangle passes 1-4 of its nodes and claims a child slot
    # (or is dropped at its cap). The four nodes are classified at once, one 1D array
    # per coordinate (no [B, 3] rows or reductions: each is a separate pass on XLA/CPU);
    # the same products and sums as :func:`_values`, min/max are exact.
    if ROWS:
        vr = g(verts, r)                                  # [B, 9]: one row per triangle
        pr = g(planes, w)                                 # [B, 16]: one row per volume
        verts = [vr[:, i] for i in range(9)]
    vx = [(verts[3 * k] if ROWS else g(verts[3 * k], r)) for k in range(3)]
    vy = [(verts[3 * k + 1] if ROWS else g(verts[3 * k + 1], r)) for k in range(3)]
    vz = [(verts[3 * k + 2] if ROWS else g(verts[3 * k + 2], r)) for k in range(3)]
    vals, codes = [], []
    for jj in range(4):
        pa, pb, pc, pd = ((pr[:, 4 * jj + i] if ROWS else g(planes[4 * jj + i], w))
                          for i in range(4))
        v3 = [ordered_dot((vx[k], vy[k], vz[k]), (pa, pb, pc), mul) + pd for k in range(3)]
        hi = jnp.minimum(jnp.minimum(v3[0], v3[1]), v3[2])
        lo = jnp.maximum(jnp.maximum(v3[0], v3[1]), v3[2])
        if jj < 3:
            cj = jnp.where(hi > margin, 1, jnp.where(lo < -margin, 0, 2))
        else:
            cj = jnp.where(lo < -(margin + cap_extra), 1, jnp.where(hi > margin, 0, 2))
        vals.append(v3)
        codes.append(cj)
    j = jnp.where(codes[0] != 1, 0, jnp.where(codes[1] != 1, 1, jnp.where(codes[2] != 1, 2, 3)))
    code = jnp.where(j == 0, codes[0], jnp.where(j == 1, codes[1],
                                                 jnp.where(j == 2, codes[2], codes[3])))
    val = [jnp.where(j == 0, vals[0][k], jnp.where(j == 1, vals[1][k], vals[2][k]))
           for k in range(3)]
    if wedge == "vertex":
        ivd = [g(inv_vdist[k], r) for k in range(3)]
        wcand = jnp.maximum(jnp.maximum(mul(jnp.abs(val[0]), ivd[0]), mul(jnp.abs(val[1]), ivd[1])),
                            mul(jnp.abs(val[2]), ivd[2]))
    elif wedge == "signed":
        idist = g(inv_dist, r)
        vmax = jnp.maximum(jnp.maximum(jnp.maximum(val[0], val[1]), val[2]), 0)
        vmin = jnp.minimum(jnp.minimum(jnp.minimum(val[0], val[1]), val[2]), 0)
        wcand, wlo = mul(vmax, idist), mul(vmin, idist)
    else:
        amax = jnp.maximum(jnp.maximum(jnp.abs(val[0]), jnp.abs(val[1])), jnp.abs(val[2]))
        wcand = mul(amax, g(inv_dist, r))
    # Materialize the classification once: every later output would otherwise recompute
    # it in its own loop fusion (XLA/CPU; eight copies before, measured in the HLO).
    if wedge == "signed":
        jc, wcand, wlo = materialize(j | (code << 2), wcand, wlo)
    else:
        jc, wcand = materialize(j | (code << 2), wcand)
    j, code = jc & 3, jc >> 2
    node = cur + j
    steps = lanes["steps"] + j + 1
    # Every scatter and gather below is in bounds: the arrays carry one scratch entry
    # (index n, c or 2n) that masked-out lanes write to (bounds-checked scatters with
    # dropped indices cost about twice as much on XLA/CPU).
    pib = "promise_in_bounds"
    depth = st["depth"].at[jnp.where(live, w, c)].min(g(key, r), mode=pib)
    drop = live & (j == 3) & (code == 1)
    isect = live & (code == 2)
    wmask = isect & (j < 3) & (wedge != "off")
    wedge_v = st["wedge"].at[jnp.where(wmask, node, n)].max(wcand, mode=pib)
    new = dict(wedge=wedge_v)
    if wedge == "signed":
        new["wedge_lo"] = st["wedge_lo"].at[jnp.where(wmask, node, n)].min(wlo, mode=pib)
    claimant = live & ~drop
    ck = jnp.where(claimant, 2 * node + (code == 2), 2 * n)
    table = st["table"].at[ck].min(lane, mode=pib)        # lowest rank = lowest lane
    wl = jnp.where(claimant, g(table, ck), lane)
    table = table.at[ck].set(big, mode=pib)
    won = claimant & (wl == lane)
    # Per lane: node | isect << 28 | drop << 29 | won << 30 (the host links the winners).
    word = node | (isect.astype(jnp.int32) << 28) | (drop.astype(jnp.int32) << 29) | (
        won.astype(jnp.int32) << 30)
    out = dict(word=word, cur=4 * g(r, wl), steps=steps,
               last=jnp.where(isect, node, lanes["last"]))
    return dict(new, depth=depth, table=table), out


# Planes and vertices as rows [C, 16] / [C, 9] read with one row gather per lane (a
# cache line) instead of 25 1D gathers.
ROWS = True


@functools.lru_cache(maxsize=None)
def _round_kernel(wedge: str):
    return jax.jit(functools.partial(_round_impl, wedge=wedge), donate_argnums=(0, 1))


@jax.jit
def _final_depth(depth, status, key):
    return jnp.where(status == STATUS_MERGED, jnp.minimum(depth, key), depth)


def build_parallel(inp: BuildInput, wedge: str = "conservative", timer=None) -> TopTree:
    """Deterministic parallel build in rounds (JAX, vectorized over triangles).

    Each round every pending triangle descends the current tree from where it stopped
    (updating the depth of every volume it enters and the wedge of every edge plane it
    straddles) until it reaches an empty child slot, which it claims. The lowest rank
    among a slot's claimants is merged there; the others continue from the new
    volume's first node in the next round. A triangle's path only depends on the
    lower-ranked triangles merged on it, so the result equals sequential insertion in
    rank order node for node (checked in tests/test_top_tree.py).

    Round 0 merges rank 0 at the root. In every later round a pending triangle descends
    exactly one volume, the one merged in the previous round at the slot it lost (whose
    children are still empty), so a round is one vectorized classification against that
    volume's four planes. Between rounds the host compacts the pending triangles into
    the smallest of 2 sizes per octave, at least 1,024 lanes, that holds them (timed as
    ``build_compact``), so the work follows the number of pending triangles, not the
    capacity (smaller sizes would each compile a kernel for rounds of microseconds).
    """
    import contextlib
    stage = (timer.stage if timer is not None
             else lambda name: contextlib.nullcontext())
    dt = inp.planes.dtype.type
    c = inp.key.shape[0]
    n = 4 * c
    count = inp.count
    with stage("build_setup"):
        pl = inp.planes.reshape(c, 16)
        vt = inp.verts.reshape(c, 9)
        if ROWS:
            pl_a, vt_a = jnp.asarray(pl), jnp.asarray(vt)
        else:
            pl_a = tuple(jnp.asarray(pl[:, i].copy()) for i in range(16))
            vt_a = tuple(jnp.asarray(vt[:, i].copy()) for i in range(9))
        args = (pl_a, vt_a, jnp.asarray(inp.key),
                jnp.asarray(inp.inv_dist), tuple(jnp.asarray(inp.inv_vdist[:, i].copy())
                                                 for i in range(3)),
                jnp.asarray(dt(inp.margin)), jnp.asarray(dt(inp.cap_extra)), jnp.int32(0))
    kernel = _round_kernel(wedge)
    with stage("build_compact"):
        pos = np.full(n, -1, np.int32)
        inter = np.full(n, -1, np.int32)
        anc = np.full(c, -1, np.int32)
        level = np.full(c, -1, np.int32)
        status = np.zeros(c, np.int32)
        # One scratch entry past the end of every device array (see _round_impl).
        st = dict(wedge=np.full(n + 1, -np.inf, dt), depth=np.full(c + 1, np.inf, dt),
                  table=np.full(2 * n + 1, 2 ** 31 - 1, np.int32))
        if wedge == "signed":
            st["wedge_lo"] = np.full(n + 1, np.inf, dt)
        root, rounds = -1, 0
        if count > 0:                 # round 0: rank 0 claims the empty root alone
            root, rounds = 0, 1
            status[0], level[0] = STATUS_MERGED, 0
        rank = np.arange(1, count, dtype=np.int32)
        cur = np.zeros(len(rank), np.int32)
        last = np.full(len(rank), -1, np.int32)
        steps = np.zeros(len(rank), np.int32)
        st = {k: jnp.asarray(v) for k, v in st.items()}
    while len(rank):
        with stage("build_compact"):
            live = len(rank)
            b = bucket(live, minimum=1024, steps=2)     # 2 sizes per octave, >= 1024
            lanes = {"rank": pad(rank, b), "cur": pad(cur, b), "last": pad(last, b, -1),
                     "steps": pad(steps, b)}
            lanes = {k: jnp.asarray(v) for k, v in lanes.items()}
        call = (st, lanes, jnp.int32(live), *args)
        if timer is not None:
            st, out = timer.run("build", kernel, *call)
        else:
            st, out = kernel(*call)
        rounds += 1
        with stage("build_compact"):
            word = np.asarray(out["word"])[:live]
            node = word & ((1 << 28) - 1)
            isect = (word >> 28) & 1
            won = np.flatnonzero((word >> 30) & 1)
            wr = rank[won]
            new_last = np.asarray(out["last"])[:live]
            new_steps = np.asarray(out["steps"])[:live]
            wi = won[isect[won] == 1]
            wp = won[isect[won] == 0]
            inter[node[wi]] = 4 * rank[wi]
            pos[node[wp]] = 4 * rank[wp]
            status[wr] = STATUS_MERGED
            anc[wr] = new_last[won]
            level[wr] = new_steps[won]
            status[rank[((word >> 29) & 1) == 1]] = STATUS_DROPPED
            keep = np.flatnonzero((word & (3 << 29)) == 0)      # neither dropped nor won
            rank = rank[keep]
            cur = np.asarray(out["cur"])[:live][keep]
            last = new_last[keep]
            steps = new_steps[keep]
    with stage("build_setup"):
        depth = _final_depth(st["depth"][:c], jnp.asarray(status), args[2])
        wedge_v = np.asarray(st["wedge"])[:n]
        wedge_lo = np.asarray(st["wedge_lo"])[:n] if wedge == "signed" else None
        return TopTree(inp.planes.reshape(-1, 4).copy(), pos, inter, wedge_v, np.asarray(depth),
                       anc, level, status, inp.tri.copy(), inp.bound.copy(), int(root), count,
                       int(rounds), inp.margin, wedge_lo)
