"""Deterministic procedural scenes, each with a default view (camera + light).

Every scene is a :class:`~shadowlab.scene.mesh.Scene` (float64 vertices in world
units, int32 faces, one object id per distinct object); Y is up and the ground, when
there is one, is object 0 (``"ground"``), a plane at y = 0 (for ``city`` and
``props``, a closed slab whose top face is y = 0, before the city's ``offset``). The
same parameters and ``seed`` always give bit-identical arrays
(``numpy.random.default_rng(seed)``).

=============  ==========================================================  ==========
name           what it stresses                                            default tris
=============  ==========================================================  ==========
sphere_grid    n x n closed UV spheres over a ground (Peciva et al. 2013's   8,098
               sphere scene); triangles per sphere and object count are
               independent knobs
gate           a near gate with bars, trees with leaf crowns, a distant      4,294
               house (Sintorn et al. 2014, Fig. 1): high-frequency depth
fuzzy          clusters of thin fur strands ("bushes"): many tiny casters    10,002
terrain        a fractal height field under a low sun (soft shadows)         18,050
blobs          marching-cubes surfaces of a sum of Gaussians over a ground   5,092
soup           degenerate, coplanar, interpenetrating, non-manifold, open    2,002
               and duplicated triangles (robustness)
atrium         columns, open arches, an open gallery and banners (the        1,686
               architectural stand-in for Pečiva 2013's Sponza)
city           closed boxes on a closed ground slab, a wall of thin posts;     732
               ``offset`` moves it far from the origin (precision);
               ``defects`` adds needles, slivers, duplicates, T-junctions
props          closed tori, capsules and cylinders resting on (touching) and  19,868
               floating over a closed ground slab: contact shadows of
               closed objects; ``triangles`` sets the size
=============  ==========================================================  ==========

Use :func:`make` (validates parameters) and :func:`default_view`; :func:`generators`
lists every generator's parameters with their defaults. Parameters are validated by
one pydantic model per generator (:func:`params_model`, built from its :class:`Param`
specifications), the same models the run configs use for ``[scene.params]``. Default views are
256 x 256, frame the interesting region, and have near/far planes fitted to the
geometry actually inside the view frustum (:func:`fit_clip_range`).

Scaling: the size parameters (``triangles_per_sphere`` and ``n``, ``leaves_per_tree``
and ``trees``, ``triangles``, ``size``, ``grid``, ``count``) scale the triangle
count as documented per generator; construction is vectorised NumPy (a Python loop
per object at most), so 10^5-10^6 triangles build in about a second. Where a scene
is made of many small casters (leaves, fur strands) their size shrinks as the count
grows so that the scene keeps its look (constant total caster area); the soup instead
spreads its defects over an area growing with their count (constant density).
"""

from __future__ import annotations

import dataclasses
import functools
import math
from typing import Annotated, Any, Callable, Mapping, Optional, Union

import numpy as np
from pydantic import (AfterValidator, BaseModel, ConfigDict, Field, StrictFloat, StrictInt, ValidationError,
                      create_model)

from . import primitives as prim
from .mesh import Scene, SceneError
from .view import Camera, PointLight, SphereLight, View

DEFAULT_RESOLUTION = (256, 256)


# --------------------------------------------------------------------------- registry

@dataclasses.dataclass(frozen=True)
class Param:
    """One generator parameter: its default, type (int or float) and inclusive range
    ``[lo, hi]`` (``None``: unbounded), enforced by :func:`params_model`.

    A default of ``None`` means "derived from the other parameters" (documented per
    generator); such a parameter also accepts ``None``.
    """

    default: Any
    kind: type = int
    lo: float | None = None
    hi: float | None = None
    doc: str = ""


@dataclasses.dataclass(frozen=True)
class Generator:
    """A procedural scene generator.

    Attributes:
        name: registry key.
        build: ``build(**params) -> Scene``; validates like :func:`make` (it is
            ``functools.partial(make, name)``), missing parameters take their defaults.
        defaults: every parameter (including ``seed``) with its default value.
        doc: one line describing the scene.
        view: ``view(scene, params) -> View``, the default camera (256 x 256) and light
            for ``scene`` built with ``params`` (a complete parameter dict).
        params: the parameter specifications (type, range, meaning).
    """

    name: str
    build: Callable[..., Scene]
    defaults: dict
    doc: str
    view: Callable[[Scene, dict], View]
    params: Mapping[str, Param] = dataclasses.field(default_factory=dict)


GENERATORS: dict[str, Generator] = {}
_BUILDERS: dict[str, Callable[..., Scene]] = {}


def _register(name: str, doc: str, params: dict[str, Param], view: Callable):
    """Decorator: register ``fn(**params) -> Scene`` as generator ``name``."""
    def deco(fn):
        _BUILDERS[name] = fn
        GENERATORS[name] = Generator(
            name=name, build=functools.partial(make, name),
            defaults={k: p.default for k, p in params.items()}, doc=doc, view=view,
            params=dict(params))
        return fn
    return deco


def generators() -> dict[str, dict]:
    """name -> {parameter: default} for every generator (for listings)."""
    return {name: dict(g.defaults) for name, g in GENERATORS.items()}


def _generator(name: str) -> Generator:
    gen = GENERATORS.get(name)
    if gen is None:
        raise SceneError(f"unknown procedural scene {name!r}; available: "
                         f"{', '.join(GENERATORS)}")
    return gen


def _finite(x: float) -> float:
    if not math.isfinite(x):
        raise ValueError("must be finite")
    return float(x)


_VEC3_ITEM = Annotated[Union[StrictInt, StrictFloat], AfterValidator(_finite)]


def _param_type(spec: Param) -> Any:
    """The pydantic type of one parameter: a strict int or finite float within
    ``[lo, hi]``, or (``kind=tuple``) three finite numbers ``[x, y, z]``; optional
    when the default is ``None``."""
    if spec.kind is tuple:
        return tuple[_VEC3_ITEM, _VEC3_ITEM, _VEC3_ITEM]
    base = StrictInt if spec.kind is int else StrictFloat
    typ = Annotated[base, Field(ge=spec.lo, le=spec.hi, allow_inf_nan=False)]
    return Optional[typ] if spec.default is None else typ


@functools.lru_cache(maxsize=None)
def params_model(name: str) -> type[BaseModel]:
    """The pydantic model of generator ``name``'s parameters (one field per
    :class:`Param`, with its default, type and inclusive range; unknown names are
    refused)."""
    gen = _generator(name)
    fields = {k: (_param_type(spec), Field(spec.default, description=spec.doc))
              for k, spec in gen.params.items()}
    return create_model(f"{name}_params", __config__=ConfigDict(extra="forbid", frozen=True),
                        **fields)


def _plain(value: Any) -> Any:
    """NumPy scalars as Python numbers (NumPy booleans stay booleans, and are refused)."""
    if isinstance(value, np.bool_):
        return bool(value)
    if isinstance(value, np.integer):
        return int(value)
    if isinstance(value, np.floating):
        return float(value)
    if isinstance(value, np.ndarray):
        return [_plain(v) for v in value.tolist()]
    return value


def _param_error(gen: Generator, err: dict) -> SceneError:
    """The SceneError for one pydantic error of a generator's parameters."""
    key = str(err["loc"][0])
    spec = gen.params[key]
    value = err["input"]
    where = f"{gen.name}: parameter {key!r}"
    ctx = err.get("ctx") or {}
    if spec.kind is tuple:
        at = f" (item {err['loc'][1]})" if len(err["loc"]) > 1 else ""
        return SceneError(f"{where} must be three finite numbers [x, y, z], got "
                          f"{value!r}{at}")
    if value is None:
        return SceneError(f"{where} must not be None")
    if isinstance(value, bool):
        return SceneError(f"{where} must be {'an integer' if spec.kind is int else 'a number'}, "
                          f"got {value!r}")
    if "ge" in ctx:
        return SceneError(f"{where} must be >= {spec.lo}, got {value}")
    if "le" in ctx:
        return SceneError(f"{where} must be <= {spec.hi}, got {value}")
    if spec.kind is int:
        return SceneError(f"{where} must be an integer, got {value!r} "
                          f"({type(value).__name__})")
    return SceneError(f"{where} must be a finite number, got {value!r}")


def resolve_params(name: str, **params) -> dict:
    """The complete, validated parameter dict of generator ``name``
    (:func:`params_model`).

    Raises:
        SceneError: unknown generator, unknown parameter (listing the allowed ones),
            or a value of the wrong type or out of range (naming the parameter).
    """
    gen = _generator(name)
    unknown = sorted(set(params) - set(gen.defaults))
    if unknown:
        raise SceneError(f"{name}: unknown parameter{'s' if len(unknown) > 1 else ''} "
                         f"{', '.join(map(repr, unknown))}; allowed: "
                         f"{', '.join(gen.defaults)}")
    try:
        model = params_model(name).model_validate({k: _plain(v) for k, v in params.items()})
    except ValidationError as exc:
        raise _param_error(gen, exc.errors()[0]) from None
    return model.model_dump()


def _scene_name(gen: Generator, params: dict) -> str:
    shown = [f"{k}={v}" for k, v in params.items() if k == "seed" or v != gen.defaults[k]]
    return f"{gen.name}({', '.join(shown)})"


def make(name: str, **params) -> Scene:
    """Build procedural scene ``name``; missing parameters take their defaults.

    The scene's name records the seed and every non-default parameter, e.g.
    ``"fuzzy(seed=0, triangles=400000)"``.

    Raises:
        SceneError: see :func:`resolve_params`; also for parameter combinations a
            generator cannot build (the message names the parameter).
    """
    gen = _generator(name)
    full = resolve_params(name, **params)
    return _BUILDERS[name](name=_scene_name(gen, full), **full)


def default_view(name: str, scene: Scene | None = None, **params) -> View:
    """The default camera and light of generator ``name``.

    Args:
        scene: the scene to frame (built from ``params`` when omitted). The near and
            far planes are always fitted to ``scene`` itself.
        params: the generator parameters the scene was built with.
    """
    gen = _generator(name)
    full = resolve_params(name, **params)
    if scene is None:
        scene = _BUILDERS[name](name=_scene_name(gen, full), **full)
    return gen.view(scene, full)


# --------------------------------------------------------------------------- helpers

class _Parts:
    """Collects meshes as objects and assembles one :class:`Scene`."""

    def __init__(self):
        self.vertices: list[np.ndarray] = []
        self.faces: list[np.ndarray] = []
        self.object_id: list[np.ndarray] = []
        self.names: list[str] = []
        self._nv = 0

    def add(self, name: str, mesh: prim.Mesh) -> None:
        """Add ``mesh`` as one object."""
        self.add_many([name], mesh, np.zeros(len(mesh[1]), dtype=np.int64))

    def add_many(self, names: list[str], mesh: prim.Mesh, local_id: np.ndarray) -> None:
        """Add ``mesh`` as ``len(names)`` objects; ``local_id`` [f] indexes ``names``."""
        v, f = mesh
        self.vertices.append(v)
        self.faces.append(np.asarray(f, dtype=np.int64) + self._nv)
        self.object_id.append(np.asarray(local_id, dtype=np.int64) + len(self.names))
        self.names.extend(names)
        self._nv += len(v)

    def scene(self, name: str) -> Scene:
        faces = np.concatenate(self.faces)
        if self._nv > np.iinfo(np.int32).max:
            raise SceneError(f"{name}: {self._nv} vertices do not fit int32 face indices")
        return Scene(np.concatenate(self.vertices), faces.astype(np.int32),
                     np.concatenate(self.object_id).astype(np.int32), tuple(self.names), name)


def _ground(parts: _Parts, x_range, z_range) -> None:
    """The ground: a horizontal rectangle at y = 0 (two triangles, normal +Y)."""
    parts.add("ground", prim.quad_grid(x_range, z_range, 0.0))


def _ground_slab(parts: _Parts, half: float, thickness: float) -> None:
    """The ground as a closed slab: a box [-half, half] in x and z whose top face is
    y = 0, ``thickness`` deep (12 triangles)."""
    parts.add("ground", prim.box((-half, -thickness, -half), (half, 0.0, half)))


def _scatter(rng: np.random.Generator, k: int, x_range, z_range,
             fill: float = 0.6) -> np.ndarray:
    """float64 [k, 2]: k well-separated random (x, z) points in a rectangle.

    One point per randomly chosen cell of a jittered grid with about k / fill cells, so
    points never share a cell (cost O(k), no rejection loop).
    """
    (x0, x1), (z0, z1) = x_range, z_range
    cells = max(k, math.ceil(k / fill))
    nx = max(1, round(math.sqrt(cells * (x1 - x0) / (z1 - z0))))
    nz = math.ceil(cells / nx)
    chosen = rng.choice(nx * nz, size=k, replace=False)
    jitter = 0.15 + 0.7 * rng.random((k, 2))
    cx = (chosen % nx + jitter[:, 0]) / nx
    cz = (chosen // nx + jitter[:, 1]) / nz
    return np.stack([x0 + cx * (x1 - x0), z0 + cz * (z1 - z0)], axis=1)


def _unit(v: np.ndarray) -> np.ndarray:
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


def _content_bounds(scene: Scene) -> np.ndarray:
    """float64 [2, 3]: bounds of everything but the ground (object 0 named "ground")."""
    keep = scene.object_id != 0 if scene.object_names[0] == "ground" else \
        np.ones(scene.num_triangles, bool)
    if not keep.any():
        keep[:] = True
    used = np.zeros(len(scene.vertices), bool)
    used[scene.faces[keep].reshape(-1)] = True
    pts = scene.vertices[used]
    return np.stack([pts.min(axis=0), pts.max(axis=0)])


def _content_frame(scene: Scene) -> tuple[float, float, float, float]:
    """(cx, cz, w, top) of :func:`_content_bounds`: the centre of its x and z ranges,
    half the larger of the two, and its largest y (the default views are placed
    relative to these)."""
    (x0, _, z0), (x1, y1, z1) = _content_bounds(scene)
    return 0.5 * (x0 + x1), 0.5 * (z0 + z1), 0.5 * max(x1 - x0, z1 - z0), y1


# --------------------------------------------------------------------------- framing

def fit_clip_range(scene: Scene, eye, target, up=(0.0, 1.0, 0.0), fov_y_deg: float = 50.0,
                   aspect: float = 1.0, margin: float = 0.03, max_ratio: float = 1e4,
                   chunk: int = 1 << 16) -> tuple[float, float]:
    """Near and far distances that bracket the geometry inside a view frustum.

    The exact depth range (along the view axis) of the scene clipped to the infinite
    pyramid of the camera is the range over three candidate point sets: vertices
    inside the pyramid, crossings of triangle edges with its four side planes, and hits
    of its four corner rays on triangles. ``near`` is that minimum shrunk by
    ``margin``, ``far`` the maximum grown by it; ``far / near <= max_ratio``.

    Args:
        scene: the geometry.
        eye, target, up: camera placement (3 floats each).
        fov_y_deg: vertical field of view, degrees; aspect: width / height.

    Returns:
        (near, far) in world units.

    Raises:
        SceneError: no triangle is inside the view.
    """
    cam = Camera(eye, target, up, fov_y_deg, 1.0, 2.0, (1, 1))
    right, cam_up, back = cam.basis()
    to_view = np.stack([right, cam_up, -back])            # rows: x right, y up, z depth
    ty = math.tan(math.radians(fov_y_deg) / 2)
    tx = ty * aspect
    planes = np.array([[1.0, 0, -tx], [-1.0, 0, -tx], [0, 1.0, -ty], [0, -1.0, -ty]])
    corners = np.array([[sx * tx, sy * ty, 1.0] for sx in (-1, 1) for sy in (-1, 1)])
    verts = (scene.vertices - cam.eye) @ to_view.T
    tol = 1e-9

    def inside(p):                                       # p [..., 3] -> bool [...]
        return np.all(p @ planes.T <= tol * np.abs(p).sum(-1, keepdims=True), axis=-1)

    lo, hi = np.inf, -np.inf
    used = np.zeros(len(verts), bool)
    used[scene.faces.reshape(-1)] = True
    v_in = verts[used & inside(verts)]
    if len(v_in):
        lo, hi = v_in[:, 2].min(), v_in[:, 2].max()
    # Only triangles with vertices on both sides of some side plane can add edge
    # crossings or corner-ray hits; those outside one plane entirely add nothing.
    side = (verts @ planes.T > 0)[scene.faces]                          # [m, 3, 4]
    straddle = np.flatnonzero(side.any(axis=(1, 2)) & ~side.all(axis=1).any(axis=1))
    for start in range(0, len(straddle), chunk):
        tri = verts[scene.faces[straddle[start:start + chunk]]]        # [c, 3, 3]
        a, b = tri, np.roll(tri, -1, axis=1)                           # edges a -> b
        sa, sb = a @ planes.T, b @ planes.T                            # [c, 3, 4]
        crossing = sa * sb < 0
        if crossing.any():
            ci = np.nonzero(crossing)
            t = sa[ci] / (sa[ci] - sb[ci])
            pa, pb = a[ci[0], ci[1]], b[ci[0], ci[1]]
            pts = pa + t[:, None] * (pb - pa)
            z = pts[inside(pts), 2]
            if len(z):
                lo, hi = min(lo, z.min()), max(hi, z.max())
        e1, e2 = tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]
        s = -tri[:, 0]
        q = np.cross(s, e1)
        for d in corners:                                              # Moller-Trumbore
            p = np.cross(d, e2)
            det = np.einsum("ij,ij->i", e1, p)
            ok = np.abs(det) > 1e-300
            inv = np.where(ok, 1.0 / np.where(ok, det, 1.0), 0.0)
            u = np.einsum("ij,ij->i", s, p) * inv
            v = (q @ d) * inv
            t = np.einsum("ij,ij->i", e2, q) * inv
            hit = ok & (u >= 0) & (v >= 0) & (u + v <= 1) & (t > 0)
            if hit.any():
                lo, hi = min(lo, t[hit].min()), max(hi, t[hit].max())  # depth = t * d.z
    if not np.isfinite(hi) or hi <= 0:
        raise SceneError(f"{scene.name}: no geometry inside the view from {cam.eye.tolist()}")
    far = hi * (1 + margin)
    near = max(lo * (1 - margin), far / max_ratio)
    return float(near), float(far)


def clip_ranges(scene: Scene, cameras) -> list[tuple[float, float] | None]:
    """:func:`fit_clip_range` per camera (repeated placements computed once); None where
    no geometry is in view."""
    cache: dict[tuple, tuple[float, float] | None] = {}
    out = []
    for cam in cameras:
        key = (tuple(cam.eye), tuple(cam.target), tuple(cam.up), cam.fov_y_deg, cam.aspect)
        if key not in cache:
            try:
                cache[key] = fit_clip_range(scene, cam.eye, cam.target, cam.up,
                                            cam.fov_y_deg, cam.aspect)
            except SceneError:
                cache[key] = None
        out.append(cache[key])
    return out


def refit_clip(scene: Scene, views, per_frame: bool = True) -> list[View]:
    """``views`` with near and far fitted to the geometry in view: per frame
    (``per_frame``, what a renderer's projection does as the camera moves), or one range
    over all frames. A frame with nothing in view keeps the range over all frames.

    Raises:
        SceneError: no geometry is in view in any frame.
    """
    views = list(views)
    ranges = clip_ranges(scene, [v.camera for v in views])
    found = [r for r in ranges if r is not None]
    if not found:
        raise SceneError("no geometry of the scene is inside the view in any frame")
    union = (min(r[0] for r in found), max(r[1] for r in found))
    return [View(v.camera.replace(near=(r if per_frame and r else union)[0],
                                  far=(r if per_frame and r else union)[1]), v.light)
            for v, r in zip(views, ranges)]


def framed_view(scene: Scene, eye, target, light, fov_y_deg: float = 50.0,
                resolution: tuple[int, int] = DEFAULT_RESOLUTION) -> View:
    """A :class:`View` looking from ``eye`` at ``target`` (Y up) with near/far fitted
    to ``scene`` by :func:`fit_clip_range`."""
    aspect = resolution[0] / resolution[1]
    near, far = fit_clip_range(scene, eye, target, (0.0, 1.0, 0.0), fov_y_deg, aspect)
    cam = Camera(eye=eye, target=target, up=(0.0, 1.0, 0.0), fov_y_deg=fov_y_deg,
                 near=near, far=far, resolution=resolution)
    return View(cam, light)


# --------------------------------------------------------------------------- sphere_grid

SPHERE_RADIUS = 1.0     # world units
SPHERE_SPACING = 3.0    # centre to centre
SPHERE_LIFT = 0.5       # gap between a sphere's bottom and the ground


def _sphere_grid_view(scene: Scene, params: dict) -> View:
    cx, cz, w, y1 = _content_frame(scene)                  # w: half width of the grid
    eye = (cx, 1.5 * w + y1, cz + 2.0 * w + 2.0)
    light = PointLight((cx + 0.8 * w, 2.5 * w + 2 * y1, cz - 0.4 * w))
    return framed_view(scene, eye, (cx, 0.0, cz + 0.1 * w), light)


@_register(
    "sphere_grid",
    "n x n closed UV spheres over a ground quad, lit by a point light above "
    "(Peciva et al. 2013 sphere scene)",
    {"n": Param(4, int, 1, 1000, "spheres per side of the grid"),
     "triangles_per_sphere": Param(512, int, 6, 10_000_000,
                                   "target triangles per sphere (UV sphere, ~)"),
     "objects": Param(None, int, 1, None,
                      "objects the sphere geometry is divided into (None: one per sphere)"),
     "seed": Param(0, int, 0, None, "unused: the grid is regular")},
    _sphere_grid_view)
def _sphere_grid(name: str, n: int, triangles_per_sphere: int, objects: int | None,
                 seed: int) -> Scene:
    """n x n unit spheres, centres 3 units apart, floating 0.5 above a ground quad.

    Each sphere is a closed UV sphere with ``stacks``, ``slices`` from
    :func:`~shadowlab.scene.primitives.sphere_resolution` (``2 slices (stacks-1)``
    triangles, within ~2% of ``triangles_per_sphere`` from 100 up). Triangles:
    ``n^2 * 2 slices (stacks-1) + 2``.

    ``objects`` divides the sphere geometry (the ground is always one more object,
    id 0) without changing it:

    * ``objects <= n^2``: spheres are merged, sphere s (row-major) going to object
      ``floor(s objects / n^2)``; every object is a union of whole, closed spheres.
    * ``objects > n^2``: each sphere is cut into ``floor((s+1) objects / n^2) -
      floor(s objects / n^2)`` pieces of (almost) equal numbers of consecutive faces,
      i.e. latitude bands from north to south (open surfaces); at most
      ``n^2 * 2 slices (stacks-1)`` objects.
    """
    stacks, slices = prim.sphere_resolution(triangles_per_sphere)
    sv, sf = prim.uv_sphere(stacks, slices)
    k, per = n * n, len(sf)
    coords = (np.arange(n) - (n - 1) / 2) * SPHERE_SPACING
    gx, gz = np.meshgrid(coords, coords, indexing="ij")
    centres = np.stack([gx.ravel(), np.full(k, SPHERE_RADIUS + SPHERE_LIFT), gz.ravel()], 1)
    mesh = prim.instances(sv, sf, centres, SPHERE_RADIUS)
    objects = k if objects is None else objects
    if objects > k * per:
        raise SceneError(f"{name}: parameter 'objects' = {objects} exceeds the {k * per} "
                         f"sphere triangles")
    label = [f"sphere_{i}_{j}" for i in range(n) for j in range(n)]
    if objects <= k:
        sphere_obj = np.arange(k) * objects // k
        local = np.repeat(sphere_obj, per)
        names = label if objects == k else [f"spheres{o}" for o in range(objects)]
    else:
        first = np.arange(k + 1) * objects // k                 # first object of sphere s
        count = np.diff(first)
        piece = np.arange(per)[None, :] * count[:, None] // per   # [k, per]
        local = (first[:-1, None] + piece).reshape(-1)
        owner = np.repeat(np.arange(k), count)
        names = [f"{label[s]}.part{o - first[s]}" for o, s in enumerate(owner)]
    parts = _Parts()
    half = 0.5 * n * SPHERE_SPACING
    _ground(parts, (-6 * half, 6 * half), (-6 * half, 6 * half))
    parts.add_many(names, mesh, local)
    return parts.scene(name)


# --------------------------------------------------------------------------- gate

GATE_Z = 3.0            # the gate's plane; the camera stands at z = 7.5
HOUSE_Z = (-40.0, -32.0)
TREE_X = (-14.0, 14.0)
TREE_Z = (-28.0, -4.0)
TREE_GAP = 2.5          # no tree trunk within this distance of x = 0


def _gate_view(scene: Scene, params: dict) -> View:
    light = PointLight((35.0, 24.0, 8.0))
    return framed_view(scene, (0.3, 2.0, 9.5), (0.0, 1.2, -30.0), light, fov_y_deg=55.0)


@_register(
    "gate",
    "a near gate with bars, trees with leaf crowns and a distant house "
    "(Sintorn et al. 2014, Fig. 1): high-frequency depth",
    {"trees": Param(12, int, 0, 100_000, "trees between the gate and the house"),
     "leaves_per_tree": Param(300, int, 0, 10_000_000, "leaf triangles per crown"),
     "bars": Param(9, int, 0, 10_000, "vertical bars of the gate"),
     "seed": Param(0, int, 0, None, "random seed (tree placement and leaves)")},
    _gate_view)
def _gate(name: str, trees: int, leaves_per_tree: int, bars: int, seed: int) -> Scene:
    """A gate 4.5 units in front of the camera, trees, and a house ~40 units away.

    Objects: ground; gate posts, lintel, two rails and ``bars`` bars (closed boxes);
    house walls, door, chimney (boxes) and gabled roof (closed prism); per tree a
    trunk (closed 10-sided cylinder) and a crown of ``leaves_per_tree`` single-triangle
    leaves with random orientations inside an ellipsoid. Leaf size scales as
    ``(300 / leaves_per_tree)^(1/2)`` so a crown's leaf area stays constant.
    Triangles: ``2 + 12 (5 + bars) + 44 + trees (40 + leaves_per_tree)``.
    """
    rng = np.random.default_rng(seed)
    parts = _Parts()
    _ground(parts, (-80.0, 80.0), (-110.0, 14.0))

    z0, z1 = GATE_Z - 0.15, GATE_Z + 0.15
    parts.add("gate.post_left", prim.box((-2.25, 0.0, z0), (-1.9, 3.3, z1)))
    parts.add("gate.post_right", prim.box((1.9, 0.0, z0), (2.25, 3.3, z1)))
    parts.add("gate.lintel", prim.box((-2.5, 3.3, z0 - 0.05), (2.5, 3.65, z1 + 0.05)))
    rails_lo = np.array([[-1.9, 0.35, GATE_Z - 0.05], [-1.9, 2.75, GATE_Z - 0.05]])
    parts.add_many(["gate.rail_low", "gate.rail_high"],
                   prim.boxes(rails_lo, rails_lo + [3.8, 0.12, 0.1]), np.repeat([0, 1], 12))
    if bars:
        bx = np.linspace(-1.9, 1.9, bars + 2)[1:-1]
        lo = np.stack([bx - 0.03, np.zeros(bars), np.full(bars, GATE_Z - 0.03)], 1)
        parts.add_many([f"gate.bar{i}" for i in range(bars)],
                       prim.boxes(lo, lo + [0.06, 3.3, 0.06]), np.repeat(np.arange(bars), 12))

    (hz0, hz1) = HOUSE_Z
    parts.add("house.walls", prim.box((-6.0, 0.0, hz0), (6.0, 4.5, hz1)))
    parts.add("house.door", prim.box((-0.8, 0.0, hz1), (0.8, 2.3, hz1 + 0.12)))
    parts.add("house.roof", prim.gable_prism((-6.6, 4.5, hz0 - 0.6), (6.6, 7.6, hz1 + 0.6)))
    parts.add("house.chimney", prim.box((2.6, 5.0, hz0 + 1.8), (3.4, 8.4, hz0 + 2.6)))

    if trees:
        xz = _scatter(rng, trees, (TREE_X[0] + TREE_GAP, TREE_X[1] - TREE_GAP), TREE_Z)
        xz[:, 0] += np.sign(xz[:, 0]) * TREE_GAP          # keep a corridor to the house
        trunk_h = rng.uniform(2.4, 4.2, trees)
        trunk_r = rng.uniform(0.14, 0.25, trees)
        crown_r = rng.uniform(1.7, 2.6, trees)
        crown_c = np.stack([xz[:, 0], trunk_h + 0.6 * crown_r, xz[:, 1]], 1)
        cv, cf = prim.cylinder(10)
        trunks = prim.instances(cv, cf, np.stack([xz[:, 0], np.zeros(trees), xz[:, 1]], 1),
                                np.stack([trunk_r, trunk_h + 0.5 * crown_r, trunk_r], 1))
        parts.add_many([f"tree{t}.trunk" for t in range(trees)], trunks,
                       np.repeat(np.arange(trees), len(cf)))
        if leaves_per_tree:
            m = trees * leaves_per_tree
            owner = np.repeat(np.arange(trees), leaves_per_tree)
            d = _unit(rng.normal(size=(m, 3)))
            rad = rng.random(m) ** 0.25                 # leaves favour the crown's shell
            radii = crown_r[owner, None] * np.array([1.0, 0.85, 1.0])
            centre = crown_c[owner] + d * rad[:, None] * radii
            size = 0.45 * math.sqrt(300 / leaves_per_tree) * rng.uniform(0.7, 1.3, m)
            leaf = np.array([[0.0, 0.6, 0.0], [-0.35, -0.3, 0.0], [0.35, -0.3, 0.0]])
            rot = prim.random_rotations(rng, m)
            corners = centre[:, None] + size[:, None, None] * np.einsum("mij,vj->mvi", rot, leaf)
            parts.add_many([f"tree{t}.crown" for t in range(trees)],
                           prim.triangle_soup(corners), owner)
    return parts.scene(name)


# --------------------------------------------------------------------------- fuzzy

def _fuzzy_view(scene: Scene, params: dict) -> View:
    cx, cz, w, y1 = _content_frame(scene)
    eye = (cx, 1.4 * w + y1, cz + 1.3 * w + 1.0)
    light = PointLight((cx - 1.2 * w, 1.3 * w + 2 * y1, cz - 0.6 * w))
    return framed_view(scene, eye, (cx, 0.0, cz + 0.05 * w), light)


@_register(
    "fuzzy",
    "clusters of thin fur strands (bushes) over a ground: many tiny, dense casters",
    {"triangles": Param(10_000, int, 1, 100_000_000, "fur strands (one triangle each)"),
     "clusters": Param(6, int, 1, 100_000, "bushes"),
     "seed": Param(0, int, 0, None, "random seed")},
    _fuzzy_view)
def _fuzzy(name: str, triangles: int, clusters: int, seed: int) -> Scene:
    """Bushes of fur strands over a ground.

    Bush centres are scattered over a square of side ``4.4 sqrt(clusters) + 2``; bush
    radius R in [1.5, 2.4]. A strand is one thin triangle from a base near the bush
    centre out to a tip at distance 0.35-1 R, in a random direction (never below the
    ground). Strand width ``0.04 R sqrt(10^4 / triangles)`` keeps the total strand
    area constant. Triangles: ``triangles + 2``; objects: ground + one per bush.
    """
    if clusters > triangles:
        raise SceneError(f"{name}: parameter 'clusters' = {clusters} exceeds "
                         f"'triangles' = {triangles}")
    rng = np.random.default_rng(seed)
    half = 2.2 * math.sqrt(clusters) + 1.0
    xz = _scatter(rng, clusters, (-half, half), (-half, half))
    radius = rng.uniform(1.5, 2.4, clusters)
    centre = np.stack([xz[:, 0], 0.55 * radius, xz[:, 1]], 1)
    owner = np.repeat(np.arange(clusters), np.diff(np.arange(clusters + 1) * triangles // clusters))
    r = radius[owner, None]
    d = _unit(rng.normal(size=(triangles, 3)))
    d[:, 1] = np.where(d[:, 1] < -0.3, -d[:, 1], d[:, 1])         # keep tips above ground
    base = centre[owner] + 0.2 * r * _unit(rng.normal(size=(triangles, 3))) \
        * rng.random((triangles, 1)) ** (1 / 3)
    tip = base + d * r * rng.uniform(0.35, 1.0, (triangles, 1))
    side = _unit(np.cross(d, rng.normal(size=(triangles, 3))))
    width = 0.04 * r * math.sqrt(1e4 / triangles)
    corners = np.stack([base - 0.5 * width * side, base + 0.5 * width * side, tip], 1)
    parts = _Parts()
    g = 4 * half
    _ground(parts, (-g, g), (-g, g))
    parts.add_many([f"bush{c}" for c in range(clusters)], prim.triangle_soup(corners), owner)
    return parts.scene(name)


# --------------------------------------------------------------------------- terrain

TERRAIN_EXTENT = 100.0      # world units per side, centred on the origin
SUN_ELEVATION_DEG = 10.0
SUN_AZIMUTH_DEG = 35.0      # measured from +x towards -z (the sun is to the right, behind)


def _terrain_view(scene: Scene, params: dict) -> View:
    el, az = math.radians(SUN_ELEVATION_DEG), math.radians(SUN_AZIMUTH_DEG)
    to_sun = np.array([math.cos(el) * math.cos(az), math.sin(el), -math.cos(el) * math.sin(az)])
    light = SphereLight(direction=-to_sun, angular_radius_deg=0.27)
    e = TERRAIN_EXTENT
    y1 = scene.bounds[1, 1]
    return framed_view(scene, (0.0, 0.45 * e + y1, 0.62 * e), (0.0, 0.0, 0.0), light,
                       fov_y_deg=50.0)


@_register(
    "terrain",
    "a fractal height field (random Fourier modes, 5 octaves) under a low sun "
    "(SphereLight, 10 degrees elevation, 0.27 degrees radius)",
    {"size": Param(96, int, 2, 20_000, "grid vertices per side"),
     "height": Param(14.0, float, 0.0, 1e4, "peak height, world units (100 x 100 extent)"),
     "seed": Param(0, int, 0, None, "random seed")},
    _terrain_view)
def _terrain(name: str, size: int, height: float, seed: int) -> Scene:
    """A height field over [-50, 50]^2 (one open object, normals up).

    ``h = height * s^1.3`` with s the sum of 5 octaves (wavelengths 80 .. 5 units,
    amplitude halving per octave) of 6 random plane waves each, rescaled to [0, 1]
    over the grid samples; the surface does not depend on ``size`` apart from this
    rescaling and its sampling. Triangles: ``2 (size - 1)^2``.
    """
    rng = np.random.default_rng(seed)
    octaves, modes = 5, 6
    e = TERRAIN_EXTENT
    axis = np.linspace(-e / 2, e / 2, size)
    zz, xx = np.meshgrid(axis, axis, indexing="ij")
    h = np.zeros((size, size))
    for o in range(octaves):
        freq = 2 ** o / 80.0
        angle = rng.uniform(0, 2 * np.pi, modes)
        phase = rng.uniform(0, 2 * np.pi, modes)
        for a, p in zip(angle, phase):
            h += 0.5 ** o * np.cos(2 * np.pi * freq * (math.cos(a) * xx + math.sin(a) * zz) + p)
    span = h.max() - h.min()
    s = (h - h.min()) / span if span > 0 else np.zeros_like(h)
    parts = _Parts()
    parts.add("terrain", prim.height_grid(height * s ** 1.3, (-e / 2, e / 2), (-e / 2, e / 2)))
    return parts.scene(name)


# --------------------------------------------------------------------------- blobs

BLOB_BOX = 10.0             # side of the cube the blobs live in, world units
BLOB_LIFT = 0.6             # gap between the cube's bottom and the ground


def _blobs_view(scene: Scene, params: dict) -> View:
    cx, cz, w, y1 = _content_frame(scene)
    eye = (cx + 0.6 * w, y1 + 1.5 * w, cz + 2.8 * w)
    light = PointLight((cx - 0.6 * w, y1 + 3.5 * w, cz - 0.2 * w))
    return framed_view(scene, eye, (cx, 0.3 * y1, cz), light)


@_register(
    "blobs",
    "organic closed surfaces: marching cubes of a sum of random Gaussian blobs, "
    "above a ground",
    {"grid": Param(32, int, 4, 2048, "voxels per side of the sampling grid"),
     "blobs": Param(16, int, 1, 100_000, "Gaussian blobs in the field"),
     "seed": Param(0, int, 0, None, "random seed")},
    _blobs_view)
def _blobs(name: str, grid: int, blobs: int, seed: int) -> Scene:
    """Iso-surface 0.5 of ``sum_i exp(-|p - c_i|^2 / (2 s_i^2))`` over a 10-unit cube.

    Centres c_i are uniform in the inner 70% of the cube, s_i in [0.05, 0.11] of its
    side. The field is sampled on ``grid^3`` voxel centres and padded with zeros, so
    every surface is closed (each connected component is one object, wound outward).
    Triangles grow as ``grid^2`` (with the default blobs and seed: 5.1k at grid 32,
    20.6k at 64, 82.5k at 128, 330k at 256).
    """
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components
    from skimage.measure import marching_cubes

    rng = np.random.default_rng(seed)
    centre = rng.uniform(0.15, 0.85, (blobs, 3))
    sigma = rng.uniform(0.05, 0.11, blobs)
    x = (np.arange(grid) + 0.5) / grid
    field = np.zeros((grid, grid, grid))
    for c, s in zip(centre, sigma):           # separable Gaussian: outer product per blob
        g = [np.exp(-(x - ci) ** 2 / (2 * s * s)) for ci in c]
        field += g[0][:, None, None] * g[1][None, :, None] * g[2][None, None, :]
    vol = np.pad(field, 1)
    if vol.max() <= 0.5:
        raise SceneError(f"{name}: parameter 'grid' = {grid} is too coarse to resolve "
                         "any blob")
    verts, faces, _, _ = marching_cubes(vol, 0.5, allow_degenerate=False)
    verts = (verts - 0.5) / grid                               # voxel centres -> [0, 1]
    if prim.signed_volume(verts, faces) < 0:
        faces = faces[:, ::-1]
    n_comp, label = connected_components(
        coo_matrix((np.ones(3 * len(faces)), (np.repeat(faces[:, 0], 3),
                                              faces.reshape(-1))), shape=(len(verts),) * 2),
        directed=False)
    world = (verts - [0.5, 0.0, 0.5]) * BLOB_BOX + [0.0, BLOB_LIFT, 0.0]
    parts = _Parts()
    _ground(parts, (-5 * BLOB_BOX, 5 * BLOB_BOX), (-5 * BLOB_BOX, 5 * BLOB_BOX))
    parts.add_many([f"blob{c}" for c in range(n_comp)], (world, faces), label[faces[:, 0]])
    return parts.scene(name)


# --------------------------------------------------------------------------- soup

def _soup_view(scene: Scene, params: dict) -> View:
    cx, cz, w, y1 = _content_frame(scene)
    eye = (cx, y1 + 1.2 * w, cz + 1.7 * w)
    light = PointLight((cx + 0.7 * w, y1 + 2.0 * w, cz + 0.3 * w))
    return framed_view(scene, eye, (cx, 0.0, cz - 0.05 * w), light)


def _frames(rng: np.random.Generator, k: int, half: float, size=(0.4, 1.0)):
    """Random placements: centres [k, 3] over the soup area (y in [0.3, 3.5]),
    rotations [k, 3, 3] and sizes [k]."""
    c = np.stack([rng.uniform(-half, half, k), rng.uniform(0.3, 3.5, k),
                  rng.uniform(-half, half, k)], 1)
    return c, prim.random_rotations(rng, k), rng.uniform(*size, k)


def _place(local: np.ndarray, centre, rot, size) -> np.ndarray:
    """World corners [k, v, 3] of local shapes [k, v, 3] (or [v, 3])."""
    local = np.broadcast_to(local, (len(centre),) + np.shape(local)[-2:])
    return centre[:, None] + size[:, None, None] * np.einsum("kij,kvj->kvi", rot, local)


@_register(
    "soup",
    "robustness stress test: degenerate, coplanar overlapping, interpenetrating, "
    "non-manifold, open and duplicated triangles over a ground",
    {"count": Param(100, int, 1, 10_000_000, "instances of each defect kind"),
     "seed": Param(0, int, 0, None, "random seed")},
    _soup_view)
def _soup(name: str, count: int, seed: int) -> Scene:
    """Polygon soup with every defect the shadow methods must survive.

    Each kind is one object holding ``count`` instances (c = count) scattered above
    the ground over a square of side ``16 sqrt(c / 100)`` (sizes 0.4-1, centres at
    heights 0.3-3.5, so a few instances also cut through the ground):

    * ``degenerate`` (c triangles): repeated vertex (a, a, b), all three equal,
      collinear (a, a + d, a + 2.5 d), cycling in that order.
    * ``coplanar`` (2c): pairs overlapping in one plane; every 4th pair lies on the
      ground plane y = 0 (coplanar with the ground too).
    * ``interpenetrating`` (2c): pairs crossing each other's interior.
    * ``nonmanifold`` (3c): three triangles sharing one edge (a "book").
    * ``open`` (10c): boxes without a lid (4 open edges each).
    * ``duplicated`` (2c): exact copies of a triangle; odd instances reversed.

    Triangles: ``20 c + 2``.
    """
    rng = np.random.default_rng(seed)
    c = count
    half = 8.0 * math.sqrt(c / 100)
    parts = _Parts()
    _ground(parts, (-3 * half, 3 * half), (-3 * half, 3 * half))

    # degenerate: zero-area triangles of three kinds
    a, _, size = _frames(rng, c, half)
    d = _unit(rng.normal(size=(c, 3))) * size[:, None]
    kind = np.arange(c) % 3
    b = np.where((kind == 1)[:, None], a, a + d)
    third = np.where((kind == 2)[:, None], a + 2.5 * d, np.where((kind == 1)[:, None], a, b))
    second = np.where((kind == 2)[:, None], a + d, a)
    parts.add("degenerate", prim.triangle_soup(np.stack([a, second, third], 1)))

    # coplanar: a triangle and a rotated, shifted copy in the same plane
    tri = np.array([[0.0, 0.0, 0.8], [-0.7, 0.0, -0.4], [0.7, 0.0, -0.4]])   # in y = 0
    centre, rot, size = _frames(rng, c, half)
    ground = np.arange(c) % 4 == 0
    rot[ground] = np.eye(3)
    centre[ground, 1] = 0.0
    ang = rng.uniform(0.3, 2.5, c)
    spin = np.zeros((c, 3, 3))
    spin[:, 0, 0] = spin[:, 2, 2] = np.cos(ang)
    spin[:, 0, 2], spin[:, 2, 0] = np.sin(ang), -np.sin(ang)
    spin[:, 1, 1] = 1.0
    shift = np.stack([rng.uniform(-0.3, 0.3, c), np.zeros(c), rng.uniform(-0.3, 0.3, c)], 1)
    second_local = np.einsum("kij,vj->kvi", spin, tri) + shift[:, None]
    pairs = np.stack([_place(tri, centre, rot, size), _place(second_local, centre, rot, size)], 1)
    parts.add("coplanar", prim.triangle_soup(pairs.reshape(-1, 3, 3)))

    # interpenetrating: one triangle in the local xy plane, one in xz crossing it
    pair = np.array([[[-1.0, -0.8, 0.0], [1.0, -0.8, 0.0], [0.0, 1.0, 0.0]],
                     [[-0.5, 0.1, -1.0], [0.5, 0.1, -1.0], [0.0, 0.1, 1.0]]])
    centre, rot, size = _frames(rng, c, half)
    placed = _place(pair.reshape(-1, 3), centre, rot, size)
    parts.add("interpenetrating", prim.triangle_soup(placed.reshape(-1, 3, 3)))

    # non-manifold: three wings on the shared edge p = (0,-1,0), q = (0,1,0)
    wing_angles = np.array([0.0, 2.1, 4.0])
    wings = np.stack([np.cos(wing_angles), np.zeros(3), np.sin(wing_angles)], 1)
    local = np.concatenate([[[0.0, -1.0, 0.0], [0.0, 1.0, 0.0]], wings])   # 5 vertices
    centre, rot, size = _frames(rng, c, half)
    verts = _place(local, centre, rot, size).reshape(-1, 3)
    faces = (np.array([[0, 1, 2], [0, 1, 3], [1, 0, 4]])[None]
             + 5 * np.arange(c)[:, None, None]).reshape(-1, 3)
    parts.add("nonmanifold", (verts, faces.astype(np.int32)))

    # open: unit boxes without their top (+y) faces
    bv, bf = prim.box((-0.5, -0.5, -0.5), (0.5, 0.5, 0.5))
    bf = np.delete(bf, [6, 7], axis=0)
    centre, rot, size = _frames(rng, c, half)
    verts = _place(bv, centre, rot, size).reshape(-1, 3)
    faces = (bf[None].astype(np.int64) + 8 * np.arange(c)[:, None, None]).reshape(-1, 3)
    parts.add("open", (verts, faces.astype(np.int32)))

    # duplicated: the same three vertices used twice (odd instances reversed)
    centre, rot, size = _frames(rng, c, half)
    verts = _place(tri, centre, rot, size).reshape(-1, 3)
    base = 3 * np.arange(c)[:, None] + np.array([0, 1, 2])
    dup = np.where((np.arange(c) % 2 == 1)[:, None], base[:, ::-1], base)
    faces = np.stack([base, dup], 1).reshape(-1, 3)
    parts.add("duplicated", (verts, faces.astype(np.int32)))
    return parts.scene(name)


# --------------------------------------------------------------------------- atrium

def _arch_band(x0: float, x1: float, z_c: float, radius: float, thickness: float,
               y0: float, segments: int) -> prim.Mesh:
    """An open semicircular arch in the plane x = x0 .. x1 spanning z_c +- radius at
    springing height y0: the curved underside (intrados) and the front face (a
    half annulus of ``thickness``), without back face or sides, so its edges are open.
    Triangles: ``4 segments``."""
    phi = np.pi * np.arange(segments + 1) / segments
    ci, si = np.cos(phi), np.sin(phi)
    inner = np.stack([np.zeros_like(phi), y0 + radius * si, z_c + radius * ci], 1)
    outer = np.stack([np.zeros_like(phi), y0 + (radius + thickness) * si,
                      z_c + (radius + thickness) * ci], 1)
    a, b = inner + [x0, 0, 0], inner + [x1, 0, 0]
    c = outer + [x0, 0, 0]
    n = segments + 1
    verts = np.concatenate([a, b, c])
    s = np.arange(segments)
    faces = np.concatenate([
        np.stack([s, s + 1, n + s + 1], 1), np.stack([s, n + s + 1, n + s], 1),   # intrados
        np.stack([s, 2 * n + s, 2 * n + s + 1], 1), np.stack([s, 2 * n + s + 1, s + 1], 1)])
    return prim._mesh(verts, faces)


def _atrium_view(scene: Scene, params: dict) -> View:
    bays = params["bays"]
    length = ATRIUM_BAY * bays
    light = PointLight((9.0, 14.0, -0.3 * length))
    return framed_view(scene, (-1.2, 1.7, 3.0), (0.8, 2.2, -length), light, fov_y_deg=60.0)


ATRIUM_BAY = 3.0        # column spacing along the nave (world units)


@_register(
    "atrium",
    "an architectural interior (the Sponza stand-in for Pečiva 2013 Tables 5-6): two "
    "colonnades of closed columns carrying open arches, an open gallery floor with "
    "a light well, and hanging single-sided banners",
    {"bays": Param(6, int, 1, 10_000, "arches per colonnade"),
     "segments": Param(16, int, 3, 100_000, "segments of a column's circle and of an arch"),
     "banners": Param(8, int, 0, 100_000, "hanging banners (two-triangle quads)"),
     "seed": Param(0, int, 0, None, "random seed (banner placement and sway)")},
    _atrium_view)
def _atrium(name: str, bays: int, segments: int, banners: int, seed: int) -> Scene:
    """A nave along -z between colonnades at x = -3 and x = 3.

    Objects: ground; per colonnade ``bays + 1`` columns (closed cylinders of radius 0.3,
    height 4) and ``bays`` open arches (:func:`_arch_band`) springing at y = 4; a gallery
    floor at y = 5.6 over each aisle with a light well (open quads); ``banners`` open
    quads hanging in the nave. Triangles:
    ``2 + 2 (bays + 1) 4 segments + 2 bays 4 segments + 4 + 2 banners``.
    """
    rng = np.random.default_rng(seed)
    parts = _Parts()
    length = ATRIUM_BAY * bays
    _ground(parts, (-12.0, 12.0), (-length - 6.0, 6.0))
    cv, cf = prim.cylinder(segments)
    zs = -ATRIUM_BAY * np.arange(bays + 1)
    for side, x in (("left", -3.0), ("right", 3.0)):
        cols = prim.instances(cv, cf, np.stack([np.full(bays + 1, x), np.zeros(bays + 1), zs], 1),
                              np.tile([0.3, 4.0, 0.3], (bays + 1, 1)))
        parts.add_many([f"{side}.column{i}" for i in range(bays + 1)], cols,
                       np.repeat(np.arange(bays + 1), len(cf)))
        r = 0.5 * ATRIUM_BAY - 0.3
        arches = prim.merge([_arch_band(x - 0.3, x + 0.3, z - 0.5 * ATRIUM_BAY, r, 0.35, 4.0,
                                        segments) for z in zs[:-1]])
        parts.add_many([f"{side}.arch{i}" for i in range(bays)], arches,
                       np.repeat(np.arange(bays), 4 * segments))
        xo = (x - 4.0, x + 0.3) if x < 0 else (x - 0.3, x + 4.0)
        parts.add(f"{side}.gallery", prim.quad_grid(xo, (-length, 0.0), 5.6))
    if banners:
        bx = rng.uniform(-2.2, 2.2, banners)
        bz = rng.uniform(-length, 0.0, banners)
        sway = rng.uniform(-0.4, 0.4, banners)
        top, bottom = 3.6, 1.6
        corners = []
        for x, z, s in zip(bx, bz, sway):
            q = np.array([[x - 0.4, top, z], [x + 0.4, top, z], [x + 0.4 + s, bottom, z + s],
                          [x - 0.4 + s, bottom, z + s]])
            corners += [q[[0, 1, 2]], q[[0, 2, 3]]]
        parts.add_many([f"banner{i}" for i in range(banners)],
                       prim.triangle_soup(np.asarray(corners)),
                       np.repeat(np.arange(banners), 2))
    return parts.scene(name)


def grazing_sheet(n: int = 40, jitter: float = 2e-7, seed: int = 0) -> Scene:
    """A robustness case, not a registered generator: a sheet of 2 (n-1)^2 triangles over
    x, z in [0, 3] at y = 1 whose vertices are ``jitter`` (a few float32 ulps) off the
    plane, and a wall x = 6 behind it. A light in the sheet's plane makes every
    triangle's side of the light a rounding decision (Pečiva et al. 2013's case for the
    deterministic multiplicity)."""
    rng = np.random.default_rng(seed + 7)
    x, z = np.meshgrid(np.linspace(0, 3, n), np.linspace(0, 3, n))
    v = np.stack([x, 1.0 + rng.uniform(-1, 1, x.shape) * jitter, z], -1).reshape(-1, 3)
    i = np.arange(n * n).reshape(n, n)
    a, b, c, d = i[:-1, :-1], i[:-1, 1:], i[1:, :-1], i[1:, 1:]
    f = np.concatenate([np.stack([a, b, d], -1).reshape(-1, 3),
                        np.stack([a, d, c], -1).reshape(-1, 3)])
    parts = _Parts()
    parts.add("sheet", prim._mesh(v, f))
    parts.add("wall", prim._mesh([[6, -4, -4], [6, 6, -4], [6, 6, 7], [6, -4, 7]],
                                 [[0, 1, 2], [0, 2, 3]]))
    return parts.scene("grazing_sheet")
# --------------------------------------------------------------------------- city

def _city_view(scene: Scene, params: dict) -> View:
    off = np.asarray(params["offset"], dtype=np.float64)
    w = params["size"] / 2
    eye = off + (0.35 * w, 1.1 * w, 1.9 * w)
    target = off + (0.0, 0.0, 0.1 * w)
    elev = math.radians(params["light_elevation_deg"])
    light = PointLight(tuple(off + 1.6 * w * np.array(
        [0.6 * math.cos(elev), math.sin(elev), -0.8 * math.cos(elev)])))
    if params["light_height"] is not None:
        light = PointLight(tuple(off + (0.3 * w, params["light_height"], -0.4 * w)))
    return framed_view(scene, tuple(eye), tuple(target), light)


@_register(
    "city",
    "large-world precision stress test: closed boxes (buildings) on a closed ground slab "
    "and a wall of thin posts, translated by `offset`",
    {"blocks": Param(6, int, 1, 1000, "buildings per side of the square grid"),
     "posts": Param(24, int, 0, 100_000, "thin posts in the wall along the back edge"),
     "posts_z": Param(-1.0, float, -1.0, 1.0, "where the wall of posts stands, as a fraction "
                      "of half the slab along z: -1 the back edge, 1 the front edge (between "
                      "the default camera and the buildings)"),
     "size": Param(40.0, float, 1e-3, 1e6, "side of the ground slab (world units)"),
     "offset": Param((0.0, 0.0, 0.0), tuple, doc="[x, y, z] translation of the scene and "
                     "of its default view (world units)"),
     "defects": Param(0, int, 0, 1, "1: add needle and sliver triangles, coincident "
                      "duplicates with opposite windings and T-junction roofs"),
     "light_elevation_deg": Param(50.0, float, 0.0, 90.0, "elevation of the default point "
                                  "light over the slab centre, degrees (small: grazing)"),
     "light_height": Param(None, float, None, None, "put the light at this height (before "
                           "the offset) instead; a building's roof height puts it in the "
                           "roof's plane"),
     "seed": Param(0, int, 0, None, "random seed")},
    _city_view)
def _city(name: str, blocks: int, posts: int, posts_z: float, size: float, offset,
          defects: int, light_elevation_deg: float, light_height, seed: int) -> Scene:
    """Closed meshes with shared edges, for large-world precision tests.

    A ground slab (a closed box of side ``size`` whose top face is y = 0, thickness
    ``size / 40``) carries ``blocks x blocks`` closed boxes (0.6 of a cell wide) with random
    heights of 0.3-1.5 cell widths and a wall of
    ``posts`` thin closed posts (cross-section ``size / 400``) along the back edge (or
    across the slab at ``posts_z``).
    Every box is 12 triangles sharing their edges. ``defects=1`` adds, per building,
    a needle (length/width 1e4) and a sliver (an almost collinear triangle) floating
    above it, a coincident duplicate of its roof with the opposite winding, and a
    roof split at a T-junction (two triangles whose vertex lies on the edge of a third).
    Everything is translated by ``offset``, after construction in float64, so the
    scene at any offset is the same scene moved.

    Triangles: ``12 (blocks^2 + posts + 1)``, plus ``8 blocks^2`` with defects.
    """
    rng = np.random.default_rng(seed)
    half = size / 2
    cell = size / blocks
    parts = _Parts()
    _ground_slab(parts, half, size / 40)
    ij = np.stack(np.meshgrid(np.arange(blocks), np.arange(blocks), indexing="ij"), -1)
    ij = ij.reshape(-1, 2).astype(np.float64)
    x0 = -half + cell * (ij[:, 0] + 0.2)
    z0 = -half + cell * (ij[:, 1] + 0.2)
    heights = cell * rng.uniform(0.3, 1.5, len(ij))
    lo = np.stack([x0, np.zeros(len(ij)), z0], 1)
    hi = np.stack([x0 + 0.6 * cell, heights, z0 + 0.6 * cell], 1)
    k = len(ij)
    parts.add_many([f"building{i}" for i in range(k)], prim.boxes(lo, hi),
                   np.repeat(np.arange(k), 12))
    if posts:
        t = size / 400
        px = np.linspace(-half + t, half - 2 * t, posts)
        shift = 0.5 * (posts_z + 1.0) * (size - 3 * t)     # 0 at the back edge
        plo = np.stack([px, np.zeros(posts), np.full(posts, -half + t + shift)], 1)
        phi = np.stack([px + t, np.full(posts, 0.35 * size),
                        np.full(posts, -half + 2 * t + shift)], 1)
        parts.add("posts", prim.boxes(plo, phi))
    if defects:
        top = heights + 0.25 * cell
        cx, cz = x0 + 0.3 * cell, z0 + 0.3 * cell
        L = 0.5 * cell
        needle = np.stack([np.stack([cx - L, top, cz], 1), np.stack([cx + L, top, cz], 1),
                           np.stack([cx, top, cz + L * 1e-4], 1)], 1)
        sliver = np.stack([np.stack([cx - L, top + 0.05 * cell, cz - 0.2 * cell], 1),
                           np.stack([cx + L, top + 0.05 * cell, cz - 0.2 * cell], 1),
                           np.stack([cx, top + 0.05 * cell + L * 1e-6, cz - 0.2 * cell], 1)], 1)
        a = np.stack([x0, heights, z0], 1)
        b = np.stack([x0 + 0.6 * cell, heights, z0], 1)
        c = np.stack([x0 + 0.6 * cell, heights, z0 + 0.6 * cell], 1)
        d = np.stack([x0, heights, z0 + 0.6 * cell], 1)
        dup = np.stack([a, c, b], 1)          # the roof triangle a, b, c reversed
        m = 0.5 * (a + c)                     # T-junction: m on the diagonal a-c
        tj = np.concatenate([np.stack([a, m, d], 1), np.stack([m, c, d], 1)], 0)
        parts.add("needles", prim.triangle_soup(needle))
        parts.add("slivers", prim.triangle_soup(sliver))
        parts.add("duplicates", prim.triangle_soup(dup))
        parts.add("tjunctions", prim.triangle_soup(tj))
    scene = parts.scene(name)
    off = np.asarray(offset, dtype=np.float64)
    if np.any(off != 0):
        scene = Scene(scene.vertices + off, scene.faces, scene.object_id, scene.object_names,
                      scene.name)
    return scene


# --------------------------------------------------------------------------- props

PROPS_SPACING = 7.0     # ground side per sqrt(object), world units


def _props_view(scene: Scene, params: dict) -> View:
    cx, cz, w, y1 = _content_frame(scene)
    eye = (cx + 0.5 * w, y1 + 1.1 * w, cz + 1.6 * w)
    light = PointLight((cx - 0.6 * w, y1 + 2.0 * w, cz - 0.3 * w))
    return framed_view(scene, eye, (cx, 0.0, cz + 0.1 * w), light)


def _prop_mesh(kind: int, per: int, rng: np.random.Generator) -> prim.Mesh:
    """One prop of about ``per`` triangles, centred on the origin (world units): a torus
    (kind 0), a capsule (1) or a cylinder (2) of random proportions."""
    if kind == 0:
        r = rng.uniform(0.2, 0.45)                     # tube radius / ring radius
        small = max(3, round(math.sqrt(per / 2 * r)))
        big = max(3, round(per / (2 * small)))
        v, f = prim.torus(big, small, r)
        return v * rng.uniform(1.0, 2.5), f
    if kind == 1:
        radius = rng.uniform(0.4, 1.2)
        stacks, _ = prim.sphere_resolution(per)
        stacks += 1 - stacks % 2                       # odd: no vertex on the equator
        slices = max(3, round(per / (2 * (stacks - 1))))
        v, f = prim.capsule(stacks, slices, rng.uniform(0.3, 1.8) / radius)
        return v * radius, f
    radius, height = rng.uniform(0.3, 1.4), rng.uniform(1.0, 5.0)
    segments = max(8, round(math.sqrt(per)))
    rings = max(1, round(per / (2 * segments)) - 1)
    v, f = prim.cylinder(segments, rings)
    return (v - [0.0, 0.5, 0.0]) * [radius, height, radius], f


@_register(
    "props",
    "closed tori, capsules and cylinders resting on (touching) and floating over a "
    "closed ground slab: contact shadows of closed objects",
    {"count": Param(40, int, 1, 100_000, "objects (each a torus, capsule or cylinder at "
                    "random)"),
     "triangles": Param(20_000, int, 100, 100_000_000, "about this many triangles in all "
                        "(shared evenly by the objects, at least 64 each)"),
     "floating": Param(0.5, float, 0.0, 1.0, "share of the objects lifted 0.3-3 units off "
                       "the ground; the others rest on it, their lowest vertex on its top"),
     "seed": Param(0, int, 0, None, "random seed")},
    _props_view)
def _props(name: str, count: int, triangles: int, floating: float, seed: int) -> Scene:
    """``count`` closed props at random orientations over a square closed ground slab.

    The props stand at well-separated random (x, z) points (:func:`_scatter`) of a
    square of side ``PROPS_SPACING sqrt(count)``; a resting prop's lowest vertex lies
    exactly on the slab's top face y = 0 (it touches the ground, as objects standing on
    a floor do), a floating one's 0.3-3 units above it. Each prop has about
    ``(triangles - 12) / count`` triangles (at least 64; tori 2 M m, capsules
    2 slices (stacks - 1), cylinders 2 segments (rings + 1)); the slab, object 0
    ("ground"), is a closed box 1.5 times the square's side with its top at y = 0.
    """
    rng = np.random.default_rng(seed)
    side = PROPS_SPACING * math.sqrt(count)
    half = 0.75 * side
    parts = _Parts()
    _ground_slab(parts, half, side / 40)
    per = max(64, (triangles - 12) // count)
    kinds = rng.integers(0, 3, count)
    rotations = prim.random_rotations(rng, count)
    spots = _scatter(rng, count, (-side / 2, side / 2), (-side / 2, side / 2))
    lifted = rng.random(count) < floating
    lift = np.where(lifted, rng.uniform(0.3, 3.0, count), 0.0)
    for i in range(count):
        v, f = _prop_mesh(int(kinds[i]), per, rng)
        v = v @ rotations[i].T
        v[:, 1] -= v[:, 1].min()                       # lowest vertex exactly at y = 0
        v += [spots[i, 0], lift[i], spots[i, 1]]
        parts.add(f"{('torus', 'capsule', 'cylinder')[kinds[i]]}{i}", (v, f))
    return parts.scene(name)
