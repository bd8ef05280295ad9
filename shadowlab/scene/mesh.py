"""Triangle-soup scenes: loading, validation and a topology report.

A :class:`Scene` is one flat triangle soup. Every format trimesh reads is
accepted; scene graphs are flattened with their transforms applied, and each
geometry becomes one *object* (``object_id`` per triangle). Polygon soup is kept
as it is: duplicated vertices, degenerate, coplanar or non-manifold triangles are
reported, never repaired, because the shadow algorithms must cope with them.
"""

from __future__ import annotations

import dataclasses
import functools
import os
from pathlib import Path

import numpy as np


class SceneError(ValueError):
    """A scene file or array that cannot be used; the message names the source."""


@dataclasses.dataclass(frozen=True)
class ObjectReport:
    """Topology of one object (one geometry of the source file)."""

    object_id: int
    name: str
    triangles: int
    closed: bool            # every edge shared by exactly two triangles, consistently
    open_edges: int         # edges used by one triangle
    nonmanifold_edges: int  # edges used by three or more triangles


@dataclasses.dataclass(frozen=True)
class SceneReport:
    """What a scene contains, for the user and for methods that can exploit it.

    ``closed`` objects allow front-face culling of shadow casters.
    """

    vertices: int
    triangles: int
    degenerate_triangles: int
    open_edges: int
    nonmanifold_edges: int
    objects: tuple[ObjectReport, ...]

    @property
    def all_closed(self) -> bool:
        return all(o.closed for o in self.objects)

    def summary(self) -> str:
        closed = sum(o.closed for o in self.objects)
        return (f"{self.triangles} triangles, {self.vertices} vertices, "
                f"{len(self.objects)} objects ({closed} closed), "
                f"{self.degenerate_triangles} degenerate, {self.open_edges} open edges, "
                f"{self.nonmanifold_edges} non-manifold edges")


@dataclasses.dataclass(frozen=True, eq=False)
class Scene:
    """A flat triangle soup.

    Attributes:
        vertices: float64 [n, 3], world units.
        faces: int32 [m, 3], indices into ``vertices``.
        object_id: int32 [m], the object each triangle belongs to.
        object_names: one name per object id.
        name: where the scene came from (a path or a generator name).
        extent: float64 [2, 3] or None: bounds to report instead of those of the used
            vertices. A subset of a scene (:meth:`subset`) keeps its parent's, so that
            lengths relative to the scene diagonal (the shadow offset) do not change.
    """

    vertices: np.ndarray
    faces: np.ndarray
    object_id: np.ndarray
    object_names: tuple[str, ...] = ("mesh",)
    name: str = "scene"
    extent: np.ndarray | None = dataclasses.field(default=None, repr=False)

    def __post_init__(self):
        v = np.ascontiguousarray(self.vertices, dtype=np.float64)
        f = np.ascontiguousarray(self.faces, dtype=np.int32)
        oid = np.ascontiguousarray(self.object_id, dtype=np.int32)
        object.__setattr__(self, "vertices", v)
        object.__setattr__(self, "faces", f)
        object.__setattr__(self, "object_id", oid)
        validate_arrays(v, f, oid, source=self.name)
        if oid.size and oid.max() >= len(self.object_names):
            names = tuple(self.object_names) + tuple(
                f"object{i}" for i in range(len(self.object_names), int(oid.max()) + 1))
            object.__setattr__(self, "object_names", names)

    @property
    def num_triangles(self) -> int:
        return int(self.faces.shape[0])

    @property
    def num_objects(self) -> int:
        return len(self.object_names)

    @functools.cached_property
    def triangles(self) -> np.ndarray:
        """float64 [m, 3, 3]: the corner positions of every triangle (computed once,
        read-only)."""
        out = self.vertices[self.faces]
        out.flags.writeable = False
        return out

    @functools.cached_property
    def bounds(self) -> np.ndarray:
        """float64 [2, 3]: the axis-aligned bounding box (min, max) of used vertices
        (``extent`` where given)."""
        if self.extent is not None:
            out = np.array(self.extent, np.float64).reshape(2, 3)
            out.flags.writeable = False
            return out
        used = self.vertices[np.unique(self.faces)]
        out = np.stack([used.min(axis=0), used.max(axis=0)])
        out.flags.writeable = False
        return out

    @property
    def diagonal(self) -> float:
        """Length of the bounding-box diagonal, world units."""
        lo, hi = self.bounds
        return float(np.linalg.norm(hi - lo))

    def report(self) -> SceneReport:
        """The mesh report (objects, closedness, ...), built once and cached on this
        scene (front-face culling asks for it every frame)."""
        if "_report_cache" not in self.__dict__:
            self.__dict__["_report_cache"] = mesh_report(self)
        return self.__dict__["_report_cache"]

    def adjacency(self, scope: str = "object", max_opposite: int = 2, dtype=np.float64):
        """The edge adjacency (:class:`shadowlab.scene.adjacency.Adjacency`), built
        once per (scope, max_opposite, dtype) and cached on this scene."""
        from .adjacency import adjacency_key, build_adjacency

        key = adjacency_key(scope, max_opposite, dtype)
        cache = self.__dict__.setdefault("_adjacency_cache", {})
        if key not in cache:
            cache[key] = build_adjacency(self, *key)
        return cache[key]

    def subset(self, keep: np.ndarray, name: str | None = None) -> "Scene":
        """The triangles where ``keep`` (bool [m]) is True, with the same vertex array,
        object ids and names, and this scene's bounds as its ``extent``."""
        keep = np.asarray(keep, bool)
        return Scene(self.vertices, self.faces[keep], self.object_id[keep],
                     self.object_names, name or self.name, extent=self.bounds)

    @staticmethod
    def concatenate(parts: list["Scene"], name: str = "scene") -> "Scene":
        """Join scenes into one soup; every part keeps its own object ids."""
        verts, faces, oids, names = [], [], [], []
        v_off = 0
        o_off = 0
        for part in parts:
            verts.append(part.vertices)
            faces.append(part.faces + v_off)
            oids.append(part.object_id + o_off)
            names.extend(part.object_names)
            v_off += len(part.vertices)
            o_off += part.num_objects
        return Scene(np.concatenate(verts), np.concatenate(faces).astype(np.int32),
                     np.concatenate(oids), tuple(names), name)


def validate_arrays(vertices: np.ndarray, faces: np.ndarray, object_id: np.ndarray,
                    source: str = "scene") -> None:
    """Raise :class:`SceneError` naming ``source`` when the arrays are unusable."""
    if vertices.ndim != 2 or vertices.shape[1] != 3:
        raise SceneError(f"{source}: vertices must have shape [n, 3], got {vertices.shape}")
    if faces.ndim != 2 or faces.shape[1] != 3:
        raise SceneError(f"{source}: faces must have shape [m, 3], got {faces.shape}")
    if faces.shape[0] == 0:
        raise SceneError(f"{source}: the mesh has no triangles")
    if object_id.shape != (faces.shape[0],):
        raise SceneError(f"{source}: object_id must have shape [{faces.shape[0]}], "
                         f"got {object_id.shape}")
    bad = ~np.isfinite(vertices).all(axis=1)
    if bad.any():
        idx = np.flatnonzero(bad)
        raise SceneError(f"{source}: {idx.size} vertices are NaN or infinite "
                         f"(first at index {idx[0]}: {vertices[idx[0]].tolist()})")
    if faces.min() < 0 or faces.max() >= vertices.shape[0]:
        row = int(np.flatnonzero((faces < 0).any(1) | (faces >= vertices.shape[0]).any(1))[0])
        raise SceneError(f"{source}: face {row} has vertex indices {faces[row].tolist()} "
                         f"out of range [0, {vertices.shape[0]})")


# Formats trimesh loads as meshes or scenes (lower-case, no dot).
SUPPORTED_FORMATS = ("obj", "ply", "stl", "off", "glb", "gltf", "dae", "3mf")


def load_scene(path: str | os.PathLike, **generator_params) -> Scene:
    """Load a mesh file, or make a procedural scene by name.

    Args:
        path: a file in a format trimesh reads (OBJ, PLY, STL, OFF, GLB/GLTF, ...),
            or the name of a procedural generator (see ``shadowlab.scene.generators()``).
        generator_params: parameters of the procedural generator (ignored for files,
            where passing any is an error).

    Returns:
        The flattened scene; each geometry of the file is one object.

    Raises:
        SceneError: missing file, unknown format, empty mesh, NaN/inf vertices,
            face indices out of range. The message names the file.
    """
    from . import procedural

    text = os.fspath(path)
    if text in procedural.GENERATORS:
        return procedural.make(text, **generator_params)
    if generator_params:
        raise SceneError(f"{text}: parameters {sorted(generator_params)} are only for "
                         f"procedural scenes ({', '.join(procedural.GENERATORS)})")
    p = Path(text)
    if not p.exists():
        hint = f"; procedural scenes are {', '.join(procedural.GENERATORS)}" if not p.suffix else ""
        raise SceneError(f"{p}: no such file{hint}")
    if p.is_dir():
        raise SceneError(f"{p}: is a directory, not a mesh file")
    ext = p.suffix.lower().lstrip(".")
    if ext not in SUPPORTED_FORMATS:
        raise SceneError(f"{p}: unknown mesh format '.{ext}'; supported: "
                         + ", ".join("." + e for e in SUPPORTED_FORMATS))
    return _load_file(p, ext)


def _load_file(p: Path, ext: str) -> Scene:
    import trimesh

    try:
        # process=False keeps the soup exactly as written (no merging, no repair).
        loaded = trimesh.load(str(p), file_type=ext, process=False, force=None)
    except Exception as exc:  # trimesh raises many exception types on bad files
        if isinstance(exc, IndexError) and "out of bounds" in str(exc):
            # numpy's message when a parser indexes the vertices with a bad face
            raise SceneError(f"{p}: face indices out of range ({exc})") from exc
        raise SceneError(f"{p}: cannot be read as .{ext}: {exc}") from exc

    parts: list[tuple[str, np.ndarray, np.ndarray]] = []
    if isinstance(loaded, trimesh.Scene):
        for node_name in loaded.graph.nodes_geometry:
            transform, geom_name = loaded.graph[node_name]
            geom = loaded.geometry[geom_name]
            if not isinstance(geom, trimesh.Trimesh):
                continue  # point clouds and paths cast no shadows
            v = trimesh.transformations.transform_points(
                np.asarray(geom.vertices, dtype=np.float64), transform)
            parts.append((str(node_name), v, np.asarray(geom.faces)))
    elif isinstance(loaded, trimesh.Trimesh):
        parts.append((p.stem, np.asarray(loaded.vertices, dtype=np.float64),
                      np.asarray(loaded.faces)))
    elif type(loaded).__name__ in ("PointCloud", "Path2D", "Path3D"):
        raise SceneError(f"{p}: the mesh is empty (no triangles; the file holds a "
                         f"{type(loaded).__name__})")
    else:
        raise SceneError(f"{p}: contains no triangle mesh (got {type(loaded).__name__})")

    parts = [(n, v, f) for n, v, f in parts if len(f)]
    if not parts:
        raise SceneError(f"{p}: the mesh is empty (no triangles)")
    verts, faces, oids, names = [], [], [], []
    offset = 0
    for i, (name, v, f) in enumerate(parts):
        f = np.asarray(f, dtype=np.int64)
        if f.ndim != 2 or f.shape[1] != 3:
            raise SceneError(f"{p}: object '{name}' has faces of shape {f.shape}, "
                             "expected triangles [m, 3]")
        if f.min() < 0 or f.max() >= len(v):
            raise SceneError(f"{p}: object '{name}' has face indices out of range "
                             f"[0, {len(v)}) (min {f.min()}, max {f.max()})")
        verts.append(v)
        faces.append(f + offset)
        oids.append(np.full(len(f), i, dtype=np.int32))
        names.append(name)
        offset += len(v)
    return Scene(np.concatenate(verts), np.concatenate(faces), np.concatenate(oids),
                 tuple(names), name=str(p))


def degenerate_mask(triangles: np.ndarray, rel_eps: float = 1e-12) -> np.ndarray:
    """bool [m]: triangles whose area is zero up to ``rel_eps`` of their squared extent.

    Args:
        triangles: float64 [m, 3, 3] corner positions.
    """
    a, b, c = triangles[:, 0], triangles[:, 1], triangles[:, 2]
    cross = np.cross(b - a, c - a)
    area2 = np.einsum("ij,ij->i", cross, cross)
    ext = np.max(np.abs(triangles - a[:, None]), axis=(1, 2))
    return area2 <= rel_eps * ext ** 4


def _edge_topology(scene: Scene, kept: np.ndarray):
    """Edges of the ``kept`` triangles (bool [m]), joined per object by exact vertex
    position (soup may duplicate vertices): the adjacency's object-scoped weld, so one
    sort serves every object.

    Returns, per undirected edge: its object, use count, and the signed sum of its
    directed uses (zero for a consistently oriented pair).
    """
    from .adjacency import weld

    faces, _, vertex_object = weld(scene, "object")
    f = faces[kept].astype(np.int64)
    directed = np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]])
    directed = directed[directed[:, 0] != directed[:, 1]]
    lo = directed.min(axis=1)
    hi = directed.max(axis=1)
    sign = np.where(directed[:, 0] < directed[:, 1], 1, -1)
    _, first, inv, counts = np.unique(lo * max(len(vertex_object), 1) + hi,
                                      return_index=True, return_inverse=True,
                                      return_counts=True)
    orient = np.bincount(inv.reshape(-1), weights=sign, minlength=len(counts))
    return vertex_object[lo[first]], counts, orient.astype(np.int64)


def mesh_report(scene: Scene) -> SceneReport:
    """Count degenerate triangles, open and non-manifold edges; find closed objects."""
    degenerate = degenerate_mask(scene.triangles)
    n_obj = len(scene.object_names)
    object_id = np.asarray(scene.object_id)
    kept = ~degenerate
    edge_obj, counts, orient = _edge_topology(scene, kept)
    per = lambda mask: np.bincount(edge_obj[mask], minlength=n_obj)  # noqa: E731
    open_edges, nonmanifold = per(counts == 1), per(counts > 2)
    inconsistent = per((counts == 2) & (orient != 0))
    triangles = np.bincount(object_id, minlength=n_obj)
    usable = np.bincount(object_id[kept], minlength=n_obj)
    objects = tuple(
        ObjectReport(oid, name, int(triangles[oid]),
                     bool(usable[oid] and open_edges[oid] == 0 and nonmanifold[oid] == 0
                          and inconsistent[oid] == 0),
                     int(open_edges[oid]), int(nonmanifold[oid]))
        for oid, name in enumerate(scene.object_names))
    return SceneReport(vertices=len(scene.vertices), triangles=scene.num_triangles,
                       degenerate_triangles=int(degenerate.sum()),
                       open_edges=int(open_edges.sum()), nonmanifold_edges=int(nonmanifold.sum()),
                       objects=objects)
