"""Scene-adaptive caster culling, shared by every method: drop the triangles that cannot
shadow any view sample of this frame, before a method sees the scene.

A triangle matters to a sample p only if it meets the set of shadow rays of p: the
segment from p to a point light, the ray towards a directional light, or, for an area
light, the segments from p to every point of the sphere (or the rays inside the sun's
cone). Two exact tests remove triangles that meet no such set for any sample:

- ``hull``: every such segment of every valid sample lies in the convex hull of the
  samples' bounding box and the light: the box's corners plus the light's point (point
  light), the corners of the light sphere's bounding box (sphere light), or the box's
  corners moved a scene diagonal twice towards the light (directional light) or along
  the four corner directions of a square around the sun's cone. A triangle whose three
  corners lie strictly outside one face plane of that hull meets none of them. The hull
  is padded outwards by ``PAD`` of the scene diagonal and the test is done in float64 on
  frame-local coordinates, so the rounding of the methods' own float32 work (whose
  casters all lie inside) never decides it.
- ``averted`` (hard shadows only): the triangles of closed objects whose outward side
  faces away from the light (a segment that ends at a light outside the object leaves
  it through a light-facing triangle, wherever it starts; ``front_face_culled``). An
  object that contains the light, or touches it, keeps every triangle
  (``light_outside_objects``).
- ``receivers`` (hard shadows only; the receiver-driven culling of CC shadow volumes,
  Lloyd et al. 2004, with a light-space max-depth grid of the samples): a blocker of a
  sample p lies on the segment from the light to p, so it has p's direction from the
  light and is nearer to the light than p. The samples' light-space positions go into a
  grid (a cube map of directions around a point light, a plane perpendicular to a
  directional light) that keeps each cell's largest depth (distance from a point light,
  distance along a directional light). A triangle whose nearest point to the light is
  farther than every sample in the cells of its (dilated) footprint shadows none of them
  (``behind_receivers``). Triangles whose footprint cannot be bounded on one cube face
  are kept.

The cull returns a :class:`~shadowlab.scene.mesh.Scene.subset` that keeps the parent's
bounds (so the shadow offset, a fraction of the diagonal, is unchanged), and the
G-buffer with its triangle ids renumbered to match (:func:`subset_gbuffer`). With casters
removed the lit mask of an exact method is unchanged (tested per method): every removed
triangle contributes nothing to any sample's count or visibility. Work counters
(tests, volumes, edges) fall; that is the point. Receivers need no separate step: every
method already works only on the valid, light-facing samples (``core.frame.view_samples``),
so sky and back-facing pixels cost nothing.
"""

from __future__ import annotations

import dataclasses
import itertools

import numpy as np

from ..core.numerics import column_bounds, cross_columns, norms3, ordered_dot
from ..reference.raycast import _orthonormal
from ..scene.caches import per_scene_cache
from ..scene.view import DirectionalLight, PointLight, SphereLight, hard_light

#: the modes of the common method option ``cull_casters``: the steps each runs
CULL_MODES = ("off", "hull", "hull_averted", "hull_receivers", "all")
_STEPS = {"off": (), "hull": ("hull",), "hull_averted": ("hull", "averted"),
          "hull_receivers": ("hull", "receivers"), "all": ("hull", "averted", "receivers")}
#: cells per side of the receivers' depth grid (per cube face for a point light)
RECEIVER_GRID = 64
#: the receivers step's depth margin: a triangle is culled only when its nearest point is
#: farther than the farthest sample of its cells by this fraction of the scene diagonal
#: plus DEPTH_REL of the sample's depth (float32 rounding of the methods' own tests is
#: about 1e-7 of either)
DEPTH_PAD = 1e-4
DEPTH_REL = 1e-5
#: outward padding of the hull, a fraction of the scene diagonal
PAD = 1e-6
#: a point light closer than this fraction of the scene diagonal to a closed object's
#: surface counts as inside it (``light_outside_objects``): none of its triangles is
#: averted-culled
LIGHT_CLEARANCE = 1e-6
#: the sides ``front_face_culled`` can drop
CULL_SIDES = ("averted", "facing")

_SUBSETS = per_scene_cache()      # {scene: {kept-mask bytes: subset scene}}
_BOXES = per_scene_cache()        # {scene: per-object bounding boxes}
_NORMALS = per_scene_cache()      # {scene: (outward normal columns, first-corner columns)}
_MAX_SUBSETS = 4


def front_face_culled(scene, light_h: np.ndarray, side: str = "averted") -> np.ndarray:
    """bool [T]: the triangles of closed objects that front-face culling drops.

    ``side="facing"`` (the papers' front-face culling): drop the triangles whose outward
    side faces the light. For a closed, consistently oriented object, a blocked segment
    from a point *outside* it to the light enters it through a triangle facing away from
    the light, so those suffice. With the receiver bias the segment starts eps above the
    receiver's tangent plane; when that start lies inside a closed object (the receiver
    is within eps below it: contacts, overhangs), the segment only leaves it, through a
    light-facing triangle, and the shadow is lost (measured: docs/clustered_ptsv.md).

    ``side="averted"`` (default): drop the triangles facing away from the light. The last
    crossing of a closed object's surface on a segment that ends at a light outside it
    always leaves the object through a light-facing triangle, wherever the segment
    starts, so this is exact with either bias.

    Both rules need the light *outside* the object: a closed object that contains a
    point light (a lamp inside a closed shade, a light inside a closed room), or whose
    surface passes within ``LIGHT_CLEARANCE`` of it, keeps all its triangles
    (:func:`light_outside_objects`); so does every open object (culling it would lose
    shadows). The outward side comes from the sign of the object's signed volume.
    ``light_h`` float64 [4] is the homogeneous light (w = 0: the direction towards a
    directional light, outside every object).
    """
    if side not in CULL_SIDES:
        raise ValueError(f"side must be one of {CULL_SIDES}")
    report = scene.report()
    closed = np.array([o.closed for o in report.objects] +
                      [False] * (scene.num_objects - len(report.objects)))
    closed &= light_outside_objects(scene, light_h, closed)
    n, v0 = outward_normals(scene)
    d = [light_h[k] - light_h[3] * v0[k] for k in range(3)]
    facing = ordered_dot(n, d, np.multiply)
    return closed[scene.object_id] & (facing > 0 if side == "facing" else facing < 0)


def outward_normals(scene) -> tuple[list[np.ndarray], list[np.ndarray]]:
    """The triangles' outward normals and first corners, each as 3 float64 columns [T],
    cached per scene (they do not depend on the light).

    A normal is ``(v1 - v0) x (v2 - v0)`` times its object's orientation, the sign of
    the object's signed volume (+1 for a zero volume); flipping a sign is exact, so
    ``n . d`` has the rounding of the unflipped product times the sign (the sums are
    ``(p0 + p1) + p2``; ``einsum``, used before, may add in another order, which can
    change the side only of a triangle whose plane contains the light). Columns instead
    of [T, 3] rows: NumPy's ``cross`` and row-wise dot products on [T, 3] arrays cost
    about 160 ms at 1M triangles, the column form a few ms (per frame only the dot
    product is left).
    """
    cached = _NORMALS.get(scene)
    if cached is None:
        tri = scene.triangles
        v0, v1, v2 = ([tri[:, i, k] for k in range(3)] for i in range(3))
        n = cross_columns([a - b for a, b in zip(v1, v0)], [a - b for a, b in zip(v2, v0)])
        vol6 = ordered_dot(v0, cross_columns(v1, v2), np.multiply)
        orient = np.sign(np.bincount(scene.object_id, weights=vol6,
                                     minlength=scene.num_objects))
        orient = np.where(orient == 0, 1.0, orient)[scene.object_id]
        cached = ([c * orient for c in n], [np.array(c) for c in v0])
        for c in cached[0] + cached[1]:
            c.flags.writeable = False           # shared by every later call on the scene
        _NORMALS[scene] = cached
    return cached


def light_outside_objects(scene, light_h: np.ndarray, objects: np.ndarray) -> np.ndarray:
    """bool [objects]: True where the light is strictly outside the closed object, for
    the objects flagged in ``objects`` (bool [num_objects]; others are False).

    A directional light (``light_h[3] == 0``) is outside every object. A point light is
    outside an object if it lies outside the object's bounding box padded by
    ``LIGHT_CLEARANCE`` of the scene diagonal; otherwise (float64, on that object's
    triangles) if its generalized winding number (the sum of the triangles' signed solid
    angles over 4 pi, Van Oosterom and Strackee 1983: 0 outside a closed surface, +-1
    inside) is below 1/2 in magnitude *and* no triangle of the object is within the
    clearance of it. The clearance rule covers a light on (or at a corner or edge of)
    the surface, where the winding number takes fractional values.
    """
    out = np.zeros(scene.num_objects, bool)
    out[: len(objects)] = objects
    if light_h[3] == 0 or not out.any():
        return out
    p = np.asarray(light_h[:3], np.float64) / light_h[3]
    clearance = LIGHT_CLEARANCE * scene.diagonal
    tri = scene.triangles
    oid = scene.object_id
    lo, hi = object_boxes(scene)
    near = out & np.all((p >= lo - clearance) & (p <= hi + clearance), axis=1)
    if not near.any():
        return out
    pick = np.flatnonzero(near[oid])
    sel = tri[pick]
    t = sel - p
    a, b, c = t[:, 0], t[:, 1], t[:, 2]
    la, lb, lc = (np.linalg.norm(x, axis=1) for x in (a, b, c))
    num = np.einsum("ij,ij->i", a, np.cross(b, c))
    den = (la * lb * lc + np.einsum("ij,ij->i", a, b) * lc + np.einsum("ij,ij->i", a, c) * lb
           + np.einsum("ij,ij->i", b, c) * la)
    winding = np.bincount(oid[pick], weights=2.0 * np.arctan2(num, den),
                          minlength=scene.num_objects) / (4.0 * np.pi)
    dist = np.full(scene.num_objects, np.inf)
    np.minimum.at(dist, oid[pick], _point_triangle_distance(p, sel))
    out[near] = (np.abs(winding[near]) < 0.5) & (dist[near] > clearance)
    return out


def object_boxes(scene) -> tuple[np.ndarray, np.ndarray]:
    """float64 [num_objects, 3] lower and upper corners of each object's triangles
    (+inf / -inf for an object without triangles); computed once per scene."""
    if scene not in _BOXES:
        oid = scene.object_id
        order = np.argsort(oid, kind="stable") if np.any(oid[1:] < oid[:-1]) else None
        v = scene.vertices[scene.faces if order is None else scene.faces[order]]
        ids = oid if order is None else oid[order]
        lo = np.full((scene.num_objects, 3), np.inf)
        hi = np.full((scene.num_objects, 3), -np.inf)
        if len(ids):
            starts = np.flatnonzero(np.r_[True, ids[1:] != ids[:-1]])
            lo[ids[starts]] = np.minimum.reduceat(v.min(axis=1), starts)
            hi[ids[starts]] = np.maximum.reduceat(v.max(axis=1), starts)
        _BOXES[scene] = (lo, hi)
    return _BOXES[scene]


def _box_corners(lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    """float64 [8, 3]: the corners of the box [lo, hi]."""
    return np.array([[(lo, hi)[i][0], (lo, hi)[j][1], (lo, hi)[k][2]]
                     for i, j, k in itertools.product((0, 1), repeat=3)])


def hull_points(lo: np.ndarray, hi: np.ndarray, light, reach: float, soft: bool) -> np.ndarray:
    """float64 [n, 3]: points whose convex hull holds every shadow ray, within ``reach``
    (world units), of every point of the box [lo, hi] (see the module docstring).
    ``soft``: the area light itself; otherwise its centre (``hard_light``)."""
    box = _box_corners(lo, hi)
    if not soft:
        light = hard_light(light)
    if isinstance(light, PointLight):
        return np.vstack([box, np.asarray(light.position, np.float64)[None]])
    if isinstance(light, DirectionalLight):
        return np.vstack([box, box - reach * np.asarray(light.direction, np.float64)])
    if isinstance(light, SphereLight) and light.radius is not None:
        c, r = np.asarray(light.position, np.float64), float(light.radius)
        return np.vstack([box, _box_corners(c - r, c + r)])
    if isinstance(light, SphereLight):
        towards = -np.asarray(light.direction, np.float64)
        towards = towards / np.linalg.norm(towards)
        u, v = _orthonormal(towards)
        t = np.tan(np.radians(light.angular_radius_deg))
        ends = [box + reach * (towards + t * (a * u + b * v))
                for a in (-1, 1) for b in (-1, 1)]
        return np.vstack([box, *ends])
    raise TypeError(f"unsupported light {type(light).__name__}")


def hull_planes(points: np.ndarray, tol: float) -> np.ndarray:
    """float64 [K, 4]: face planes (n, d) of the convex hull of ``points`` [n, 3], with
    n . x <= d inside (n of unit length), found among the planes through every three
    points that have all points on one side (within ``tol``, world units)."""
    idx = np.array(list(itertools.combinations(range(len(points)), 3)))
    a, b, c = points[idx[:, 0]], points[idx[:, 1]], points[idx[:, 2]]
    n = np.cross(b - a, c - a)
    length = np.linalg.norm(n, axis=1)
    ok = length > 1e-12 * max(1.0, float(np.abs(points).max())) ** 2
    n = n[ok] / length[ok, None]
    d = np.einsum("ij,ij->i", n, a[ok])
    side = points @ n.T - d                       # [points, planes]
    below = np.all(side <= tol, axis=0)
    above = np.all(side >= -tol, axis=0)
    planes = np.vstack([np.column_stack([n[below], d[below]]),
                        np.column_stack([-n[above], -d[above]])])
    return np.unique(np.round(planes, 12), axis=0)


def outside_hull(triangles: np.ndarray, planes: np.ndarray, pad: float) -> np.ndarray:
    """bool [T]: triangles [T, 3, 3] whose three corners lie more than ``pad`` outside
    one plane of ``planes`` [K, 4]."""
    corners = np.asarray(triangles).reshape(-1, 3)                # [3T, 3]: one matvec
    out = np.zeros(len(triangles), bool)
    for n0, n1, n2, d in planes:
        far = corners @ np.array([n0, n1, n2]) - d > pad          # [3T]
        out |= far[0::3] & far[1::3] & far[2::3]
    return out


def _point_triangle_distance(p: np.ndarray, tri: np.ndarray) -> np.ndarray:
    """float64 [T]: the distance from the point p [3] to each triangle of ``tri``
    [T, 3, 3] (its nearest point: inside, on an edge or a vertex)."""
    a, b, c = tri[:, 0] - p, tri[:, 1] - p, tri[:, 2] - p
    n = np.cross(b - a, c - a)
    nn = np.einsum("ij,ij->i", n, n)
    ok = nn > 0
    # the foot of the perpendicular from p (the origin here) is inside iff it lies on
    # the inner side of every edge
    h = np.where(ok, np.einsum("ij,ij->i", n, a) / np.where(ok, nn, 1.0), 0.0)
    foot = h[:, None] * n
    inside = ok & np.all([np.einsum("ij,ij->i", np.cross(y - x, foot - x), n) >= 0
                          for x, y in ((a, b), (b, c), (c, a))], axis=0)
    plane = np.abs(h) * np.sqrt(nn)

    def segment(x, y):
        d = y - x
        dd = np.einsum("ij,ij->i", d, d)
        t = np.clip(-np.einsum("ij,ij->i", x, d) / np.where(dd > 0, dd, 1.0), 0.0, 1.0)
        return np.linalg.norm(x + t[:, None] * d, axis=1)

    edges = np.minimum(np.minimum(segment(a, b), segment(b, c)), segment(c, a))
    return np.where(inside, np.minimum(plane, edges), edges)


def _max_pyramid(grid: np.ndarray) -> list[np.ndarray]:
    """The max-mip pyramid of ``grid`` [F, G, G] (G a power of two): level l [F, G/2^l,
    G/2^l] holds the largest value of the cells it covers."""
    levels = [grid]
    while levels[-1].shape[-1] > 1:
        g = levels[-1]
        f, n = g.shape[0], g.shape[-1] // 2
        levels.append(g.reshape(f, n, 2, n, 2).max(axis=(2, 4)))
    return levels


def _range_max(levels: list[np.ndarray], face, i0, i1, j0, j1) -> np.ndarray:
    """float64 [T]: an upper bound of the largest value over the cells [i0..i1] x [j0..j1]
    of each face (the largest over the at most 2 x 2 cells of the first pyramid level
    whose cells cover that range)."""
    out = np.full(len(face), -np.inf)
    todo = np.ones(len(face), bool)
    for level, g in enumerate(levels):
        a0, a1, b0, b1 = i0 >> level, i1 >> level, j0 >> level, j1 >> level
        fit = todo & (a1 - a0 <= 1) & (b1 - b0 <= 1)
        if fit.any():
            f = face[fit]
            out[fit] = np.maximum.reduce([g[f, x[fit], y[fit]]
                                          for x in (a0, a1) for y in (b0, b1)])
            todo &= ~fit
        if not todo.any():
            break
    return out


def behind_receivers(triangles: np.ndarray, samples: np.ndarray, light_h: np.ndarray,
                     diag: float, cells: int = RECEIVER_GRID) -> np.ndarray:
    """bool [T]: the triangles [T, 3, 3] that lie behind every sample [S, 3] in their
    light-space footprint, so shadow none (the ``receivers`` step; float64, frame-local
    coordinates; ``light_h`` [4] homogeneous, w = 0 for a directional light given as the
    direction towards it; ``diag`` the scene diagonal, world units).

    The footprint is dilated by one cell, and a triangle is culled only when its
    nearest depth exceeds the cells' largest by ``DEPTH_PAD diag + DEPTH_REL depth``."""
    if len(samples) == 0 or len(triangles) == 0:
        return np.zeros(len(triangles), bool)
    pad = DEPTH_PAD * diag
    if light_h[3] == 0:
        w = np.asarray(light_h[:3], np.float64)
        w = w / np.linalg.norm(w)
        e1, e2 = _orthonormal(w)
        basis = np.stack([e1, e2, -w], 1)              # (u, v, depth away from the light)
        sp, tp = samples @ basis, triangles @ basis
        lo, hi = column_bounds(sp[:, :2])
        # cells never narrower than the methods' float32 rounding of the coordinates
        # (the one-cell dilation must cover it, also when the samples span nothing)
        reach = diag + float(np.abs(sp).max()) + float(np.abs(tp).max())
        size = np.maximum(hi - lo, 64 * 1e-6 * reach) / cells
        si = np.clip(((sp[:, :2] - lo) / size).astype(np.int64), 0, cells - 1)
        side = 1 << int(np.ceil(np.log2(cells)))     # the pyramid halves a power of two
        grid = np.full((1, side, side), -np.inf)
        np.maximum.at(grid, (0, si[:, 0], si[:, 1]), sp[:, 2])
        tlo = np.floor((tp[:, :, :2].min(axis=1) - lo) / size).astype(np.int64) - 1
        thi = np.floor((tp[:, :, :2].max(axis=1) - lo) / size).astype(np.int64) + 1
        outside = np.any(thi < 0, axis=1) | np.any(tlo > cells - 1, axis=1)
        tlo, thi = np.clip(tlo, 0, cells - 1), np.clip(thi, 0, cells - 1)
        far = _range_max(_max_pyramid(grid), np.zeros(len(tp), np.int64), tlo[:, 0],
                         thi[:, 0], tlo[:, 1], thi[:, 1])
        near = tp[:, :, 2].min(axis=1)
        depth_scale = np.abs(sp[:, 2]).max()
        return outside | (near > far + pad + DEPTH_REL * depth_scale)
    light = np.asarray(light_h[:3], np.float64) / light_h[3]
    d = samples - light
    dist = norms3(d)
    if dist.min() <= pad:          # a sample at the light: directions are not defined
        return np.zeros(len(triangles), bool)
    # cube faces, each extended by two cells on every side, so a sample within two cells
    # of a face's border is also recorded on the neighbouring face
    h = 2.0 / cells
    ext = 1.0 + 2 * h
    n = cells + 4
    size = 1 << int(np.ceil(np.log2(n)))
    grid = np.full((6, size, size), -np.inf)
    td = triangles - light
    face_of = np.full(len(td), -1)
    centroid = td.mean(axis=1)
    major = np.argmax(np.abs(centroid), axis=1)
    tsign = np.sign(centroid[np.arange(len(td)), major])
    t_ij = np.zeros((len(td), 4), np.int64)
    for axis in range(3):
        b, c = [k for k in range(3) if k != axis]
        for sign in (-1.0, 1.0):
            face = 2 * axis + (sign > 0)
            along = sign * d[:, axis]
            on = along > 0
            u = d[on, b] / along[on]
            v = d[on, c] / along[on]
            rec = (np.abs(u) <= ext) & (np.abs(v) <= ext)
            iu = ((u[rec] + ext) / h).astype(np.int64)
            iv = ((v[rec] + ext) / h).astype(np.int64)
            np.maximum.at(grid, (face, np.minimum(iu, n - 1), np.minimum(iv, n - 1)),
                          dist[on][rec])
            # triangles: all three corners in front of this face, inside its recorded
            # part less one cell (so their dilated footprint's samples were recorded)
            mine = (major == axis) & (tsign == sign)
            ta = sign * td[mine][:, :, axis]
            front = np.all(ta > 0, axis=1)
            tu = td[mine][:, :, b] / np.where(front[:, None], ta, 1.0)
            tv = td[mine][:, :, c] / np.where(front[:, None], ta, 1.0)
            fits = front & np.all(np.abs(tu) <= ext - h, axis=1) & \
                np.all(np.abs(tv) <= ext - h, axis=1)
            idx = np.flatnonzero(mine)[fits]
            face_of[idx] = face
            t_ij[idx] = np.stack([
                np.floor((tu[fits].min(axis=1) + ext) / h).astype(np.int64) - 1,
                np.floor((tu[fits].max(axis=1) + ext) / h).astype(np.int64) + 1,
                np.floor((tv[fits].min(axis=1) + ext) / h).astype(np.int64) - 1,
                np.floor((tv[fits].max(axis=1) + ext) / h).astype(np.int64) + 1], 1)
    bounded = face_of >= 0
    t_ij = np.clip(t_ij, 0, n - 1)
    far = np.full(len(td), np.inf)
    far[bounded] = _range_max(_max_pyramid(grid), face_of[bounded], t_ij[bounded, 0],
                              t_ij[bounded, 1], t_ij[bounded, 2], t_ij[bounded, 3])
    near = _point_triangle_distance(light, triangles)
    return bounded & (near > far + pad + DEPTH_REL * np.where(np.isfinite(far), far, 0.0))


@dataclasses.dataclass(frozen=True)
class CasterCull:
    """What :func:`cull_casters` removed.

    Attributes:
        keep: bool [T], the triangles passed on.
        hull: triangles outside the hull of the samples' shadow rays.
        averted: further triangles of closed objects facing away from the light.
        receivers: further triangles behind every sample in their light-space footprint.
    """

    keep: np.ndarray
    hull: int
    averted: int
    receivers: int = 0

    @property
    def culled(self) -> int:
        return self.hull + self.averted + self.receivers


def cull_casters(scene, gbuf, light, mode: str, soft: bool = False) -> CasterCull:
    """The casters ``mode`` (one of ``CULL_MODES``) keeps for this frame (frame-local
    ``scene`` [T triangles], ``gbuf`` and ``light``); ``soft`` for an area-light method
    (``averted`` and ``receivers`` are not used then: an area light sees both sides of a
    triangle, and a sample's blockers lie on many segments)."""
    if mode not in CULL_MODES:
        raise ValueError(f"mode must be one of {CULL_MODES}, got {mode!r}")
    keep = np.ones(scene.num_triangles, bool)
    if mode == "off":
        return CasterCull(keep, 0, 0)
    pts = gbuf.position[gbuf.valid]
    if len(pts) == 0:
        return CasterCull(keep, 0, 0)
    lo, hi = column_bounds(pts)
    diag = max(scene.diagonal, float((hi - lo).max()), 1e-30)
    pad = PAD * diag
    lo, hi = lo - pad, hi + pad
    planes = hull_planes(hull_points(lo, hi, light, 2.0 * diag, soft), tol=pad)
    outside = outside_hull(scene.triangles, planes, pad)
    steps = _STEPS[mode]
    step = np.where(outside, 1, 0)          # the step that dropped each triangle: 1, 2, 3
    keep &= ~outside
    if "averted" in steps and not soft:
        drop = front_face_culled(scene, hard_light(light).homogeneous, "averted") & keep
        step[drop] = 2
        keep &= ~drop
    if "receivers" in steps and not soft:
        drop = np.zeros_like(keep)
        drop[keep] = behind_receivers(scene.triangles[keep], pts,
                                      hard_light(light).homogeneous, diag)
        step[drop] = 3
        keep &= ~drop
    if not keep.any():          # methods expect a caster: keep one that shadows nothing
        first = int(np.flatnonzero(step)[0]) if step.any() else 0
        keep[first], step[first] = True, 0
    counts = np.bincount(step, minlength=4)
    return CasterCull(keep, int(counts[1]), int(counts[2]), int(counts[3]))


def subset_gbuffer(gbuf, keep: np.ndarray):
    """``gbuf`` with its triangle ids [H, W] renumbered into the subset of ``keep`` (bool
    [T]): a kept triangle gets its index among the kept ones, a culled one -1 (as an
    invalid pixel), so a method that reads ``gbuf.triangle`` sees the scene it is given."""
    if keep.all():
        return gbuf
    new_id = np.where(keep, np.cumsum(keep) - 1, -1).astype(np.int32)
    tri = np.asarray(gbuf.triangle)
    renumbered = np.where(tri >= 0, new_id[np.clip(tri, 0, None)], -1).astype(tri.dtype)
    return dataclasses.replace(gbuf, triangle=renumbered)


def without_culled_faces(scene, light_h: np.ndarray, side: str = "averted"):
    """The methods' own face culling before their triangle setup: (the scene without the
    triangles :func:`front_face_culled` drops, how many it dropped).

    The result is a cached :func:`subset_scene`: it keeps the scene's bounds (so shadow
    offsets, a fraction of the diagonal, are unchanged) and the order of the kept
    triangles. Its triangle ids are its own; the G-buffer's are not renumbered (the
    methods that call this read none). Should every triangle go (possible only for
    degenerate closed objects), the first one stays, since a scene holds at least one;
    a dropped triangle decides no shadow, so keeping it changes nothing.
    """
    drop = front_face_culled(scene, light_h, side)
    if drop.all():
        drop[0] = False
    return subset_scene(scene, ~drop), int(drop.sum())


def subset_scene(scene, keep: np.ndarray):
    """``scene.subset(keep)``, cached per scene and mask (a static frame reuses it, and so
    the per-scene caches of the subset, such as its edge adjacency)."""
    if keep.all():
        return scene
    held = _SUBSETS.setdefault(scene, {})
    key = np.packbits(keep).tobytes()
    out = held.get(key)
    if out is None:
        out = scene.subset(keep)
        if len(held) >= _MAX_SUBSETS:
            held.pop(next(iter(held)))
        held[key] = out
    return out


__all__ = ["CULL_MODES", "CULL_SIDES", "CasterCull", "PAD", "behind_receivers", "cull_casters",
           "front_face_culled", "hull_planes", "hull_points", "outside_hull", "outward_normals",
           "subset_gbuffer", "subset_scene", "without_culled_faces"]
