"""The numerics policy: products rounded once, sums in a fixed order.

XLA may fuse ``a * b + c`` into a fused multiply-add, and does so or not depending on
the surrounding program (vector body or remainder, array size, fusion decisions). A
value that decides a bit of the output must therefore not depend on the program it is
traced in. The policy every exact method follows:

- **Opaque products.** :func:`opaque_mul` rounds ``a * b`` once and passes the result
  through an integer bit-cast ORed with a zero XLA cannot prove to be zero
  (:func:`opaque_zero`). No compiler can fuse the product into a following add or
  reassociate across it; the cost is one integer OR per product.
- **Ordered sums.** Sums are explicit left-to-right adds (:func:`ordered_sum`,
  :func:`ordered_dot`), never reductions whose order the compiler picks.

The Warp kernels repeat the same plain operations in the same order, which is how they
equal the JAX methods bit for bit.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np


def _int_like(dtype):
    """The integer dtype with the width of float ``dtype`` (int64 for float64, else int32)."""
    return jnp.int64 if dtype == jnp.float64 else jnp.int32


def opaque_zero(x, dtype=None):
    """An integer 0 [] that XLA cannot prove to be 0: 1 if ``x`` holds a NaN, else 0.

    Callers pick an ``x`` whose NaN would make every meaningful output NaN or invalid
    anyway (e.g. the light of a triangle setup), and compute the zero once per program.

    Args:
        x: float array [...] (any shape).
        dtype: integer dtype of the result; default the integer of ``x``'s width
            (int64 for float64, else int32). One int32 zero serves both precisions:
            :func:`opaque` widens it to the value's width.
    """
    x = jnp.asarray(x)
    return jnp.any(jnp.isnan(x)).astype(_int_like(x.dtype) if dtype is None else dtype)


def opaque(v, zero):
    """``v`` [...] unchanged, but opaque to fused multiply-add contraction.

    Its bits are ORed with ``zero`` (from :func:`opaque_zero`, any integer dtype; cast to
    ``v``'s width), so XLA cannot fuse the value into the operation that consumes it.
    """
    it = _int_like(v.dtype)
    return jax.lax.bitcast_convert_type(
        jax.lax.bitcast_convert_type(v, it) | jnp.asarray(zero).astype(it), v.dtype)


def opaque_mul(a, b, zero):
    """``a * b`` [...] rounded once and opaque to fused multiply-add contraction."""
    return opaque(a * b, zero)


def opaque_multiplier(zero):
    """The function ``mul(a, b) = opaque_mul(a, b, zero)`` (for the helpers below)."""
    def mul(a, b):
        return opaque_mul(a, b, zero)
    return mul


def ordered_sum(terms):
    """``((t0 + t1) + t2) + ...``: the terms [...] added strictly left to right."""
    it = iter(terms)
    total = next(it)
    for t in it:
        total = total + t
    return total


def ordered_dot(a, b, mul):
    """``((a0 b0 + a1 b1) + a2 b2) + ...`` with each product ``mul(a_i, b_i)``.

    Args:
        a, b: equal-length sequences of arrays [...] (e.g. the 3 columns of a vector).
        mul: the product, e.g. from :func:`opaque_multiplier` (or ``numpy.multiply`` in
            a NumPy reference, which never fuses).
    """
    return ordered_sum(mul(x, y) for x, y in zip(a, b))


def cross3(a, b, mul):
    """Cross product of 3-vectors given as 3 columns [...]: ``a_i b_j - a_j b_i``, each
    product ``mul``-rounded."""
    return [mul(a[1], b[2]) - mul(a[2], b[1]),
            mul(a[2], b[0]) - mul(a[0], b[2]),
            mul(a[0], b[1]) - mul(a[1], b[0])]


def _identity_of_max(dtype):
    if jnp.issubdtype(dtype, jnp.floating):
        return jnp.array(-jnp.inf, dtype)
    if dtype == jnp.bool_:
        return jnp.array(False)
    return jnp.array(jnp.iinfo(dtype).min, dtype)


def materialize(*arrays):
    """The ``arrays`` (same shape), computed once into buffers by one fusion: returns
    them unchanged, value for value (NaN and signed zeros included).

    XLA/CPU gives every consumer of an elementwise expression (each output of a loop
    body, each scatter's indices or updates, each reduction) a loop fusion of its own
    that recomputes the whole expression; ``jax.lax.optimization_barrier`` is removed
    before fusion and does not prevent it. A reduction is a fusion root that consumers
    read from memory, so every array is stacked with the identity of ``max`` along a new
    last axis of size 2 and reduced over it by one variadic reduction (one fusion for
    all of them). Measured on a toy expression with three consumers: the expression
    computed 3 times without, once with, 3x faster. (If a later XLA simplified the
    padded reduction away, results would be unchanged, only the speed lost.)
    """
    ops, inits = [], []
    for a in arrays:
        a = jnp.asarray(a)
        ident = _identity_of_max(a.dtype)
        ops.append(jnp.stack([a, jnp.broadcast_to(ident, a.shape)], axis=-1))
        inits.append(ident)
    nd = ops[0].ndim - 1

    def combine(x, y):
        return tuple(jnp.logical_or(u, v) if u.dtype == jnp.bool_ else jax.lax.max(u, v)
                     for u, v in zip(x, y))

    out = jax.lax.reduce(tuple(ops), tuple(inits), combine, (nd,))
    return out if len(arrays) > 1 else out[0]


def cross_columns(a, b):
    """Cross product of NumPy 3-vectors given as 3 columns [...] each: the columns of
    ``a x b``, each ``a_i b_j - a_j b_i`` (the products and differences ``np.cross``
    computes, bit for bit, without its slow reduction-shaped loops on [N, 3] arrays)."""
    return [a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]]


def column_bounds(x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(min, max) [k] of the columns of a NumPy array x [N, k], equal to ``x.min(axis=0)``
    and ``x.max(axis=0)`` (NaN propagates the same way) and about ten times faster on
    [N, 3] arrays: one reduction along each (long) column instead of NumPy's reduction
    across the short axis for every row. Raises ValueError on an empty x, as NumPy does."""
    x = np.asarray(x)
    if x.ndim != 2:
        raise ValueError(f"column_bounds: expected an [N, k] array, got shape {x.shape}")
    lo = np.array([x[:, i].min() for i in range(x.shape[1])], x.dtype)
    hi = np.array([x[:, i].max() for i in range(x.shape[1])], x.dtype)
    return lo, hi


def norms3(x: np.ndarray, keepdims: bool = False, origin=None) -> np.ndarray:
    """Euclidean norms [...] (or [..., 1] with ``keepdims``) of NumPy vectors x [..., 3],
    bit for bit ``np.linalg.norm(x, axis=-1)``: the same squares summed in the same order
    (``(x0^2 + x1^2) + x2^2``; NumPy reduces a length-3 axis sequentially), about four
    times faster on [N, 3] arrays (no strided reduction).

    ``origin`` [3]: the norms of ``x - origin`` in float64 instead, bit for bit
    ``norms3(x - origin)`` with a float64 origin, on coordinate columns."""
    x = np.asarray(x)
    if x.shape[-1:] != (3,):
        raise ValueError(f"norms3: the last axis must have length 3, got shape {x.shape}")
    if not np.issubdtype(x.dtype, np.inexact):
        x = x.astype(np.float64)
    if origin is None:
        a, b, c = x[..., 0], x[..., 1], x[..., 2]
    else:       # bit for bit norms3(x - origin), without the [..., 3] temporary
        x = x.astype(np.float64, copy=False)
        a, b, c = (x[..., i] - origin[i] for i in range(3))
    out = np.sqrt(a * a + b * b + c * c)
    return out[..., None] if keepdims else out
