"""An independent float64 ground truth for precision studies (plain NumPy, no Embree).

Embree intersects in float32; this module repeats the two casts of the pipeline in
float64 with a plain Moller-Trumbore test against every triangle, so its answer does
not depend on Embree, on JAX or on the frame origin the rest of shadowlab uses:

- :func:`primary_hits`: the closest hit of each pixel-centre ray, computed in
  coordinates relative to the camera eye (the float64 spacing at 1e6 world units is
  1e-10, far below any tolerance used here);
- :func:`hard_shadows`: the documented lit criterion (docs/conventions.md) on given
  samples, computed relative to the light for a point light (relative to the sample
  for a directional light): lit when the sample faces the light and no triangle
  crosses the segment from the sample to the light more than ``eps = shadow_eps *
  diagonal`` above the sample's tangent plane, and (point light) more than ``eps``
  from the light along the segment. Triangle edges are inclusive.

Cost is pixels x triangles (chunked); meant for small images (<= 128 x 128) and a few
thousand triangles.
"""

from __future__ import annotations

import numpy as np

from .raycast import DEFAULT_SHADOW_EPS, shadow_epsilon
from ..scene.mesh import Scene
from ..scene.view import Camera, Light, hard_light

_CHUNK = 1 << 20       # ray x triangle pairs per NumPy block


def _crossings(origins: np.ndarray, dirs: np.ndarray, tri: np.ndarray):
    """Moller-Trumbore, float64: t [R, T], and bool [R, T] where the line hits the
    triangle (inclusive edges, non-degenerate). origins, dirs [R, 3]; tri [T, 3, 3]."""
    a = tri[:, 0]
    e1 = tri[:, 1] - a
    e2 = tri[:, 2] - a
    h = np.cross(dirs[:, None], e2[None])                        # [R, T, 3]
    det = np.einsum("tk,rtk->rt", e1, h)
    ok = det != 0
    inv = 1.0 / np.where(ok, det, 1.0)
    s = origins[:, None] - a[None]
    u = np.einsum("rtk,rtk->rt", s, h) * inv
    q = np.cross(s, e1[None])
    v = np.einsum("rtk,rk->rt", q, dirs) * inv
    t = np.einsum("tk,rtk->rt", e2, q) * inv
    hit = ok & (u >= 0) & (v >= 0) & (u + v <= 1)
    return t, hit


def primary_hits(scene: Scene, camera: Camera) -> dict[str, np.ndarray]:
    """Closest float64 hits of the camera's pixel-centre rays.

    Returns:
        ``triangle`` int64 [H, W] (-1: no hit between near and far), ``position``
        float64 [H, W, 3] world coordinates (eye + t d, 0 where invalid), ``valid`` bool
        [H, W].
    """
    origins, dirs = camera.primary_rays()
    h, w = camera.height, camera.width
    d = dirs.reshape(-1, 3).astype(np.float64)
    eye = np.asarray(camera.eye, np.float64)
    tri = scene.triangles - eye                                   # eye-relative
    _, _, back = camera.basis()
    n = len(d)
    best_t = np.full(n, np.inf)
    best = np.full(n, -1, np.int64)
    step = max(1, _CHUNK // max(len(tri), 1))
    for lo in range(0, n, step):
        sl = slice(lo, lo + step)
        t, hit = _crossings(np.zeros((len(d[sl]), 3)), d[sl], tri)
        depth = t * -(d[sl] @ back)[:, None]
        hit &= (t > 0) & (depth >= camera.near) & (depth <= camera.far)
        t = np.where(hit, t, np.inf)
        k = np.argmin(t, axis=1)
        tk = t[np.arange(len(k)), k]
        best_t[sl] = tk
        best[sl] = np.where(np.isfinite(tk), k, -1)
    valid = best >= 0
    pos = np.zeros((n, 3))
    pos[valid] = eye + best_t[valid, None] * d[valid]
    return {"triangle": best.reshape(h, w), "position": pos.reshape(h, w, 3),
            "valid": valid.reshape(h, w)}


def hard_shadows(scene: Scene, points: np.ndarray, normals: np.ndarray, light: Light,
                 shadow_eps: float = DEFAULT_SHADOW_EPS) -> np.ndarray:
    """bool [N]: the lit criterion for samples ``points`` [N, 3] (world, float64) with
    unit normals [N, 3] (facing the camera), in float64.

    Lit = facing the light (``n . (L.xyz - L.w p) > 0``) and no triangle crossing the
    segment to the light at a height ``t n.d > eps`` above the tangent plane, where the
    segment is ``p + t d``, ``d = L - p`` (t in (0, 1)) for a point light and ``d`` the
    unit direction to a light at infinity (t > 0).
    """
    hl = hard_light(light)
    lh = hl.homogeneous
    eps = shadow_epsilon(scene, shadow_eps)
    points = np.asarray(points, np.float64).reshape(-1, 3)
    normals = np.asarray(normals, np.float64).reshape(-1, 3)
    if lh[3]:
        centre = lh[:3] / lh[3]
        tri = scene.triangles - centre                           # light-relative
        p = points - centre
        d = -p
    else:
        tri = scene.triangles
        p = points
        d = np.broadcast_to(lh[:3] / np.linalg.norm(lh[:3]), p.shape)
    facing = np.einsum("ij,ij->i", normals, d) > 0
    lit = facing.copy()
    idx = np.flatnonzero(facing)
    step = max(1, _CHUNK // max(len(tri), 1))
    for lo in range(0, len(idx), step):
        i = idx[lo:lo + step]
        if lh[3]:
            t, hit = _crossings(p[i], d[i], tri)
            # crossings within eps of the light are ignored, as by the reference
            hit &= (t > 0) & ((1 - t) * np.linalg.norm(d[i], axis=1)[:, None] > eps)
        else:
            t, hit = _directional(p[i], d[i], tri)             # sample-relative
            hit &= t > 0
        height = t * np.einsum("ij,ij->i", normals[i], d[i])[:, None]
        lit[i] = ~np.any(hit & (height > eps), axis=1)
    return lit


def _directional(p: np.ndarray, d: np.ndarray, tri: np.ndarray):
    """:func:`_crossings` of rays from p [R, 3] along d [R, 3], with the triangles moved
    relative to each sample (float64)."""
    a = tri[None, :, 0] - p[:, None]                             # [R, T, 3]
    e1 = (tri[:, 1] - tri[:, 0])[None]
    e2 = (tri[:, 2] - tri[:, 0])[None]
    h = np.cross(d[:, None], e2)
    det = np.einsum("rtk,rtk->rt", e1, h)
    ok = det != 0
    inv = 1.0 / np.where(ok, det, 1.0)
    s = -a
    u = np.einsum("rtk,rtk->rt", s, h) * inv
    q = np.cross(s, e1)
    v = np.einsum("rtk,rk->rt", q, d) * inv
    t = np.einsum("rtk,rtk->rt", np.broadcast_to(e2, q.shape), q) * inv
    return t, ok & (u >= 0) & (v >= 0) & (u + v <= 1)


def gbuffer_shadows(scene: Scene, gbuf, light: Light,
                    shadow_eps: float = DEFAULT_SHADOW_EPS) -> np.ndarray:
    """bool [H, W]: :func:`hard_shadows` on a G-buffer's valid samples (False elsewhere)."""
    idx = np.flatnonzero(gbuf.valid)
    lit = np.zeros(gbuf.valid.size, bool)
    lit[idx] = hard_shadows(scene, gbuf.position.reshape(-1, 3)[idx],
                            gbuf.normal.reshape(-1, 3)[idx], light, shadow_eps)
    return lit.reshape(gbuf.valid.shape)
