"""Explain mismatches against the reference: which lie on a shadow boundary?

The Embree reference works in float32, the methods in float32 or float64, so the two
may disagree where the segment from a sample to the light passes within rounding of
a caster's edge, or crosses a caster just at the self-shadowing cut ``eps`` above the
sample's tangent plane, or where the sample's own surface is edge-on to the light (the
terminator: the facing test ``n . (L.xyz - L.w p) > 0`` of a sample whose true value
is 0 has the sign of its rounding, which differs between two float64 evaluations in
different order or frames). For each mismatched pixel this module recomputes, in
float64 and against every triangle, how close the segment comes to such a boundary.

Edge distances are in world units, measured in the caster's plane from the crossing
point to the nearest edge line, and compared with ``EDGE_ULPS`` float32 spacings of the
scene's coordinate magnitude (largest absolute coordinate of the vertices and the
light), measured from the G-buffer's frame origin: the inputs of every method are
float32 coordinates relative to it, so nothing finer is resolved. A
barycentric tolerance would be too strict on slivers (a 0.02-wide strand) and too loose
on large triangles.
"""

from __future__ import annotations

import numpy as np

from .raycast import DEFAULT_SHADOW_EPS, GBuffer, facing_test, shadow_epsilon
from ..scene.mesh import Scene
from ..scene.view import Light, hard_light

EDGE_ULPS = 64            # float32 spacings of the coordinate magnitude (edge tolerance)
CUT_TOLERANCE = 1e-3      # relative distance of the crossing height from eps
FACING_ULPS = 64          # float64 spacings of the facing test's magnitude (terminator)
FACING_TOLERANCE = FACING_ULPS * float(np.finfo(np.float64).eps)   # on facing_margin


def facing_margin(gbuf: GBuffer, light: Light, pixels: np.ndarray) -> np.ndarray:
    """float64 [K]: for pixels [K, 2] (row, col), the facing test ``n . (L.xyz - L.w p)``
    in the G-buffer's coordinates (world, for ``render_gbuffer``'s) relative to its
    rounding scale ``|n| (|L.xyz| + |L.w| |p|)`` (Euclidean norms). Two float64
    evaluations of the test (in another order, or in a frame-local copy of the
    G-buffer) differ by a few float64 spacings of that scale, so a margin within
    ``FACING_ULPS`` spacings (``FACING_TOLERANCE``) is a sample on the terminator. Its
    lit value is then the facing test's alone: any crossing of its segment lies at a
    height ``t n . d`` of at most that margin times the scale (t <= 1 for a point light;
    t up to the scene's size along a unit d for a directional one), about 1e-14 of the
    distances involved, far below the cut ``eps`` unless ``shadow_eps`` is set below
    about 1e-12 or the scene lies 1e9 diagonals from the origin."""
    lh = hard_light(light).homogeneous
    idx = tuple(np.asarray(pixels).reshape(-1, 2).T)
    p, n = gbuf.position[idx], gbuf.normal[idx]
    value = facing_test(n, p, lh)
    scale = np.linalg.norm(n, axis=1) * (np.linalg.norm(lh[:3]) + abs(lh[3])
                                         * np.linalg.norm(p, axis=1))
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.where(scale > 0, np.abs(value) / scale, np.inf)


def edge_tolerance(scene: Scene, light: Light, origin=None) -> float:
    """World units: ``EDGE_ULPS`` float32 spacings of the largest absolute coordinate
    of the scene's vertices and the (finite) light position, measured from the frame
    origin ``origin`` (float64 [3], default 0; ``GBuffer.origin``): the methods and
    Embree work in float32 coordinates relative to it (``shadowlab.core.frame``)."""
    lh = hard_light(light).homogeneous
    o = np.zeros(3) if origin is None else np.asarray(origin, np.float64)
    scale = float(np.abs(scene.vertices - o).max(initial=0.0))
    if lh[3]:
        scale = max(scale, float(np.abs(lh[:3] / lh[3] - o).max()))
    return EDGE_ULPS * float(np.finfo(np.float32).eps) * max(scale, 1.0)


def boundary_distance(scene: Scene, gbuf: GBuffer, light: Light, pixels: np.ndarray,
                      shadow_eps: float = DEFAULT_SHADOW_EPS, chunk: int = 65536,
                      reach: float | None = None) -> dict:
    """For pixels [K, 2] (row, col): the float64 margins of their segment to the light.

    Args:
        reach: world units; triangles whose edge the segment misses by more than this
            are not considered (default: ``edge_tolerance(scene, light)``).

    Returns:
        ``edge`` float64 [K]: the smallest world distance, in the caster's plane, from the
        crossing point to an edge line of a caster that the segment crosses (or misses
        by at most ``reach``) above the cut (inf if none), and ``cut`` float64 [K]: the
        smallest relative distance |height - eps| / eps of a crossing.
    """
    hl = hard_light(light)
    lh = hl.homogeneous
    eps = shadow_epsilon(scene, shadow_eps)
    tri = scene.triangles
    a, e1, e2 = tri[:, 0], tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]
    reach = edge_tolerance(scene, light, gbuf.origin) if reach is None else reach
    # World distance per unit of each barycentric coordinate: the triangle's height
    # over the edge where that coordinate is 0 (u: edge v0-v2, v: v0-v1, w: v1-v2).
    twice_area = np.linalg.norm(np.cross(e1, e2), axis=-1)
    with np.errstate(divide="ignore", invalid="ignore"):
        heights = np.stack([twice_area / np.linalg.norm(e2, axis=-1),
                            twice_area / np.linalg.norm(e1, axis=-1),
                            twice_area / np.linalg.norm(e2 - e1, axis=-1)], axis=-1)
    heights = np.nan_to_num(heights, nan=0.0, posinf=0.0)
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
            bary = np.stack([u, v, 1 - u - v], axis=-1)
            world = bary * heights[sl_]                 # signed distances to the edge lines
            margin = world.min(axis=-1)
            near = inside_t & (margin > -reach) & (height > eps)
            if near.any():
                edge[n] = min(edge[n], np.abs(margin[near]).min())
            crossing = inside_t & (bary.min(axis=-1) >= 0)
            if crossing.any():
                cut[n] = min(cut[n], (np.abs(height[crossing] - eps) / eps).min())
    return {"edge": edge, "cut": cut}


def unexplained_mismatches(scene: Scene, gbuf: GBuffer, light: Light, lit: np.ndarray,
                           truth: np.ndarray, shadow_eps: float = DEFAULT_SHADOW_EPS) -> np.ndarray:
    """int [K, 2]: mismatched valid pixels that lie on no shadow boundary (within
    ``edge_tolerance(scene, light, gbuf.origin)`` world units of a caster's edge,
    ``CUT_TOLERANCE`` of the cut, or ``FACING_ULPS`` float64 spacings of the terminator,
    :func:`facing_margin`)."""
    bad = np.argwhere((np.asarray(lit, bool) != np.asarray(truth, bool)) & gbuf.valid)
    if len(bad) == 0:
        return bad
    bad = bad[facing_margin(gbuf, light, bad) > FACING_TOLERANCE]
    if len(bad) == 0:
        return bad
    tol = edge_tolerance(scene, light, gbuf.origin)
    dist = boundary_distance(scene, gbuf, light, bad, shadow_eps, reach=tol)
    explained = (dist["edge"] <= tol) | (dist["cut"] <= CUT_TOLERANCE)
    return bad[~explained]


def unexplained_count(scene: Scene, gbuf: GBuffer, light: Light, lit: np.ndarray,
                      truth: np.ndarray, mask: np.ndarray | None = None,
                      shadow_eps: float = DEFAULT_SHADOW_EPS, limit: int = 200) -> int:
    """How many mismatched pixels (valid, and inside ``mask`` bool [H, W] if given) lie
    on no shadow boundary. Above ``limit`` mismatches none is examined and all count as
    unexplained (an experiment's check then fails, as it should for so many)."""
    keep = np.asarray(gbuf.valid if mask is None else gbuf.valid & mask, bool)
    lit = np.where(keep, np.asarray(lit, bool), np.asarray(truth, bool))
    wrong = int(np.count_nonzero(lit != np.asarray(truth, bool)))
    if wrong == 0 or wrong > limit:
        return wrong
    return len(unexplained_mismatches(scene, gbuf, light, lit, truth, shadow_eps))
