"""Edge adjacency of a triangle soup: welded vertices, edges, their triangles.

Methods that reason about edges (silhouette extraction) need, for every edge of the
soup, the triangles that share it, each with its opposite vertex and the direction
in which it traverses the edge. This module builds that once per scene and
parameter set (:meth:`shadowlab.scene.Scene.adjacency` caches it on the scene).

Construction, all vectorized with NumPy:

1. **Weld.** Vertices are cast to the working ``dtype`` and identified by exact
   equality of their coordinates (bitwise, except that -0.0 equals 0.0; scene
   vertices are finite, so there is no NaN). Under ``scope="object"`` two corners
   are welded only if they also belong to the same object (``Scene.object_id``);
   under ``scope="scene"`` across objects. Welded indices are ranks in
   lexicographic order of (object id under "object" scope, x, y, z), so comparing
   two welded indices of one object compares their positions lexicographically.
2. **Degenerate triangles are skipped:** a repeated welded vertex, or zero area
   (the cross product (b - a) x (c - a) of the welded coordinates, in float64, is
   exactly zero). A skipped triangle contributes to no edge.
3. **Edges** are sorted welded pairs (lo, hi), lo < hi. Every kept triangle
   (a, b, c) contributes three entries: edge (a, b) with opposite vertex c, (b, c)
   with a, (c, a) with b; the *sign* of an entry is +1 if the triangle traverses
   its edge from lo to hi, else -1. Entries of one edge are ordered by triangle
   index.
4. **Records.** A GPU record holds at most ``max_opposite`` = K opposite vertices.
   An edge with n adjacent triangles fills ceil(n / K) consecutive records (the
   edge is *split* when n > K); unused slots are padded.

Classification of an edge with n adjacent triangles: *open* if n = 1, *manifold*
if n = 2 with opposite signs, *non-manifold* otherwise (n > 2, or n = 2 with the
same sign: two triangles of inconsistent orientation, or two coincident copies).
"""

from __future__ import annotations

import dataclasses
from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:  # pragma: no cover
    from .mesh import Scene

SCOPES = ("object", "scene")
DTYPES = ("float32", "float64")


@dataclasses.dataclass(frozen=True)
class AdjacencyReport:
    """Counts of one adjacency build. ``open_edges + manifold_edges +
    nonmanifold_edges == edges``; ``records >= edges``, with equality iff no edge is
    split."""

    scope: str
    max_opposite: int
    dtype: str
    vertices: int              # welded vertices (used by at least one triangle)
    triangles: int             # triangles of the scene
    degenerate_triangles: int  # skipped: repeated welded vertex or zero area
    edges: int
    records: int
    split_edges: int           # edges with more than max_opposite adjacent triangles
    open_edges: int            # one adjacent triangle
    manifold_edges: int        # two, traversing the edge in opposite directions
    nonmanifold_edges: int     # more than two, or two with the same direction

    def summary(self) -> str:
        return (f"adjacency ({self.scope}, K={self.max_opposite}, {self.dtype}): "
                f"{self.vertices} welded vertices, {self.edges} edges in {self.records} "
                f"records ({self.split_edges} split), {self.open_edges} open, "
                f"{self.manifold_edges} manifold, {self.nonmanifold_edges} non-manifold, "
                f"{self.degenerate_triangles} degenerate triangles skipped")


@dataclasses.dataclass(frozen=True, eq=False)
class Adjacency:
    """Edge adjacency of a scene (all arrays read-only).

    Shapes: m triangles of the scene, V welded vertices, T kept triangles, E edges,
    R records, K = ``max_opposite``.

    Attributes:
        positions: [V, 3] ``dtype``, welded vertex positions, world units.
        vertex_object: int32 [V], the object of each welded vertex (-1 under
            ``scope="scene"``, where a vertex may be shared by several objects).
        faces: int32 [m, 3], every scene triangle in welded indices (skipped ones too).
        kept: bool [m], False for the skipped degenerate triangles.
        edge_vertices: int32 [E, 2], (lo, hi) welded indices, lo < hi, edges sorted
            lexicographically.
        edge_count: int32 [E], number of adjacent triangles of each edge (>= 1).
        edge_offsets: int64 [E + 1], edge e owns entries ``edge_offsets[e]:edge_offsets[e+1]``.
        entry_triangle: int32 [3T], scene triangle index of each entry.
        entry_opposite: int32 [3T], welded opposite vertex of each entry.
        entry_sign: int8 [3T], +1 if the triangle traverses the edge lo -> hi, else -1.
        edge_first_record: int32 [E + 1], edge e owns records
            ``edge_first_record[e]:edge_first_record[e+1]``.
        record_edge: int32 [R], the edge of each record.
        triangle: int32 [R, K], scene triangle index per slot, -1 padding.
        opposite: int32 [R, K], welded opposite vertex per slot, -1 padding.
        sign: int8 [R, K], winding sign per slot (+1 / -1), 0 padding.
        report: the counts (:class:`AdjacencyReport`).
    """

    positions: np.ndarray
    vertex_object: np.ndarray
    faces: np.ndarray
    kept: np.ndarray
    edge_vertices: np.ndarray
    edge_count: np.ndarray
    edge_offsets: np.ndarray
    entry_triangle: np.ndarray
    entry_opposite: np.ndarray
    entry_sign: np.ndarray
    edge_first_record: np.ndarray
    record_edge: np.ndarray
    triangle: np.ndarray
    opposite: np.ndarray
    sign: np.ndarray
    report: AdjacencyReport

    @property
    def record_vertices(self) -> np.ndarray:
        """int32 [R, 2]: the (lo, hi) welded vertices of each record's edge."""
        return self.edge_vertices[self.record_edge]

    @property
    def edge_class(self) -> np.ndarray:
        """int8 [E]: 1 open, 2 manifold, 3 non-manifold."""
        return _classify(self.edge_count, self.edge_offsets, self.entry_sign)


def adjacency_key(scope: str = "object", max_opposite: int = 2,
                  dtype=np.float64) -> tuple[str, int, str]:
    """The validated, normalized (scope, max_opposite, dtype name) of a build.

    Raises:
        ValueError: unknown scope or dtype, or max_opposite < 1.
    """
    if scope not in SCOPES:
        raise ValueError(f"adjacency scope must be one of {SCOPES}, got {scope!r}")
    if isinstance(max_opposite, bool) or int(max_opposite) != max_opposite or max_opposite < 1:
        raise ValueError(f"adjacency max_opposite must be an integer >= 1, got {max_opposite!r}")
    name = np.dtype(dtype).name
    if name not in DTYPES:
        raise ValueError(f"adjacency dtype must be one of {DTYPES}, got {name}")
    return scope, int(max_opposite), name


def _readonly(**arrays) -> dict:
    for a in arrays.values():
        a.flags.writeable = False
    return arrays


def _classify(count: np.ndarray, offsets: np.ndarray, entry_sign: np.ndarray) -> np.ndarray:
    """int8 [E]: 1 open, 2 manifold, 3 non-manifold (see the module docstring)."""
    cls = np.full(len(count), 3, dtype=np.int8)
    cls[count == 1] = 1
    two = np.flatnonzero(count == 2)
    opposite_dirs = entry_sign[offsets[two]] != entry_sign[offsets[two] + 1]
    cls[two[opposite_dirs]] = 2
    return cls


def weld(scene: "Scene", scope: str = "object", dtype=np.float64
         ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Weld the corners of ``scene``'s triangles by exact position.

    Returns:
        faces int32 [m, 3] welded indices, positions [V, 3] ``dtype``,
        vertex_object int32 [V] (-1 under scope "scene").
    """
    scope, _, name = adjacency_key(scope, 1, dtype)
    v = scene.vertices.astype(name)
    v = np.where(v == 0, np.zeros((), v.dtype), v)  # -0.0 -> +0.0
    used, corner_vertex = np.unique(scene.faces.reshape(-1), return_inverse=True)
    # Rank the used vertices by position (lexicographic x, y, z); equal rows share a rank.
    pos = v[used]
    order = np.lexsort((pos[:, 2], pos[:, 1], pos[:, 0]))
    sp = pos[order]
    new = np.ones(len(sp), dtype=bool)
    new[1:] = np.any(sp[1:] != sp[:-1], axis=1)
    rank = np.empty(len(sp), dtype=np.int64)
    rank[order] = np.cumsum(new) - 1
    corner_rank = rank[corner_vertex.reshape(-1)]
    if scope == "object":
        n_rank = int(rank.max()) + 1
        oid = np.repeat(scene.object_id.astype(np.int64), 3)
        key = oid * n_rank + corner_rank
    else:
        key = corner_rank
    uniq, first, inv = np.unique(key, return_index=True, return_inverse=True)
    faces = inv.reshape(-1, 3).astype(np.int32)
    positions = pos[corner_vertex.reshape(-1)[first]]
    if scope == "object":
        vertex_object = (uniq // n_rank).astype(np.int32)
    else:
        vertex_object = np.full(len(uniq), -1, dtype=np.int32)
    return faces, positions, vertex_object


def build_adjacency(scene: "Scene", scope: str = "object", max_opposite: int = 2,
                    dtype=np.float64) -> Adjacency:
    """Build the edge adjacency of ``scene`` (uncached; use ``scene.adjacency``).

    Args:
        scene: the triangle soup.
        scope: "object" (edges join only triangles of one object) or "scene".
        max_opposite: K, opposite vertices per record (>= 1; 2 as one GPU record).
        dtype: working precision of the weld, float32 or float64.
    """
    scope, k, name = adjacency_key(scope, max_opposite, dtype)
    faces, positions, vertex_object = weld(scene, scope, name)
    m = len(faces)
    p = positions.astype(np.float64)[faces]
    cross = np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0])
    repeated = ((faces[:, 0] == faces[:, 1]) | (faces[:, 1] == faces[:, 2])
                | (faces[:, 2] == faces[:, 0]))
    kept = ~(repeated | np.all(cross == 0, axis=1))
    tri = np.flatnonzero(kept).astype(np.int32)
    f = faces[tri]
    # Entries in (triangle, slot) order: slot j is edge (f[j], f[j+1]) opposite f[j+2].
    a = f.reshape(-1)
    b = f[:, [1, 2, 0]].reshape(-1)
    c = f[:, [2, 0, 1]].reshape(-1)
    lo = np.minimum(a, b).astype(np.int64)
    hi = np.maximum(a, b).astype(np.int64)
    key = lo * max(len(positions), 1) + hi
    order = np.argsort(key, kind="stable")  # stable: triangle order within an edge
    skey = key[order]
    entry_triangle = np.repeat(tri, 3)[order]
    entry_opposite = c[order].astype(np.int32)
    entry_sign = np.where(a < b, 1, -1).astype(np.int8)[order]
    uniq, starts, counts = np.unique(skey, return_index=True, return_counts=True)
    n_edges = len(uniq)
    edge_vertices = np.stack([uniq // max(len(positions), 1),
                              uniq % max(len(positions), 1)], axis=1).astype(np.int32)
    edge_offsets = np.append(starts, len(skey)).astype(np.int64)
    edge_count = counts.astype(np.int32)

    n_rec = -(-counts // k)
    edge_first_record = np.zeros(n_edges + 1, dtype=np.int64)
    np.cumsum(n_rec, out=edge_first_record[1:])
    n_records = int(edge_first_record[-1])
    record_edge = np.repeat(np.arange(n_edges, dtype=np.int32), n_rec)
    entry_edge = np.repeat(np.arange(n_edges), counts)
    within = np.arange(len(skey)) - starts[entry_edge]
    rec = edge_first_record[entry_edge] + within // k
    slot = within % k
    triangle = np.full((n_records, k), -1, dtype=np.int32)
    opposite = np.full((n_records, k), -1, dtype=np.int32)
    sign = np.zeros((n_records, k), dtype=np.int8)
    triangle[rec, slot] = entry_triangle
    opposite[rec, slot] = entry_opposite
    sign[rec, slot] = entry_sign

    cls = _classify(edge_count, edge_offsets, entry_sign)
    report = AdjacencyReport(
        scope=scope, max_opposite=k, dtype=name, vertices=len(positions), triangles=m,
        degenerate_triangles=int(m - len(tri)), edges=n_edges, records=n_records,
        split_edges=int((counts > k).sum()), open_edges=int((cls == 1).sum()),
        manifold_edges=int((cls == 2).sum()), nonmanifold_edges=int((cls == 3).sum()))
    arrays = _readonly(
        positions=positions, vertex_object=vertex_object, faces=faces, kept=kept,
        edge_vertices=edge_vertices, edge_count=edge_count, edge_offsets=edge_offsets,
        entry_triangle=entry_triangle.astype(np.int32), entry_opposite=entry_opposite,
        entry_sign=entry_sign, edge_first_record=edge_first_record.astype(np.int32),
        record_edge=record_edge, triangle=triangle, opposite=opposite, sign=sign)
    return Adjacency(report=report, **arrays)
