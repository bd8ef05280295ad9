"""Clip-space visibility test of silhouette side quads (Pečiva 2013, Algorithms 3-6).

A side quad of the edge AB extruded away from the light has the clip-space corners
``A_c = VP (A, 1)``, ``B_c = VP (B, 1)``, ``C_c = VP (A L_w - l, 0)``, ``D_c = VP (B L_w - l, 0)``
(C and D at infinity). Two tests, vectorized over quads (NumPy, per frame, in the dtype
of the inputs: float64 in the method). Every product and sum is an explicit elementwise
operation in a fixed order (no BLAS call, whose summation order and fused multiply-adds
are not fixed), so ``shadowlab.kernels.silhouette.side_visibility`` repeats them and
takes the same decisions bit for bit:

- ``mode="paper"``: Algorithms 3-6 as printed: each of the four edges against the
  clip cube (Liang-Barsky in homogeneous coordinates, Algorithm 3), else the quad
  against one volume diagonal of the cube (Algorithms 4, 5) chosen from the side's
  normal transformed *as a vector*, ``VP (n, 0)``. A plane's normal transforms with the
  inverse transpose, so that choice picks the wrong diagonal for some quads and culls
  sides that cover the whole screen; the near and far planes also cull sides a
  depth-clamped stencil still needs.
- ``mode="exact"``: the four edges against the view *pyramid* ``|x| <= w, |y| <= w``
  (no near or far plane), widened by a relative margin ``MARGIN`` so rounding keeps a
  side rather than culling it, else the four screen-corner eye rays against the
  quad: if the quad meets the pyramid but none of its edges does, the plane's cross
  section of the pyramid lies inside the quad, and its corners are on the corner rays.
  Culls only sides that no view ray between the eye and infinity crosses.
"""

from __future__ import annotations

import math

import numpy as np

from ..core.numerics import cross_columns, ordered_dot

CULL_MODES = ("off", "paper", "exact")
MARGIN = 2.0 ** -10


def _dot(x, y):
    """``((x0 y0 + x1 y1) + x2 y2) + ...`` of column lists (arrays [N] or scalars)."""
    return ordered_dot(x, y, np.multiply)


def _cols(x):
    return [x[..., k] for k in range(x.shape[-1])]


def _transform(m: np.ndarray, x: np.ndarray) -> np.ndarray:
    """``x @ m.T`` for x [N, 4] and m [4, 4], each row an ordered dot product."""
    xc = _cols(x)
    return np.stack([_dot(xc, list(m[i])) for i in range(4)], axis=1)


def clip_corners(a: np.ndarray, b: np.ndarray, light_h: np.ndarray, vp: np.ndarray):
    """Clip-space corners [N, 4] each (A_c, B_c, C_c, D_c) of the side quads of edges
    a, b [N, 3] (world units) from the homogeneous light [4] (all in one dtype)."""
    one = np.ones((len(a), 1), a.dtype)
    zero = np.zeros((len(a), 1), a.dtype)
    lw, lx = light_h[3], light_h[:3]
    corners = [np.hstack([a, one]), np.hstack([b, one]), np.hstack([a * lw - lx, zero]),
               np.hstack([b * lw - lx, zero])]
    return [_transform(vp, c) for c in corners]


def edge_visible(p: np.ndarray, q: np.ndarray, axes: int = 3, margin: float = 0.0) -> np.ndarray:
    """Algorithm 3: bool [N], the clip-space segment p -> q [N, 4] meets the clip region.

    ``axes=3`` is the cube |x|, |y|, |z| <= w; ``axes=2`` the pyramid |x|, |y| <= w.
    ``margin`` widens the region to |x| <= (1 + margin) w.
    """
    left = np.zeros(len(p), p.dtype)
    right = np.ones(len(p), p.dtype)
    ok = np.ones(len(p), bool)
    widen = p.dtype.type(1 + margin)
    wp, wq = p[:, 3] * widen, q[:, 3] * widen
    for i in range(axes):
        for s in (1.0, -1.0):
            m = s * p[:, i] + wp
            n = s * q[:, i] + wq
            v = n - m
            with np.errstate(divide="ignore", invalid="ignore"):
                root = -m / v
            ok &= ~((v == 0) & (m < 0))
            left = np.where(v > 0, np.maximum(left, root), left)
            right = np.where(v < 0, np.minimum(right, root), right)
    return ok & (left <= right)


def diagonal_id(a: np.ndarray, b: np.ndarray, light_h: np.ndarray, vp: np.ndarray) -> np.ndarray:
    """Algorithm 4: int [N] in {-1, 0, 1, 2}, from the side normal transformed as a vector."""
    n = cross_columns(_cols(b - a), _cols(light_h[:3] - light_h[3] * a))
    s = np.stack([_dot(n, list(vp[i, :3])) for i in range(3)], axis=1)
    u = (s > 0).astype(np.int64)            # floor((1 + sgn s) / sqrt 2)
    u = np.where(u[:, 2:3] == 1, 1 - u, u)
    return u[:, 0] + 2 * u[:, 1] - 1


def diagonal_id_plane(a: np.ndarray, b: np.ndarray, light_h: np.ndarray, vp: np.ndarray
                      ) -> np.ndarray:
    """Algorithm 4 with the corrected normal: the side plane pi = (n, -n.A) mapped to clip
    space as ``pi VP^-1`` (a plane transforms with the inverse transpose), then the same
    sign-to-diagonal rule. int [N] in {-1, 0, 1, 2}."""
    n = np.cross(b - a, light_h[:3] - light_h[3] * a)
    plane = np.hstack([n, -np.einsum("ij,ij->i", n, a)[:, None]])
    s = plane @ np.linalg.inv(vp)
    u = np.floor((1 + np.sign(s[:, :3])) / math.sqrt(2)).astype(np.int64)
    u = np.where(u[:, 2:3] == 1, 1 - u, u)
    return u[:, 0] + 2 * u[:, 1] - 1


def full_visible(a: np.ndarray, f: np.ndarray, g: np.ndarray, diag: np.ndarray) -> np.ndarray:
    """Algorithm 5: bool [N], the parallelogram a + t f + l g (clip space [N, 4]) meets
    the diagonal ``diag`` of the clip cube inside the cube."""
    av, bv, cv = a[:, :3].copy(), f[:, :3].copy(), g[:, :3].copy()
    rows = np.flatnonzero(diag >= 0)
    for arr in (av, bv, cv):
        arr[rows, diag[rows]] *= -1
    m, n, o = av[:, 0] - av[:, 1], bv[:, 0] - bv[:, 1], cv[:, 0] - cv[:, 1]
    p, q, r = av[:, 0] - av[:, 2], bv[:, 0] - bv[:, 2], cv[:, 0] - cv[:, 2]
    d = q * o - n * r
    with np.errstate(divide="ignore", invalid="ignore"):
        t = (m * r - p * o) / d
        l_ = -(m * q - p * n) / d
    x = a + t[:, None] * f + l_[:, None] * g
    inside = np.all((-x[:, 3:4] < x[:, :3]) & (x[:, :3] < x[:, 3:4]), axis=1)
    return (d != 0) & (t > 0) & (t < 1) & (l_ > 0) & (l_ < 1) & inside


def corner_rays_cross(a: np.ndarray, b: np.ndarray, light_h: np.ndarray, eye: np.ndarray,
                      rays: np.ndarray) -> np.ndarray:
    """bool [N]: some eye ray ``eye + t rays[k]`` (t > 0; rays [K, 3]) crosses the side quad
    of edge a, b [N, 3]: the line AB pierces the wedge (E, L, infinity along the ray)."""
    ap, bp = _cols(a - eye), _cols(b - eye)
    lp = list(light_h[:3] - light_h[3] * eye)
    lw = light_h[3]
    out = np.zeros(len(a), bool)
    ab = cross_columns(ap, bp)
    pi3 = -_dot(lp, ab)
    la, lb = cross_columns(lp, ap), cross_columns(lp, bp)
    r = cross_columns([lp[k] - lw * ap[k] for k in range(3)], [bp[k] - ap[k] for k in range(3)])
    for d in rays:
        d = list(d)
        sa = _dot(la, d)
        sb = _dot(lb, d)
        pi1 = _dot(ab, d)
        rho = _dot(r, d)
        out |= ((sa >= 0) != (sb >= 0)) & ((pi1 >= 0) == (rho >= 0)) & ((rho >= 0) == (pi3 >= 0))
    return out


def side_visible(a: np.ndarray, b: np.ndarray, light_h: np.ndarray, camera, mode: str,
                 diagonal: str = "paper", dtype=np.float64) -> np.ndarray:
    """bool [N]: keep the side quad of edge a, b [N, 3] (world units) under ``mode``
    ("paper" or "exact", see the module docstring; "off" keeps all). ``diagonal``
    ("paper" or "plane", :func:`diagonal_id_plane`) picks Algorithm 4's rule for the
    paper's test, to tell its two defects apart. ``dtype``: the arithmetic's precision
    (the inputs, the camera's matrix, eye and corner rays are rounded to it first)."""
    if mode == "off":
        return np.ones(len(a), bool)
    if mode not in CULL_MODES:
        raise ValueError(f"cull mode must be one of {CULL_MODES}, got {mode!r}")
    a, b = np.asarray(a, dtype), np.asarray(b, dtype)
    light_h = np.asarray(light_h, dtype)
    vp = camera.view_projection().astype(dtype)
    ac, bc, cc, dc = clip_corners(a, b, light_h, vp)
    axes, margin = (3, 0.0) if mode == "paper" else (2, MARGIN)
    vis = np.zeros(len(a), bool)
    for p, q in ((ac, bc), (ac, cc), (bc, dc), (cc, dc)):
        vis |= edge_visible(p, q, axes, margin)
    if mode == "paper":
        pick = diagonal_id if diagonal == "paper" else diagonal_id_plane
        vis |= full_visible(ac, bc - ac, cc - ac, pick(a, b, light_h, vp))
    else:
        vis |= corner_rays_cross(a, b, light_h, np.asarray(camera.eye, dtype),
                                 screen_corner_rays(camera).astype(dtype))
    return vis


def screen_corner_rays(camera) -> np.ndarray:
    """float64 [4, 3]: directions from the eye through the four corners of the image
    (the edges of the view pyramid), widened by ``MARGIN``."""
    t = math.tan(math.radians(camera.fov_y_deg) / 2) * (1 + MARGIN)
    r, u, back = camera.basis()
    return np.array([sx * t * camera.aspect * r + sy * t * u - back
                     for sx in (-1, 1) for sy in (-1, 1)])
