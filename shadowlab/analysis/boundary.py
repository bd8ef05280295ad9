"""Explain mismatches against the reference: which lie on a shadow boundary?

The Embree reference works in float32, the methods in float32 or float64, so the two
may disagree where the segment from a sample to the light passes within rounding of
a caster's edge, or crosses a caster just at the self-shadowing cut ``eps`` above the
sample's tangent plane. For each mismatched pixel this module recomputes, in float64
and against every triangle, how close the segment comes to such a boundary.
"""

from __future__ import annotations

import numpy as np

from ..raycast import GBuffer, shadow_epsilon
from ..scene.mesh import Scene
from ..scene.view import Light, hard_light

EDGE_TOLERANCE = 1e-5     # barycentric distance from a caster's edge
CUT_TOLERANCE = 1e-3      # relative distance of the crossing height from eps


def boundary_distance(scene: Scene, gbuf: GBuffer, light: Light, pixels: np.ndarray,
                      shadow_eps: float = 1e-5, chunk: int = 65536) -> dict:
    """For pixels [K, 2] (row, col): the float64 margins of their segment to the light.

    Returns:
        ``edge`` float64 [K]: the smallest barycentric distance from a caster's edge over
        triangles the segment crosses (or nearly crosses) above the cut, and ``cut``
        float64 [K]: the smallest relative distance |height - eps| / eps of a crossing.
    """
    hl = hard_light(light)
    lh = hl.homogeneous
    eps = shadow_epsilon(scene, shadow_eps)
    tri = scene.triangles
    a, e1, e2 = tri[:, 0], tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]
    k = len(pixels)
    edge = np.full(k, np.inf)
    cut = np.full(k, np.inf)
    for n, (i, j) in enumerate(np.asarray(pixels).reshape(-1, 2)):
        p, nrm = gbuf.position[i, j], gbuf.normal[i, j]
        d = lh[:3] - lh[3] * p                # to the light (point: the whole segment)
        for lo in range(0, len(tri), chunk):
            sl_ = slice(lo, lo + chunk)
            h = np.cross(d, e2[sl_])
            det = np.einsum("ij,ij->i", e1[sl_], h)
            ok = np.abs(det) > 1e-300
            inv = np.where(ok, 1 / np.where(ok, det, 1), 0)
            s = p - a[sl_]
            u = np.einsum("ij,ij->i", s, h) * inv
            q = np.cross(s, e1[sl_])
            v = (q @ d) * inv
            t = np.einsum("ij,ij->i", e2[sl_], q) * inv
            inside_t = (t > 0) & ((t < 1) if lh[3] else True) & ok
            height = t * (nrm @ d)
            margin = np.minimum(np.minimum(u, v), 1 - u - v)
            near = inside_t & (margin > -EDGE_TOLERANCE) & (height > eps)
            if near.any():
                edge[n] = min(edge[n], np.abs(margin[near]).min())
            crossing = inside_t & (margin >= 0)
            if crossing.any():
                cut[n] = min(cut[n], (np.abs(height[crossing] - eps) / eps).min())
    return {"edge": edge, "cut": cut}


def unexplained_mismatches(scene: Scene, gbuf: GBuffer, light: Light, lit: np.ndarray,
                           truth: np.ndarray, shadow_eps: float = 1e-5) -> np.ndarray:
    """int [K, 2]: mismatched valid pixels that lie on no shadow boundary (within
    ``EDGE_TOLERANCE`` of a caster's edge or ``CUT_TOLERANCE`` of the cut)."""
    bad = np.argwhere((np.asarray(lit, bool) != np.asarray(truth, bool)) & gbuf.valid)
    if len(bad) == 0:
        return bad
    dist = boundary_distance(scene, gbuf, light, bad, shadow_eps)
    explained = (dist["edge"] <= EDGE_TOLERANCE) | (dist["cut"] <= CUT_TOLERANCE)
    return bad[~explained]
