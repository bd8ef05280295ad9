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


def shifted_scan(x, combine, fill):
    """Inclusive prefix scan of ``x`` [..., P] along its last axis (P small, e.g. a row of
    a tile or a chunk of a few thousand slots) in log2(P) passes, each combining every
    element with the one ``shift`` before it (``fill``, the identity of ``combine``, where
    there is none). XLA/CPU lowers ``cumsum`` / ``cummax`` over such an axis to a windowed
    reduction, several times slower.

    Args:
        x: array [..., P]; combine: elementwise associative op, e.g. ``jnp.add`` or
            ``jnp.maximum``; fill: its identity for x's values (0 for sums; for a max,
            anything at most every value).
    """
    widths = [(0, 0)] * (x.ndim - 1)
    shift = 1
    while shift < x.shape[-1]:
        x = combine(x, jnp.pad(x[..., :-shift], widths + [(shift, 0)], constant_values=fill))
        shift *= 2
    return x


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


# --------------------------------------------------------------------------- packed intervals
#
# An interval [lo, hi] with lo <= 0 <= hi stored in one word of a float dtype's width:
# each end rounded away from zero (outward, so the stored interval holds the exact one)
# to a float of half that width, hi in the upper half. float32 words hold two bfloat16
# values (a float32's upper 16 bits: its exponent range, 8 significant bits, so each end
# moves out by less than 2^-7 of itself); float64 words hold two float32 values. An
# empty interval (lo = +inf, hi = -inf) packs exactly. A nonzero end below the half
# float's smallest normal is stored as that normal (XLA/CPU flushes subnormal inputs to
# zero, which would move the end inwards).

_HALVES = {np.dtype(np.float32): (np.uint32, np.uint16, 16),
           np.dtype(np.float64): (np.uint64, np.uint32, 32)}


def _round_half_away(x: np.ndarray, dtype) -> np.ndarray:
    """The upper-half bits (uint16 / uint32) of x rounded away from zero to a float of
    half ``dtype``'s width; infinities stay infinite, a finite x beyond that float's
    range becomes infinite (still outward)."""
    word, half, shift = _HALVES[np.dtype(dtype)]
    if half == np.uint16:          # bfloat16: a float32's upper half, magnitude up
        b = np.asarray(x, np.float32).view(np.uint32)
        low = b & np.uint32(0xFFFF)
        finite = (b & np.uint32(0x7F800000)) != np.uint32(0x7F800000)
        up = (low != 0) & finite
        h = (b >> np.uint32(16)) + up.astype(np.uint32)
        # a subnormal half becomes the smallest normal (XLA/CPU flushes subnormals)
        sub = ((h & np.uint32(0x7F80)) == 0) & ((h & np.uint32(0x7F)) != 0)
        h = np.where(sub, (h & np.uint32(0x8000)) | np.uint32(0x0080), h)
        return h.astype(np.uint16)
    x = np.asarray(x, np.float64)
    with np.errstate(over="ignore"):
        y = x.astype(np.float32)
    short = np.isfinite(x) & (np.abs(y.astype(np.float64)) < np.abs(x))
    y = np.where(short, np.nextafter(y, np.copysign(np.float32(np.inf), y)), y)
    tiny = np.finfo(np.float32).tiny        # XLA/CPU flushes subnormals: round them up
    y = np.where((y != 0) & (np.abs(y) < tiny), np.copysign(tiny, y), y)
    return y.astype(np.float32).view(np.uint32)


def pack_interval(lo: np.ndarray, hi: np.ndarray, dtype) -> np.ndarray:
    """[lo, hi] [...] rounded outward and packed into one word each (see above).

    lo, hi: NumPy arrays of one shape with lo <= 0 <= hi, or lo = +inf, hi = -inf
    (empty); the rounding moves magnitudes up, which is outward only for such intervals.
    dtype: float32 or float64, the word's width. Returns the words [...] as ``dtype``
    (bits, not values; :func:`unpack_interval` and :func:`unpack_interval_np` read them).
    """
    lo, hi = np.asarray(lo), np.asarray(hi)
    ok = ((lo <= 0) & (hi >= 0)) | ((lo == np.inf) & (hi == -np.inf))
    if not np.all(ok):
        raise ValueError("pack_interval: needs lo <= 0 <= hi (or an empty interval "
                         "lo = +inf, hi = -inf)")
    word, half, shift = _HALVES[np.dtype(dtype)]
    w = (_round_half_away(hi, dtype).astype(word) << word(shift)) | \
        _round_half_away(lo, dtype).astype(word)
    return w.view(dtype)


def unpack_interval_np(words: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(lo, hi) [...] in the words' float dtype, the values :func:`unpack_interval`
    gives (NumPy; for plain reference loops and the Warp kernels)."""
    words = np.asarray(words)
    word, half, shift = _HALVES[words.dtype]
    b = words.view(word)
    if half == np.uint16:
        return ((b << np.uint32(16)).view(np.float32),
                (b & np.uint32(0xFFFF0000)).view(np.float32))
    lo = (b & np.uint64(0xFFFFFFFF)).astype(np.uint32).view(np.float32)
    hi = (b >> np.uint64(32)).astype(np.uint32).view(np.float32)
    return lo.astype(np.float64), hi.astype(np.float64)


def unpack_interval(words):
    """(lo, hi) [...] in the words' float dtype from :func:`pack_interval`'s words (JAX;
    integer shifts and masks, then bit-casts: exact)."""
    bc = jax.lax.bitcast_convert_type
    if words.dtype == jnp.float32:
        b = bc(words, jnp.uint32)
        return (bc(b << jnp.uint32(16), jnp.float32),
                bc(b & jnp.uint32(0xFFFF0000), jnp.float32))
    b = bc(words, jnp.uint64)
    lo = bc((b & jnp.uint64(0xFFFFFFFF)).astype(jnp.uint32), jnp.float32)
    hi = bc((b >> jnp.uint64(32)).astype(jnp.uint32), jnp.float32)
    return lo.astype(jnp.float64), hi.astype(jnp.float64)


def max_abs(x: np.ndarray) -> float:
    """The largest ``|x|`` over every element of ``x`` (0.0 when empty; NaN if any is
    NaN), as ``np.abs(x).max(initial=0.0)`` without its temporary the size of ``x`` for
    floating-point input (other dtypes take that expression: negating an integer minimum
    can wrap)."""
    x = np.asarray(x)
    if not np.issubdtype(x.dtype, np.floating):
        return float(np.abs(x.astype(np.float64)).max(initial=0.0))
    if x.size == 0:
        return 0.0
    return float(np.maximum(x.max(), -x.min()))
