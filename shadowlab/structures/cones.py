"""Truncated cones bounding what a blocker can shadow, and conservative tests on them.

A blocker (a triangle, or a group of triangles) with bounding sphere (c, rho) can only
shadow points inside a cone: for a sun of angular radius r, the cone of half-angle r
around the light's travel direction with its apex rho / sin(r) behind c; for a sphere
light (L, R), the penumbra cone through the internal similitude centre of the two
spheres, half-angle asin((R + rho) / |c - L|). The cone is truncated by the plane through
the blocker's vertex closest to the light (nothing before it is shadowed). A cone is a
dict of arrays (the leading axes index cones):

- ``apex`` [..., 3], ``axis`` [..., 3] (unit, away from the light), world units;
- ``sin``, ``cos`` [...] of the half-angle;
- ``t0`` [...]: points p with p . axis < t0 are never shadowed (world units);
- ``always`` bool [...]: no finite cone (the blocker is too close to a sphere light).

The tests are conservative: they may keep a cone that shadows nothing, never drop one
that shadows something, also in float32 far from the origin: every comparison is
relaxed by a bound on its rounding error, ``ROUND_C`` units in the last place of the
magnitudes involved (:func:`rounding_slack`; the argument is in docs/soft_tiled.md,
"Culling in float32").
"""

from __future__ import annotations

import math

import jax
import jax.numpy as jnp
import numpy as np

from ..core.capacity import bucket
from ..core.numerics import norms3
from ..scene.view import SphereLight

GOLDEN_ITERS = 16       # golden-section steps of the capsule test
ROUND_C = 64            # rounding slack, in unit roundoffs of the largest magnitude


def rounding_slack(dtype, *magnitudes):
    """ROUND_C * u * (sum of ``magnitudes``), u the unit roundoff of ``dtype``: a bound on
    the rounding error of the cone distances and dot products computed here from inputs
    of those magnitudes (world units; see docs/soft_tiled.md)."""
    u = float(jnp.finfo(dtype).eps) / 2
    return ROUND_C * u * sum(magnitudes)


def _norm3(v):
    return jnp.sqrt(v[0] * v[0] + v[1] * v[1] + v[2] * v[2])


def blocker_cones(tri: np.ndarray, groups: np.ndarray | None, light: SphereLight,
                  ) -> dict[str, np.ndarray]:
    """Truncated cones bounding what each blocker can shadow (float64, NumPy).

    Args:
        tri: float64 [T, 3, 3] triangles.
        groups: None (one cone per triangle) or int [C, k] triangle ids (-1 = none),
            one cone per group.
    Returns:
        dict of apex [n, 3], axis [n, 3] (unit, away from the light), sin [n], cos [n],
        t0 [n] (points p with p . axis < t0 are never shadowed), always bool [n]
        (no finite cone: the blocker is too close to a sphere light).
    """
    if groups is None:
        pts = tri                                              # [n, 3, 3]
        mask = np.ones(tri.shape[:2], bool)
    else:
        pts = tri[np.maximum(groups, 0)].reshape(len(groups), 3 * groups.shape[1], 3)
        mask = np.repeat(groups >= 0, 3, axis=1)
    big = np.where(mask[..., None], pts, np.nan)
    lo = np.nanmin(big, axis=1)
    hi = np.nanmax(big, axis=1)
    centre = 0.5 * (lo + hi)
    rho = np.sqrt(np.nanmax(((big - centre[:, None]) ** 2).sum(-1), axis=1))
    rho = rho * (1 + 1e-6) + 1e-9
    n = len(centre)
    if light.is_sun:
        axis = np.broadcast_to(light.direction, (n, 3)).copy()
        r = math.radians(light.angular_radius_deg)
        sin_a = np.full(n, math.sin(r))
        apex = centre - axis * (rho / sin_a)[:, None]
        always = np.zeros(n, bool)
    else:
        L = light.position
        to_c = centre - L
        dist = norms3(to_c)
        axis = to_c / np.maximum(dist, 1e-300)[:, None]
        R = light.radius
        always = R + rho >= dist
        sin_a = np.where(always, 1.0, (R + rho) / np.maximum(dist, 1e-300))
        apex = (rho[:, None] * L + R * centre) / (R + rho)[:, None]
    cos_a = np.sqrt(np.maximum(1 - sin_a ** 2, 0))
    proj = np.einsum("nki,ni->nk", np.where(mask[..., None], pts, 0.0), axis)
    t0 = np.where(mask, proj, np.inf).min(axis=1)
    return {"apex": apex, "axis": axis, "sin": sin_a, "cos": cos_a, "t0": t0,
            "always": always}


def _split(v):
    """A [..., 3] array as a tuple of three [...] arrays (structure of arrays)."""
    return tuple(v[..., i] for i in range(3))


def _cone_dist(p, apex, axis, sin_a, cos_a):
    """Distance [...] from points p to infinite solid cones; p, apex, axis: 3-tuples."""
    v = tuple(p[i] - apex[i] for i in range(3))
    h = v[0] * axis[0] + v[1] * axis[1] + v[2] * axis[2]
    vv = v[0] * v[0] + v[1] * v[1] + v[2] * v[2]
    # the distance from the axis as |v x axis|, not sqrt(|v|^2 - h^2): no cancellation
    # (that form loses half the digits, an error of sqrt(u) |v|)
    c = (v[1] * axis[2] - v[2] * axis[1], v[2] * axis[0] - v[0] * axis[2],
         v[0] * axis[1] - v[1] * axis[0])
    q = _norm3(c)
    side = q * cos_a - h * sin_a
    return jnp.where(side <= 0, 0.0,
                     jnp.where(h * cos_a + q * sin_a >= 0, side, jnp.sqrt(vv)))


def cone_hits_capsule(cone, s0, s1, r0, r1):
    """Conservative: may the truncated cone meet the capsule hull(B(s0, r0), B(s1, r1))?

    f(t) = dist(s(t), cone) - r(t) is convex on [0, 1]; golden-section search brackets
    its minimum, and f(t*) - Lip * bracket <= 0 accepts (Lip = |s1 - s0| + |r1 - r0|), so
    the test never rejects a capsule that meets the cone. A sphere is s0 = s1, r0 = r1.

    Args:
        cone: dict of arrays broadcastable to [...] (apex/axis [..., 3]).
        s0, s1: [..., 3]; r0, r1: [...].
    Returns:
        bool [...].
    """
    apex, axis, sa, ca = _split(cone["apex"]), _split(cone["axis"]), cone["sin"], cone["cos"]
    s0, s1 = _split(s0), _split(s1)
    ds = tuple(s1[i] - s0[i] for i in range(3))

    def f(t):
        p = tuple(s0[i] + t * ds[i] for i in range(3))
        return _cone_dist(p, apex, axis, sa, ca) - (r0 + t * (r1 - r0))

    shape = jnp.broadcast_shapes(r0.shape, sa.shape)
    lo = jnp.zeros(shape, r0.dtype)
    hi = jnp.ones(shape, r0.dtype)
    g = (math.sqrt(5) - 1) / 2
    a = hi - g * (hi - lo)
    b = lo + g * (hi - lo)
    fa, fb = f(a), f(b)
    for _ in range(GOLDEN_ITERS):          # one new evaluation per step
        left = fa <= fb                      # the minimum lies in [lo, b] or in [a, hi]
        hi = jnp.where(left, b, hi)
        lo = jnp.where(left, lo, a)
        x = jnp.where(left, hi - g * (hi - lo), lo + g * (hi - lo))
        fx = f(x)
        a, b, fa, fb = (jnp.where(left, x, b), jnp.where(left, a, x),
                        jnp.where(left, fx, fb), jnp.where(left, fa, fx))
    t = 0.5 * (lo + hi)
    lip = jnp.sqrt(ds[0] ** 2 + ds[1] ** 2 + ds[2] ** 2) + jnp.abs(r1 - r0)
    best = jnp.minimum(jnp.minimum(f(t), f(jnp.zeros_like(t))), f(jnp.ones_like(t)))
    # rounding: every f and dot product below is computed from inputs of at most this
    # magnitude (points of the capsule, the apex, radii, t0)
    size = (_norm3(apex) + jnp.maximum(_norm3(s0), _norm3(s1)) + jnp.abs(r0) + jnp.abs(r1)
            + jnp.abs(jnp.where(jnp.isfinite(cone["t0"]), cone["t0"], 0.0)))
    slack = rounding_slack(r0.dtype, size)
    meets = best - lip * (hi - lo) <= slack
    reach = jnp.maximum(s0[0] * axis[0] + s0[1] * axis[1] + s0[2] * axis[2] + r0,
                        s1[0] * axis[0] + s1[1] * axis[1] + s1[2] * axis[2] + r1)
    return (meets & (reach + slack >= cone["t0"])) | cone["always"]


def cone_outside_plane(cone, normal, offset):
    """bool [...]: the truncated cone lies entirely in n . x + offset < 0.

    Its start cap (the disk where p . axis = t0) must be outside and every ray of the
    cone must move away from the plane (n . axis <= -sin a).
    """
    apex, axis, sa, ca = cone["apex"], cone["axis"], cone["sin"], cone["cos"]
    nd = jnp.sum(normal * axis, -1)
    h = cone["t0"] - jnp.sum(apex * axis, -1)                 # apex to the cap, along axis
    h = jnp.maximum(h, 0.0)
    cap_c = apex + h[..., None] * axis
    cap_r = h * sa / jnp.maximum(ca, 1e-30)
    lateral = jnp.sqrt(jnp.maximum(1 - nd * nd, 0.0))
    dtype = nd.dtype
    slack = rounding_slack(dtype, jnp.sqrt(jnp.sum(apex * apex, -1)), h, cap_r,
                           jnp.abs(offset))
    cap_out = jnp.sum(normal * cap_c, -1) + offset + cap_r * lateral < -slack
    return cap_out & (nd <= -sa - rounding_slack(dtype, 1.0)) & ~cone["always"]


@jax.jit
def cones_in_frustum(cone, planes, s0, s1, r0, r1):
    """bool [n]: the cones [n] that may shadow a sample of a view frustum.

    The frustum is given twice: as six planes [6, 4] (inside where n . x + d >= 0; a
    cone entirely outside one is dropped) and as the capsule hull(B(s0, r0), B(s1, r1))
    bounding it (s0, s1 [3], r0, r1 scalars, world units; a cone missing it is dropped).
    """
    keep = cone_hits_capsule(cone, s0, s1, r0, r1)
    for k in range(6):
        keep = keep & ~cone_outside_plane(cone, planes[k, :3], planes[k, 3])
    return keep


def pad_cones(cone: dict) -> dict:
    """The cones [n] padded to a bucketed length [m] >= n (at least 256, 8 sizes per
    octave, so few compiled shapes): padding cones have t0 = inf and meet nothing."""
    n = len(cone["t0"])
    cap = bucket(max(n, 1), minimum=256, steps=8)
    out = {}
    for k, v in cone.items():
        fill = {"t0": np.inf, "always": False}.get(k, 0.0)
        if k == "axis":
            fill = 0.0
        pad = np.full((cap - n,) + v.shape[1:], fill, dtype=v.dtype)
        if k == "axis":
            pad[..., 2] = 1.0
        if k in ("sin",):
            pad[:] = 0.5
        if k == "cos":
            pad[:] = math.sqrt(0.75)
        out[k] = np.concatenate([v, pad])
    return out
