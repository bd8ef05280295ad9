"""View-sample hierarchies for per-triangle shadow volumes (Sintorn et al. 2014 and 2011).

Both hierarchies are 32-ary trees over uint32 keys, stored as a *full tree*: level
``l`` (0 = root) has ``nodes(l)`` nodes, node ``i`` of level ``l`` has children
``32 i + c`` (c = 0..31) on level ``l + 1``, and a node's index is ``key >> shift(l)``.
Levels ``0 .. D-1`` are inner nodes stored as uint32 *child masks* (bit c set = child
c exists); level ``D`` holds the leaves, whose existence is a bit of their parent.

- ``cluster`` tree (2014): leaves are clusters, keys from eq. (1): the 8 x 8 pixel tile
  (x', y') and an exponential depth slice z', Morton-interleaved
  (:func:`shadowlab.geometry.morton.round_robin_layout`). 1024 x 1024 gives the paper's
  23-bit key (7 + 7 + 9 bits), D = 5 mask levels and a 3-bit root word.
- ``ptsv`` tree (2011): leaves are 8 x 4 pixel tiles, inner nodes alternate 4 x 8 and
  8 x 4 children (2D keys, :func:`~shadowlab.geometry.morton.grouped_layout`), and every
  node stores the depth range of its samples (a hierarchical min/max depth buffer).

Node bounds live in *post-perspective space* ``(nx, ny, q)``: NDC x and y and
``q = 1 / w`` (w = view depth). NDC z is an affine function of q, so these are the
paper's clip-space AABBs, parametrised so that a clip-space plane is an affine
function of (nx, ny, q) and far depths keep their float resolution (see
``volume_planes.post_perspective_planes``). Bounds are *implicit* (from the key) or
*explicit* (min / max over the node's samples), in one of two storage layouts:
``full`` (an array over every node of a level, the paper's first version) or
``compact`` (an int32 pointer per node into a list of the existing nodes' boxes, the
paper's Section 3 variant). Every box is padded outwards by a few hundred ulps so
it contains its samples' coordinates in the working precision.

Each node also stores ``smin``, the minimum over its samples of the receiver-bias
scale (``common.bias_terms``); trivial accept and cap rejection need it to be
exact with the ``"receiver"`` bias (with ``"cap"`` it is 1). This is not in the
paper, whose plain cap offset needs no per-sample data.
"""

from __future__ import annotations

import dataclasses
import functools
import math

import jax
import jax.numpy as jnp
import numpy as np

from ..core.capacity import CapacityError
from ..core.numerics import opaque_multiplier, opaque_zero, ordered_dot, shifted_scan
from ..geometry.morton import axis_bits, decode, encode, grouped_layout, round_robin_layout

FANOUT_BITS = 5
DEPTH_SLICE_MODES = ("clamp", "scaled")


def _bits_for(n: int) -> int:
    return max(0, int(n - 1).bit_length())


def pad_fraction(dtype) -> float:
    """Relative outward padding of node boxes: 256 ulps of the working precision."""
    return 256 * float(np.finfo(dtype).eps)


@dataclasses.dataclass(frozen=True)
class TreeLayout:
    """Static description of a view-sample tree (hashable: used as a jit static arg).

    Attributes:
        kind: "cluster" (2014) or "ptsv" (2011).
        width, height: image size in pixels.
        tile: (tw, th) leaf tile size in pixels.
        bits: key bits per axis: (x, y, z) for clusters, (x, y) for PTSV.
        layout: axis of each key bit, LSB first.
        near, far: the camera's clip distances (world units).
        log_ratio: ln of the depth-slice ratio r (slice k covers depths
            [near r^k, near r^(k+1))); 0 for PTSV.
        depth_slices: "clamp" (eq. 1, the top slice absorbs everything farther) or
            "scaled" (r enlarged so that far fits in the slices).
        saturates: eq. (1) needs more slices than the key holds for [near, far].
        tan_half_fov: tan(fov_y / 2).
        p00, p11: the projection's x and y scales (f / aspect, f).
    """

    kind: str
    width: int
    height: int
    tile: tuple[int, int]
    bits: tuple[int, ...]
    layout: tuple[int, ...]
    near: float
    far: float
    log_ratio: float
    depth_slices: str
    saturates: bool
    p00: float
    p11: float

    @property
    def key_bits(self) -> int:
        return len(self.layout)

    @property
    def levels(self) -> int:
        """D: the number of mask levels (the leaves are level D)."""
        return max(1, math.ceil(self.key_bits / FANOUT_BITS))

    @property
    def tiles_x(self) -> int:
        return -(-self.width // self.tile[0])

    @property
    def tiles_y(self) -> int:
        return -(-self.height // self.tile[1])

    @property
    def tile_pixels(self) -> int:
        return self.tile[0] * self.tile[1]

    @property
    def slices(self) -> int:
        return 1 << self.bits[2] if self.kind == "cluster" else 1

    def shift(self, level: int) -> int:
        """Node index at ``level`` = key >> shift(level)."""
        return FANOUT_BITS * (self.levels - level)

    def nodes(self, level: int) -> int:
        return 1 << max(0, self.key_bits - self.shift(level))

    def extent_bits(self, level: int, axis: int) -> int:
        """log2 of a level-``level`` node's extent along ``axis`` in leaf units."""
        return axis_bits(self.layout, axis, below=min(self.shift(level), self.key_bits))


#: key bits of a tree: the accepted-children rows (32 per inner node, every level) are
#: indexed with int32, which 31 or more key bits would pass
MAX_KEY_BITS = 30


def cluster_layout(camera, z_bits: int = 0, depth_slices: str = "clamp",
                   fov_y_deg: float | None = None) -> TreeLayout:
    """The 2014 cluster key layout for ``camera`` (resolution, near, far, fov).

    ``z_bits = 0`` picks the paper's choice: two more depth bits than the larger of the
    x / y tile bits (9 at 1024 x 1024, 10 for 1080p), at most ``MAX_KEY_BITS`` key bits in
    total (:class:`~shadowlab.core.capacity.CapacityError` beyond).
    The slice ratio is eq. (1): r = 1 + 2 tan(fov_y / 2) / S_y, S_y the tile rows.
    """
    if depth_slices not in DEPTH_SLICE_MODES:
        raise ValueError(f"depth_slices must be one of {DEPTH_SLICE_MODES}")
    w, h = camera.resolution
    bx, by = _bits_for(-(-w // 8)), _bits_for(-(-h // 8))
    bz = z_bits or min(max(bx, by) + 2, MAX_KEY_BITS - bx - by)
    if bz < 1 or bx + by + bz > MAX_KEY_BITS:
        bz = max(bz, 1)
        raise CapacityError(f"cluster key needs {bx + by + bz} bits at {w}x{h} with "
                            f"z_bits={bz}; at most {MAX_KEY_BITS} (the merge addresses a "
                            f"node's 32 children at int32 offsets): use a smaller z_bits "
                            f"or resolution")
    fov = camera.fov_y_deg if fov_y_deg is None else fov_y_deg
    tan_half = math.tan(math.radians(fov) / 2)
    sy = -(-h // 8)
    log_r = math.log1p(2 * tan_half / sy)
    needed = math.log(camera.far / camera.near) / log_r
    saturates = needed > (1 << bz)
    if depth_slices == "scaled" and saturates:
        log_r = math.log(camera.far / camera.near) / (1 << bz)
    f = 1.0 / tan_half
    return TreeLayout("cluster", w, h, (8, 8), (bx, by, bz), round_robin_layout((bx, by, bz)),
                      float(camera.near), float(camera.far), float(log_r), depth_slices,
                      bool(saturates), f / camera.aspect, f)


def ptsv_layout(camera) -> TreeLayout:
    """The 2011 PTSV tree: 8 x 4 leaf tiles, children alternating 4 x 8 and 8 x 4."""
    w, h = camera.resolution
    bx, by = _bits_for(-(-w // 8)), _bits_for(-(-h // 4))
    layout = grouped_layout((bx, by), ((2, 3), (3, 2)))
    f = 1.0 / math.tan(math.radians(camera.fov_y_deg) / 2)
    return TreeLayout("ptsv", w, h, (8, 4), (bx, by), layout, float(camera.near),
                      float(camera.far), 0.0, "clamp", False, f / camera.aspect, f)


# --------------------------------------------------------------------------- samples

def view_transform(position, view):
    """View-space points [S, 3] of world points [S, 3] (``view`` [4, 4], same dtype).

    float32: ``((x r0 + y r1) + z r2) + t`` per row, each product rounded once, in
    columns. That is the rounding of XLA's float32 ``position @ R.T + t`` (which it
    lowers to a multiply and a size-3 reduction: measured bit-identical on every sample
    of gate and sphere_grid at 1024^2), but the [S, 3] reduction is ~50x slower than
    this column form. float64: the dot itself (XLA's float64 dot rounds as an FMA chain,
    which XLA cannot be made to emit elementwise), so keys stay what they were.
    """
    if position.dtype == jnp.float64:
        return position @ view[:3, :3].T + view[:3, 3]
    mul = opaque_multiplier(opaque_zero(view, jnp.int32))    # NaN view: garbage either way
    xyz = [position[:, 0], position[:, 1], position[:, 2]]
    rows = [ordered_dot(xyz, [view[j, 0], view[j, 1], view[j, 2]], mul) + view[j, 3]
            for j in range(3)]
    return jnp.stack(rows, axis=1)


def sample_coords(tree: TreeLayout, position, view):
    """Post-perspective coordinates (nx, ny, q) [S, 3] of world points [S, 3].

    ``view`` [4, 4] is the world -> view matrix; computed in the dtype of ``position``
    (the view transform: :func:`view_transform`).
    """
    v = view_transform(position, view)
    w = -v[:, 2]
    q = 1 / w
    return jnp.stack([tree.p00 * v[:, 0] * q, tree.p11 * v[:, 1] * q, q], axis=1)


def sample_keys(tree: TreeLayout, px, py, coords):
    """uint32 keys [S] of samples at pixel (px, py) [S] (int32) with coords [S, 3].

    Cluster keys: (px // 8, py // 8, z') with z' = floor(ln(w / near) / ln r) clamped
    to [0, slices - 1]; PTSV keys: (px // 8, py // 4). Also returns bool [S], the
    samples whose unclamped z' exceeds the top slice (saturated; always False for PTSV).
    """
    tx = (px // tree.tile[0]).astype(jnp.uint32)
    ty = (py // tree.tile[1]).astype(jnp.uint32)
    if tree.kind == "ptsv":
        return encode((tx, ty), tree.layout, xp=jnp), jnp.zeros(px.shape, bool)
    w = 1 / coords[:, 2]
    z = jnp.floor(jnp.log(w / tree.near) / tree.log_ratio)
    top = tree.slices - 1
    saturated = z > top
    zi = jnp.clip(z, 0, top).astype(jnp.uint32)
    return encode((tx, ty, zi), tree.layout, xp=jnp), saturated


def sample_keys_numpy(tree: TreeLayout, px, py, depth) -> np.ndarray:
    """Plain NumPy loop version of :func:`sample_keys` (float64 depth), for tests."""
    out = np.zeros(len(px), np.uint32)
    for i in range(len(px)):
        c = [px[i] // tree.tile[0], py[i] // tree.tile[1]]
        if tree.kind == "cluster":
            z = math.floor(math.log(depth[i] / tree.near) / tree.log_ratio)
            c.append(min(max(z, 0), tree.slices - 1))
        key, used = 0, [0] * len(c)
        for bit, a in enumerate(tree.layout):
            key |= ((c[a] >> used[a]) & 1) << bit
            used[a] += 1
        out[i] = key
    return out


# --------------------------------------------------------------------------- bounds

def level_extents(tree: TreeLayout, level: int) -> tuple:
    """(key shift, x / y extent in tiles as floats, z extent in slices as an int) of a
    level-``level`` node: what :func:`implicit_bounds` needs to know about the level."""
    return (min(tree.shift(level), tree.key_bits), float(1 << tree.extent_bits(level, 0)),
            float(1 << tree.extent_bits(level, 1)),
            1 << tree.extent_bits(level, 2) if tree.kind == "cluster" else 0)


def implicit_bounds(tree: TreeLayout, level: int, node, dtype):
    """Implicit boxes (lo, hi), each [..., 3], of level-``level`` nodes ``node`` (uint32).

    x / y from the node's tile range, q from its depth-slice range (the top slice is
    open-ended: q down to 0). For PTSV the q range is [0, 1 / near] (explicit bounds
    replace it). Padded outwards by :func:`pad_fraction`.
    """
    shift, ex, ey, ez = level_extents(tree, level)
    base = jnp.asarray(node).astype(jnp.uint32) << shift
    coords = decode(base, tree.layout, len(tree.bits), xp=jnp)
    tw, th = tree.tile
    x0 = coords[0].astype(dtype)
    y0 = coords[1].astype(dtype)
    nx_lo = 2 * tw * x0 / tree.width - 1
    nx_hi = jnp.minimum(2 * tw * (x0 + ex) / tree.width - 1, 1)
    ny_hi = 1 - 2 * th * y0 / tree.height
    ny_lo = jnp.maximum(1 - 2 * th * (y0 + ey) / tree.height, -1)
    if tree.kind == "cluster":
        z0 = coords[2].astype(dtype)
        q_hi = jnp.exp(-tree.log_ratio * z0) / tree.near
        top = coords[2].astype(jnp.int32) + ez >= tree.slices
        q_lo = jnp.where(top, 0, jnp.exp(-tree.log_ratio * (z0 + ez)) / tree.near)
    else:
        q_hi = jnp.full(nx_lo.shape, 1 / tree.near, dtype)
        q_lo = jnp.zeros(nx_lo.shape, dtype)
    lo = jnp.stack([nx_lo, ny_lo, q_lo], axis=-1).astype(dtype)
    hi = jnp.stack([nx_hi, ny_hi, q_hi], axis=-1).astype(dtype)
    return pad_box(lo, hi, dtype)


def pad_box(lo, hi, dtype):
    """Boxes grown by ``pad_fraction`` of their coordinates' magnitude plus a tiny floor."""
    pad = pad_fraction(dtype)
    tiny = float(np.finfo(dtype).tiny) * 1e6
    return (lo - (jnp.abs(lo) * pad + tiny)).astype(dtype), (hi + (jnp.abs(hi) * pad + tiny)).astype(dtype)


# --------------------------------------------------------------------------- build

@dataclasses.dataclass(frozen=True, eq=False)
class Hierarchy:
    """A built tree (device arrays).

    Attributes:
        tree: the static layout.
        masks: per mask level l = 0..D-1, uint32 [nodes(l)] child masks (the paper's full
            mask arrays: one bit per node of levels 1..D).
        counts: per level l = 1..D, the number of existing nodes (int32 scalars, on the
            device until read).
        storage: "full" or "compact".
        start: per mask level l = 0..D-1, int32 [nodes(l)]: for an existing node i, the
            number of existing level-(l + 1) nodes before its first child (in key order);
            0 for absent nodes (never read). None for "full". A child's index in the
            compact list is ``start[parent] + popcount(word & ((1 << c) - 1))``
            (:func:`child_index`), so the per-node pointers (:attr:`ptr`) need not be
            stored.
        lo, hi: per level 1..D, float [capacity_l, 3] explicit boxes (padded); for
            "full" capacity_l = nodes(l), for "compact" min(nodes(l), samples).
        smin: per level 1..D, float [capacity_l], the minimum bias scale of the node's
            samples.
        keys: per level 1..D, uint32 [capacity_l], the key of each listed node (the
            inverse of :attr:`ptr`; rows past the level's count are 0), for "compact";
            None for "full", whose row index is the key.
    """

    tree: TreeLayout
    masks: tuple
    counts: tuple
    storage: str
    start: tuple | None
    lo: tuple
    hi: tuple
    smin: tuple
    keys: tuple | None = None

    @property
    def clusters(self) -> int:
        return int(self.counts[-1])

    @functools.cached_property
    def exists(self) -> tuple:
        """Per level 1..D, bool [nodes(l)]: the masks' bits unpacked, a bool per node of
        the full tree. On demand for tests and analysis; the build never forms it."""
        c = jnp.arange(32, dtype=jnp.uint32)
        return tuple((((m[:, None] >> c) & jnp.uint32(1)) == 1).reshape(-1)[
            : self.tree.nodes(level + 1)] for level, m in enumerate(self.masks))

    @functools.cached_property
    def ptr(self) -> tuple | None:
        """Per level 1..D, int32 [nodes(l)]: each node's index in the compact list (-1 if
        absent), the paper's pointer per node; None for "full". Computed on demand (for
        tests, analysis and the Warp kernels), not by the traversal."""
        if self.start is None:
            return None
        return tuple(_compact_pointers(self.tree, self.masks, level)
                     for level in range(1, self.tree.levels + 1))


def child_index(masks, start, level: int, node):
    """int32 [...]: compact-list index of the existing level-``level`` nodes ``node``
    (uint32 [...]) from their parents' mask words and ``start`` (see :class:`Hierarchy`)."""
    parent = (node >> FANOUT_BITS).astype(jnp.int32)
    c = node & jnp.uint32(31)
    below = masks[level - 1][parent] & ((jnp.uint32(1) << c) - jnp.uint32(1))
    return start[level - 1][parent] + jax.lax.population_count(below).astype(jnp.int32)


@functools.partial(jax.jit, static_argnames=("tree", "level"))
def _compact_pointers(tree: TreeLayout, masks, level: int):
    """int32 [nodes(level)]: index of each existing level-``level`` node in key order
    (-1 if absent), from its parent's child-mask word: the parent's exclusive prefix
    count of set bits plus the bits below the child's own (no prefix sum over the whole
    level)."""
    word = masks[level - 1]
    cnt = jax.lax.population_count(word).astype(jnp.int32)
    start = jnp.cumsum(cnt) - cnt
    c = jnp.arange(32, dtype=jnp.uint32)
    below = jax.lax.population_count(word[:, None] & ((jnp.uint32(1) << c) - jnp.uint32(1)))
    bit = ((word[:, None] >> c) & jnp.uint32(1)) == 1
    ptr = jnp.where(bit, start[:, None] + below.astype(jnp.int32), -1)
    return ptr.reshape(-1)[: tree.nodes(level)]


def tile_slots(tree: TreeLayout, px, py, valid):
    """The samples grouped by leaf tile (the paper builds with one warp per 8 x 8 tile).

    Args:
        px, py: int32 [S] pixel of each sample; valid: bool [S].
    Returns:
        slot: int32 [S], ``tile * P + pixel within the tile`` (0 for invalid rows), P =
        ``tree.tile_pixels``; table: int32 [tiles, P], the sample at each slot (S where
        there is none).
    """
    s = px.shape[0]
    tw, th = tree.tile
    tiles = tree.tiles_x * tree.tiles_y
    tile = (py // th) * tree.tiles_x + px // tw
    within = (py % th) * tw + px % tw
    slot = jnp.where(valid, tile * tree.tile_pixels + within, 0)
    table = jnp.full((tiles, tree.tile_pixels), s, jnp.int32).at[
        jnp.where(valid, tile, tiles), within].set(jnp.arange(s, dtype=jnp.int32), mode="drop")
    return slot, table


ENTRY_CHUNK = 4096       # list entries per step of the build's loops over existing nodes


def _over(count, cap: int, body, init):
    """``init`` carried through ``body(base, e, ok, carry)`` for chunks [base, base + e)
    of a list with static capacity ``cap`` (a multiple of e = min(cap, ENTRY_CHUNK));
    ``ok`` bool [e] marks the entries below ``count``. The trip count follows ``count``
    (a traced int), so the work is the list's length, not its capacity."""
    e = min(cap, ENTRY_CHUNK)

    def step(i, carry):
        base = i * e
        return body(base, e, base + jnp.arange(e) < count, carry)

    return jax.lax.fori_loop(0, (count + e - 1) // e, step, init)


def _pad_live(lo, hi, count):
    """``pad_box`` applied to the chunks of lo, hi [cap, 3] (cap a multiple of the chunk)
    that hold rows [0, count); rows after the last such chunk (absent nodes, never read)
    keep their unpadded fill."""
    def body(base, e, ok, carry):
        olo, ohi = carry
        plo, phi = pad_box(jax.lax.dynamic_slice_in_dim(lo, base, e),
                           jax.lax.dynamic_slice_in_dim(hi, base, e), lo.dtype)
        return (jax.lax.dynamic_update_slice_in_dim(olo, plo, base, 0),
                jax.lax.dynamic_update_slice_in_dim(ohi, phi, base, 0))

    return _over(count, lo.shape[0], body, (lo, hi))


def _tile_leaves(tile_keys, tile_valid, cap: int):
    """The distinct leaf keys (clusters): uint32 [cap] (tile-major, ascending within a
    tile; the first ``count`` entries are used) and count (int32).

    Samples of different tiles never share a key (the key holds the tile's x and y), so
    duplicates are found within each tile's row (at most P samples, as the paper's warp
    per tile does): a row sort and a comparison with the left neighbour. Prefix sums
    over the rows' counts and within the rows place each tile's clusters in the list.
    Work and memory follow the samples; nothing is indexed by key.
    """
    # empty slots repeat a key of their row, so they add no distinct value
    fill = jnp.max(jnp.where(tile_valid, tile_keys, 0), axis=1, keepdims=True)
    # equal integers are indistinguishable, so the (faster) unstable sort suffices
    k = jax.lax.sort(jnp.where(tile_valid, tile_keys, fill), dimension=1, is_stable=False)
    first = jnp.concatenate([jnp.ones_like(k[:, :1], bool), k[:, 1:] != k[:, :-1]], axis=1)
    first &= jnp.any(tile_valid, axis=1, keepdims=True)
    within = shifted_scan(first.astype(jnp.int32), jnp.add, 0)
    per_tile = within[:, -1]
    pos = (jnp.cumsum(per_tile) - per_tile)[:, None] + within - 1
    leaves = jnp.zeros(cap, jnp.uint32).at[jnp.where(first, pos, cap)].set(k, mode="drop")
    return leaves, jnp.sum(per_tile)


def _lowest_bit(word):
    """Index of the lowest set bit of uint32 ``word`` (!= 0)."""
    return jax.lax.population_count((word & (~word + jnp.uint32(1))) - jnp.uint32(1))


def _represents(tree: TreeLayout, masks, key, level: int):
    """bool [...]: whether the leaf entries ``key`` represent their level-``level`` node:
    the node's lowest existing child is the entry's own, at every level from ``level``
    down to the leaves (needs the masks of levels ``level`` .. D-1)."""
    rep = jnp.ones(key.shape, bool)
    for lv in range(level, tree.levels):
        word = masks[lv][(key >> tree.shift(lv)).astype(jnp.int32)]
        rep &= ((key >> tree.shift(lv + 1)) & jnp.uint32(31)) == _lowest_bit(word)
    return rep


def _masks_from_leaves(tree: TreeLayout, leaves, count):
    """Child masks (levels 0..D-1) and node counts (levels 1..D) from the distinct leaves.

    Bottom-up, a bit per node set once by a scatter-add (the bits added to one word are
    distinct, so the add is an OR): every leaf sets its bit in its level-(D-1) word;
    a level-l node is then represented by the entry that represents its lowest existing
    child (the lowest set bit of its word: :func:`_represents`), which sets the node's
    bit in its parent's word. Each level is one pass over the leaf list.
    """
    d = tree.levels
    masks, counts = [None] * d, [None] * d
    for level in range(d - 1, -1, -1):
        n_words = tree.nodes(level)

        def body(base, e, ok, carry, level=level, n_words=n_words):
            words, n = carry
            key = jax.lax.dynamic_slice_in_dim(leaves, base, e)
            rep = ok & _represents(tree, masks, key, level + 1)
            node = key >> tree.shift(level + 1)
            parent = jnp.where(rep, (node >> FANOUT_BITS).astype(jnp.int32), n_words)
            words = words.at[parent].add(jnp.uint32(1) << (node & jnp.uint32(31)),
                                         mode="drop")
            return words, n + jnp.sum(rep, dtype=jnp.int32)

        masks[level], counts[level] = _over(count, leaves.shape[0], body, (
            jnp.zeros(n_words, jnp.uint32), jnp.zeros((), jnp.int32)))
    return masks, counts


def _starts(tree: TreeLayout, masks, counts, leaves, count):
    """``start`` per mask level (see :class:`Hierarchy`), top-down over the existing
    nodes: a level's nodes find their compact index from the level above
    (:func:`child_index`), write their words' popcounts at those indices, and an
    exclusive prefix sum over the level's ``counts`` entries gives their starts.
    Absent nodes keep 0."""
    d = tree.levels
    cap = leaves.shape[0]
    starts = [jnp.zeros(tree.nodes(0), jnp.int32)]        # the root's first child: entry 0
    for level in range(1, d):
        n_list = min(tree.nodes(level), cap)

        def reps(base, e, ok, level=level):
            key = jax.lax.dynamic_slice_in_dim(leaves, base, e)
            node = key >> tree.shift(level)
            rep = ok & _represents(tree, masks, key, level)
            return node, rep, child_index(masks, starts, level, node)

        def put(base, e, ok, pcs, level=level, n_list=n_list):
            node, rep, idx = reps(base, e, ok)
            pc = jax.lax.population_count(masks[level][node.astype(jnp.int32)])
            return pcs.at[jnp.where(rep, idx, n_list)].set(pc.astype(jnp.int32), mode="drop")

        pcs = _over(count, cap, put, jnp.zeros(n_list, jnp.int32))

        def scan(base, e, ok, carry):
            out, total = carry
            v = jax.lax.dynamic_slice_in_dim(pcs, base, e)
            c = jnp.cumsum(v)
            return jax.lax.dynamic_update_slice_in_dim(out, total + c - v, base, 0), total + c[-1]

        excl, _ = _over(counts[level - 1], n_list, scan, (pcs, jnp.zeros((), jnp.int32)))

        def back(base, e, ok, start, level=level):
            node, rep, idx = reps(base, e, ok)
            where = jnp.where(rep, node.astype(jnp.int32), tree.nodes(level))
            return start.at[where].set(excl[jnp.where(rep, idx, 0)], mode="drop")

        starts.append(_over(count, cap, back, jnp.zeros(tree.nodes(level), jnp.int32)))
    return starts


@functools.partial(jax.jit, static_argnames=("tree", "storage", "caps", "list_cap"))
def _build(tree: TreeLayout, storage: str, caps: tuple, list_cap: int, keys, valid, coords,
           scale, tile_keys, tile_valid):
    """Masks, counts, and explicit boxes and smin per level 1..D, in one call.

    The distinct leaves come from the tiles (:func:`_tile_leaves`), the masks and
    counts from them (:func:`_masks_from_leaves`), compact storage's starts top-down
    (:func:`_starts`). Leaf boxes are reduced from the samples (scatter-min / max to
    each sample's compact index or, for "full", its key), inner boxes from their
    children's boxes; compact storage carries each entry's key to find its parent (and
    returns them: :attr:`Hierarchy.keys`), and its inner levels and padding loop over the
    existing entries only.
    """
    d = tree.levels
    dtype = coords.dtype
    big = jnp.asarray(np.finfo(dtype).max, dtype)
    leaves, n_leaves = _tile_leaves(tile_keys, tile_valid, list_cap)
    masks, counts = _masks_from_leaves(tree, leaves, n_leaves)
    counts = tuple(counts)
    los, his, smins, ekeys = [None] * d, [None] * d, [None] * d, None
    if storage == "full":
        starts = None
        idx = jnp.where(valid, keys.astype(jnp.int32), caps[d - 1])
        cap = caps[d - 1]
        los[d - 1] = jnp.full((cap, 3), big).at[idx].min(coords, mode="drop")
        his[d - 1] = jnp.full((cap, 3), -big).at[idx].max(coords, mode="drop")
        smins[d - 1] = jnp.full((cap,), big).at[idx].min(scale, mode="drop")
        for level in range(d - 1, 0, -1):
            n = tree.nodes(level)
            los[level - 1] = jnp.min(los[level].reshape(n, -1, 3), axis=1)
            his[level - 1] = jnp.max(his[level].reshape(n, -1, 3), axis=1)
            smins[level - 1] = jnp.min(smins[level].reshape(n, -1), axis=1)
        padded = [pad_box(lo, hi, dtype) for lo, hi in zip(los, his)]
    else:
        starts = _starts(tree, masks, counts, leaves, n_leaves)
        cap = caps[d - 1]
        idx = jnp.where(valid, child_index(masks, starts, d, keys), cap)
        los[d - 1] = jnp.full((cap, 3), big).at[idx].min(coords, mode="drop")
        his[d - 1] = jnp.full((cap, 3), -big).at[idx].max(coords, mode="drop")
        smins[d - 1] = jnp.full((cap,), big).at[idx].min(scale, mode="drop")

        def leaf_keys(base, e, ok, ekey):
            key = jax.lax.dynamic_slice_in_dim(leaves, base, e)
            at = jnp.where(ok, child_index(masks, starts, d, key), cap)
            return ekey.at[at].set(key, mode="drop")

        ekey = _over(n_leaves, list_cap, leaf_keys, jnp.zeros(cap, jnp.uint32))
        ekeys = [None] * (d - 1) + [ekey]
        for level in range(d - 1, 0, -1):
            cap = caps[level - 1]

            def body(base, e, ok, carry, level=level, cap=cap, ekey=ekey):
                lo, hi, sm, key = carry
                pkey = jax.lax.dynamic_slice_in_dim(ekey, base, e) >> FANOUT_BITS
                parent = jnp.where(ok, child_index(masks, starts, level, pkey), cap)
                lo = lo.at[parent].min(jax.lax.dynamic_slice_in_dim(los[level], base, e),
                                       mode="drop")
                hi = hi.at[parent].max(jax.lax.dynamic_slice_in_dim(his[level], base, e),
                                       mode="drop")
                sm = sm.at[parent].min(jax.lax.dynamic_slice_in_dim(smins[level], base, e),
                                       mode="drop")
                return lo, hi, sm, key.at[parent].set(pkey, mode="drop")

            los[level - 1], his[level - 1], smins[level - 1], ekey = _over(
                counts[level], caps[level], body,
                (jnp.full((cap, 3), big), jnp.full((cap, 3), -big), jnp.full((cap,), big),
                 jnp.zeros(cap, jnp.uint32)))
            ekeys[level - 1] = ekey
        padded = [_pad_live(lo, hi, n) for lo, hi, n in zip(los, his, counts)]
    return (tuple(masks), counts, None if starts is None else tuple(starts),
            tuple(p[0] for p in padded), tuple(p[1] for p in padded), tuple(smins),
            None if ekeys is None else tuple(ekeys))


def build(tree: TreeLayout, keys, valid, coords, scale, storage: str = "compact", *,
          tile_keys, tile_valid) -> Hierarchy:
    """Build masks and explicit bounds over samples (one jitted call, no host round
    trip; ``counts`` stay on the device until read).

    Args:
        keys: uint32 [S] sample keys; valid: bool [S] (False for padding rows).
        coords: [S, 3] post-perspective coordinates; scale: [S] bias scale.
        storage: "full" or "compact" (how explicit boxes are stored). Compact lists are
            sized min(nodes, samples rounded up to ``ENTRY_CHUNK``) per level (a static
            bound: no count is read back).
        tile_keys: uint32 [tiles, P], the keys of each leaf tile's samples, and
            tile_valid: bool [tiles, P], where there is one (the samples grouped by
            :func:`tile_slots`' table); every valid sample must be in them.

    Apart from the mask (and, for "compact", ``start``) words, which the traversal
    indexes by node as the paper does, work and memory follow the samples and the
    existing nodes, not the key space; "full" storage keeps the paper's full-tree boxes.
    """
    s = -(-keys.shape[0] // ENTRY_CHUNK) * ENTRY_CHUNK     # a multiple of the chunk
    list_cap = min(tree.nodes(tree.levels), s)               # node counts are powers of two
    if storage == "full":
        caps = tuple(tree.nodes(level) for level in range(1, tree.levels + 1))
    else:
        caps = tuple(min(tree.nodes(level), s) for level in range(1, tree.levels + 1))
    masks, counts, start, lo, hi, smin, entry_keys = _build(tree, storage, caps, list_cap,
                                                            keys, valid, coords, scale,
                                                            tile_keys, tile_valid)
    return Hierarchy(tree, masks, counts, storage, start, lo, hi, smin, entry_keys)


def masks_numpy(tree: TreeLayout, keys: np.ndarray) -> list[np.ndarray]:
    """Plain loop version of the child masks (levels 0..D-1), for tests."""
    d = tree.levels
    masks = [np.zeros(tree.nodes(level), np.uint32) for level in range(d)]
    for k in np.unique(keys):
        k = int(k)
        for level in range(d):
            node = k >> tree.shift(level)
            child = (k >> tree.shift(level + 1)) & 31
            masks[level][node] |= np.uint32(1 << child)
    return masks


# --------------------------------------------------------------------------- memory

def memory_report(tree: TreeLayout, existing: int | None = None) -> dict:
    """Bytes each layout needs (the paper's Section 3 figures).

    Counts every node of levels 0..D (the leaves included). Masks: one bit per node
    (= a uint32 word per inner node); full bounds: six float32 per node; compact:
    an int32 pointer per node plus six float32 per existing box (``existing``, or the
    paper's worst case of one box per pixel; the inner levels add at most 1/32 + ...
    of that again).
    """
    d = tree.levels
    per_level = [tree.nodes(level) for level in range(d + 1)]
    total = sum(per_level)
    worst = min(per_level[-1], tree.width * tree.height)      # the paper: one box per pixel
    box = 6 * 4
    out = {"levels": d + 1, "key_bits": tree.key_bits, "nodes_per_level": per_level,
           "total_nodes": total,
           "mask_bytes": 4 * sum(per_level[:-1]),
           "full_bounds_bytes": box * total,
           "pointer_bytes": 4 * total,
           "compact_worst_bytes": box * worst}
    if existing is not None:
        out["compact_bytes"] = box * int(existing)
    return out


def decode_np(leaf: int, tree: TreeLayout) -> tuple[int, int]:
    """(tile x, tile y) of a leaf key (plain Python, for tests and analysis)."""
    c = decode(np.uint32(leaf), tree.layout, len(tree.bits))
    return int(c[0]), int(c[1])
