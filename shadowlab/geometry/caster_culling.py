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
  it through a light-facing triangle, wherever it starts; ``front_face_culled``).

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

from ..reference.raycast import _orthonormal
from ..scene.caches import per_scene_cache
from ..scene.view import DirectionalLight, PointLight, SphereLight, hard_light

#: the modes of the common method option ``cull_casters``
CULL_MODES = ("off", "hull", "hull_averted")
#: outward padding of the hull, a fraction of the scene diagonal
PAD = 1e-6
#: the sides ``front_face_culled`` can drop
CULL_SIDES = ("averted", "facing")

_SUBSETS = per_scene_cache()      # {scene: {kept-mask bytes: subset scene}}
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

    The outward side comes from the sign of the object's signed volume; open objects keep
    all their triangles (culling them would lose shadows). ``light_h`` float64 [4] is the
    homogeneous light (w = 0: the direction towards a directional light).
    """
    if side not in CULL_SIDES:
        raise ValueError(f"side must be one of {CULL_SIDES}")
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
    return closed[scene.object_id] & (facing > 0 if side == "facing" else facing < 0)


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
    out = np.zeros(len(triangles), bool)
    for n0, n1, n2, d in planes:
        dist = triangles @ np.array([n0, n1, n2]) - d          # [T, 3]
        out |= np.all(dist > pad, axis=1)
    return out


@dataclasses.dataclass(frozen=True)
class CasterCull:
    """What :func:`cull_casters` removed.

    Attributes:
        keep: bool [T], the triangles passed on.
        hull: triangles outside the hull of the samples' shadow rays.
        averted: further triangles of closed objects facing away from the light.
    """

    keep: np.ndarray
    hull: int
    averted: int

    @property
    def culled(self) -> int:
        return self.hull + self.averted


def cull_casters(scene, gbuf, light, mode: str, soft: bool = False) -> CasterCull:
    """The casters ``mode`` (one of ``CULL_MODES``) keeps for this frame (frame-local
    ``scene`` [T triangles], ``gbuf`` and ``light``); ``soft`` for an area-light method
    (``averted`` is not used then: an area light sees both sides of a triangle)."""
    if mode not in CULL_MODES:
        raise ValueError(f"mode must be one of {CULL_MODES}, got {mode!r}")
    keep = np.ones(scene.num_triangles, bool)
    if mode == "off":
        return CasterCull(keep, 0, 0)
    pts = gbuf.position[gbuf.valid]
    if len(pts) == 0:
        return CasterCull(keep, 0, 0)
    diag = max(scene.diagonal, float(np.ptp(pts, axis=0).max()), 1e-30)
    pad = PAD * diag
    lo, hi = pts.min(axis=0) - pad, pts.max(axis=0) + pad
    planes = hull_planes(hull_points(lo, hi, light, 2.0 * diag, soft), tol=pad)
    outside = outside_hull(scene.triangles, planes, pad)
    keep &= ~outside
    averted = 0
    if mode == "hull_averted" and not soft:
        drop = front_face_culled(scene, hard_light(light).homogeneous, "averted") & keep
        averted = int(drop.sum())
        keep &= ~drop
    if not keep.any():          # methods expect a caster: keep one that shadows nothing
        keep[int(np.flatnonzero(outside)[0]) if outside.any() else 0] = True
    return CasterCull(keep, int(outside.sum()) - int(keep[outside].sum()), averted)


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


__all__ = ["CULL_MODES", "CULL_SIDES", "CasterCull", "PAD", "cull_casters",
           "front_face_culled", "hull_planes", "hull_points", "outside_hull", "subset_gbuffer",
           "subset_scene"]
