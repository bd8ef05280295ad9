"""``brute_force``: every view sample against every triangle's shadow volume.

The slow but simple oracle. Triangle setup builds the four planes of each shadow
volume (the math of ``shadowlab.geometry.planes``, rounded the same way at every array
size: see :func:`setup`); the test loops over triangles in unrolled
chunks (``lax.fori_loop``) and is vectorized over all samples, so XLA fuses each
chunk into one pass over the samples. A sample is shadowed when it is inside any
volume: inside all three edge planes (inclusive) and behind the cap by more than the
bias (option ``bias``: ``"receiver"``, the reference's criterion, or ``"cap"``, the
papers'; see ``common.bias_terms``).
"""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp
import numpy as np

from ..geometry.planes import degeneracy_tolerance
from ..scene.view import hard_light
from ..timing import StageTimer
from .common import BIAS_MODES, bias_terms, bucket, cap_bias, precision_mode, view_samples
from .registry import Option, register
from .result import ShadowResult


def opaque_zero(x):
    """An integer 0 [] that XLA cannot prove to be 0: 1 if ``x`` holds a NaN, else 0.

    ``opaque_mul`` ORs it into a product's bits. Callers pick an ``x`` whose NaN makes
    every meaningful output NaN or invalid anyway (the light in :func:`setup`).
    """
    it = jnp.int64 if x.dtype == jnp.float64 else jnp.int32
    return jnp.any(jnp.isnan(x)).astype(it)


def opaque_mul(a, b, zero):
    """a * b, rounded once and opaque to fused multiply-add contraction.

    The product goes through an integer bit-cast and an OR with ``zero``
    (``opaque_zero``: not a compile-time constant), so no compiler can fuse it into a
    following add or reassociate across it; the cost is one integer OR.
    """
    p = a * b
    it = jnp.int64 if p.dtype == jnp.float64 else jnp.int32
    return jax.lax.bitcast_convert_type(jax.lax.bitcast_convert_type(p, it) | zero, p.dtype)


def _dot3(a, b, mul):
    """(a0 b0 + a1 b1) + a2 b2, each product rounded; a, b: 3 columns [T]."""
    return (mul(a[0], b[0]) + mul(a[1], b[1])) + mul(a[2], b[2])


def _cross3(a, b, mul):
    """Cross product of 3 columns [T]: a_i b_j - a_j b_i, both products rounded."""
    return [mul(a[1], b[2]) - mul(a[2], b[1]),
            mul(a[2], b[0]) - mul(a[0], b[2]),
            mul(a[0], b[1]) - mul(a[1], b[0])]


def _lex_less(a, b):
    ax, ay, az = a
    bx, by, bz = b
    return (ax < bx) | ((ax == bx) & ((ay < by) | ((ay == by) & (az < bz))))


def _plane(n, d, flip, mul):
    """Oriented, normalised plane [4 columns] and the normal's length [T]."""
    n = [jnp.where(flip, -x, x) for x in n]
    d = jnp.where(flip, -d, d)
    length = jnp.sqrt(_dot3(n, n, mul))
    safe = jnp.where(length > 0, length, 1)
    return [n[0] / safe, n[1] / safe, n[2] / safe, d / safe], length


@jax.jit
def setup(tri, light):
    """Planes [T, 16] (four planes of four coefficients) and valid [T] from tri [T, 3, 3].

    The planes and validity of ``geometry.planes.shadow_volume_planes``, written so that
    every value is the same IEEE operations in the same order for any T (the Warp
    kernel ``kernels.clustered_ptsv.setup`` and ``tests/test_brute_force.py``'s NumPy
    loop repeat them): products through :func:`opaque_mul` (XLA would otherwise fuse
    ``a*b + c`` into FMAs where its vector code for the given T happens to), sums of
    three as ``(x0 + x1) + x2`` (no reductions), each normal component and the offset
    divided by the length (four true divisions, no reciprocal), lengths
    ``sqrt((n0 n0 + n1 n1) + n2 n2)``, sides flipped by negation.

    Args:
        tri: [T, 3, 3] corners (world units). light: [4] homogeneous light.
    """
    zero = opaque_zero(light)

    def mul(a, b):
        return opaque_mul(a, b, zero)

    tol = degeneracy_tolerance(tri.dtype)
    v = [[tri[:, i, k] for k in range(3)] for i in range(3)]
    lxyz, lw = [light[k] for k in range(3)], light[3]

    def norm(x):
        return jnp.sqrt(_dot3(x, x, mul))

    def sub(a, b):
        return [a[k] - b[k] for k in range(3)]

    cols, ok = [], jnp.ones(tri.shape[0], dtype=bool)
    for i in range(3):
        a, b, c = v[i], v[(i + 1) % 3], v[(i + 2) % 3]
        swap = _lex_less(b, a)
        lo = [jnp.where(swap, b[k], a[k]) for k in range(3)]
        hi = [jnp.where(swap, a[k], b[k]) for k in range(3)]
        to_light = [lxyz[k] - mul(lw, lo[k]) for k in range(3)]
        n = _cross3(sub(hi, lo), to_light, mul)
        d = -_dot3(n, lo, mul)
        side = _dot3(n, c, mul) + d
        plane, length = _plane(n, d, side < 0, mul)
        reach = jnp.maximum(norm(sub(c, a)), norm(sub(c, b)))
        ok &= (length > 0) & (jnp.abs(side) > mul(mul(tol, length), reach))
        cols += plane
    cn = _cross3(sub(v[1], v[0]), sub(v[2], v[0]), mul)
    cd = -_dot3(cn, v[0], mul)
    light_side = _dot3(cn, lxyz, mul) + mul(lw, cd)
    plane, length = _plane(cn, cd, light_side < 0, mul)
    to_light = norm([lxyz[k] - mul(lw, v[0][k]) for k in range(3)])
    ok &= (length > 0) & (jnp.abs(light_side) > mul(mul(tol, length), to_light))
    cols += plane
    return jnp.stack(cols, axis=1), ok


@functools.lru_cache(maxsize=None)
def _test_kernel(chunk: int):
    @jax.jit
    def test(points, scale, planes, bound, n_chunks):
        """bool [S]: points [S, 3] inside any volume of planes [T, 16] (T % chunk == 0).

        ``scale`` [S] and ``bound`` [T] are the bias terms of ``common.bias_terms``;
        invalid triangles have ``bound = -inf``. Only the first ``n_chunks`` chunks are
        visited: the padding of the triangle capacity costs nothing.
        """
        px, py, pz = points[:, 0], points[:, 1], points[:, 2]

        def body(i, shadow):
            blk = jax.lax.dynamic_slice_in_dim(planes, i * chunk, chunk)
            lim = jax.lax.dynamic_slice_in_dim(bound, i * chunk, chunk)
            for j in range(chunk):
                p = blk[j]
                e0 = px * p[0] + py * p[1] + pz * p[2] + p[3]
                e1 = px * p[4] + py * p[5] + pz * p[6] + p[7]
                e2 = px * p[8] + py * p[9] + pz * p[10] + p[11]
                cap = px * p[12] + py * p[13] + pz * p[14] + p[15]
                shadow = shadow | ((e0 >= 0) & (e1 >= 0) & (e2 >= 0) & (cap * scale < lim[j]))
            return shadow

        return jax.lax.fori_loop(0, n_chunks, body, jnp.zeros(points.shape[0], dtype=bool))
    return test


@register("brute_force", doc="every view sample against every triangle's shadow volume "
          "(the exact oracle)", paper="DESIGN.md (oracle)", kind="exact",
          counters=("samples", "casters", "culled_triangles", "tests", "tests_per_pixel",
                    "shadowed", "lit"),
          stages=("samples", "setup", "bias", "test"),
          options={"chunk": Option(16, "triangles per unrolled loop step", allowed=(4, 8, 16, 32)),
                   "bias": Option("receiver", "self-shadowing bias: 'receiver' = eps above the "
                                  "receiver's tangent plane (as the reference), 'cap' = eps "
                                  "behind the caster's plane (as the papers)",
                                  allowed=BIAS_MODES)})
def brute_force(scene, gbuf, light, *, precision, shadow_eps, chunk, bias):
    timer = StageTimer()
    with timer.stage("samples"):
        samples = view_samples(gbuf, light)
    with precision_mode(precision) as dtype:
        t = bucket(scene.num_triangles, minimum=chunk)
        tri = np.zeros((t, 3, 3), dtype=dtype)
        tri[: scene.num_triangles] = scene.triangles
        light_h = hard_light(light).homogeneous.astype(dtype)
        planes, valid = timer.run("setup", setup, jnp.asarray(tri), jnp.asarray(light_h))
        with timer.stage("bias"):
            valid = np.array(valid)
            valid[scene.num_triangles:] = False
            scale, bound = bias_terms(samples, hard_light(light).homogeneous,
                                      np.asarray(planes).reshape(-1, 4, 4),
                                      cap_bias(scene, shadow_eps), bias)
            bound = np.where(valid, bound, -np.inf).astype(dtype)
            points = jnp.asarray(samples.padded_position(dtype))
            scale = jnp.asarray(samples.padded(scale, dtype))
        n_chunks = jnp.asarray(-(-scene.num_triangles // chunk), dtype=jnp.int32)
        shadow = timer.run("test", _test_kernel(chunk), points, scale, planes, jnp.asarray(bound),
                           n_chunks)
    shadow = np.asarray(shadow)[: samples.count]
    casters = int(valid.sum())
    lit_values = ~shadow
    lit = samples.scatter(lit_values, fill=False)
    counters = {
        "samples": samples.count,
        "casters": casters,
        "culled_triangles": scene.num_triangles - casters,
        "tests": samples.count * casters,
        "tests_per_pixel": samples.scatter(np.full(samples.count, casters, np.int64), fill=0),
        "shadowed": int(shadow.sum()),
        "lit": int(lit.sum()),
    }
    timings = dict(timer.times, total=timer.total)
    return ShadowResult(lit, counters, timings)
