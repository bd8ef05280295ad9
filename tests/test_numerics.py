"""The numerics policy (``core.numerics``): opaque products keep IEEE product bits and
are never fused into a following add; ordered sums add strictly left to right."""

import functools

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from shadowlab.core.numerics import (column_bounds, cross3, max_abs, norms3, opaque, opaque_mul, opaque_multiplier,
                                     pack_interval, unpack_interval, unpack_interval_np,
                                     opaque_zero, ordered_dot, ordered_sum)
from shadowlab.core.frame import precision_mode


def _operands(dt, n=4096, seed=0):
    rng = np.random.default_rng(seed)
    a, b = (rng.uniform(-4, 4, n) * 10.0 ** rng.integers(-3, 4, n) for _ in range(2))
    c = -(a * b) * (1 + rng.uniform(-1e-6, 1e-6, n))     # near-cancellation: FMA shows
    return a.astype(dt), b.astype(dt), c.astype(dt)


@pytest.mark.parametrize("precision", ["float32", "float64"])
def test_opaque_zero_is_zero_unless_nan(precision):
    with precision_mode(precision) as dt:
        wide = jnp.int64 if dt == np.float64 else jnp.int32
        x = jnp.asarray(np.ones(5, dt))
        z = opaque_zero(x)
        assert z.dtype == wide and int(z) == 0
        assert opaque_zero(x, jnp.int32).dtype == jnp.int32
        assert int(opaque_zero(x.at[3].set(jnp.nan))) == 1


@pytest.mark.parametrize("precision", ["float32", "float64"])
def test_opaque_mul_is_the_rounded_product(precision):
    with precision_mode(precision) as dt:
        a, b, _ = _operands(dt)
        for zero in (opaque_zero(jnp.asarray(a)), opaque_zero(jnp.asarray(a), jnp.int32)):
            got = np.asarray(jax.jit(opaque_mul)(jnp.asarray(a), jnp.asarray(b), zero))
            assert got.dtype == dt
            np.testing.assert_array_equal(got, a * b)         # NumPy: one rounding
        v = jnp.asarray(a)
        np.testing.assert_array_equal(np.asarray(opaque(v, opaque_zero(v))), a)


def test_opaque_product_is_not_fused_into_the_add():
    """mul(a, b) + c equals two roundings (NumPy), on inputs where a fused multiply-add
    (one rounding) gives other bits for most elements."""
    a, b, c = _operands(np.float32)
    fma = ((a.astype(np.float64) * b) + c).astype(np.float32)   # exact product, one rounding
    two = a * b + c
    assert np.mean(fma != two) > 0.5                           # the test can tell them apart

    @jax.jit
    def muladd(a, b, c):
        return opaque_mul(a, b, opaque_zero(c)) + c

    got = np.asarray(muladd(jnp.asarray(a), jnp.asarray(b), jnp.asarray(c)))
    np.testing.assert_array_equal(got, two)


def test_ordered_sum_adds_left_to_right():
    f = np.float32
    terms = [f(1e8), f(1.0), f(-1e8), f(0.25)]
    want = functools.reduce(lambda s, t: f(s + t), terms)
    assert want != sum(sorted(terms))                           # order matters here
    got = jax.jit(lambda *t: ordered_sum(t))(*(jnp.asarray(t) for t in terms))
    assert np.asarray(got) == want
    assert ordered_sum([5]) == 5


@pytest.mark.parametrize("precision", ["float32", "float64"])
def test_ordered_dot_and_cross3_match_numpy_op_by_op(precision):
    with precision_mode(precision) as dt:
        rng = np.random.default_rng(3)
        a, b = (list(rng.normal(size=(3, 500)).astype(dt)) for _ in range(2))
        want_dot = (a[0] * b[0] + a[1] * b[1]) + a[2] * b[2]
        want_cross = np.stack([a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2],
                               a[0] * b[1] - a[1] * b[0]], 1)

        @jax.jit
        def run(a, b):
            mul = opaque_multiplier(opaque_zero(a[0]))
            return ordered_dot(a, b, mul), jnp.stack(cross3(a, b, mul), 1)

        d, c = run([jnp.asarray(x) for x in a], [jnp.asarray(x) for x in b])
        np.testing.assert_array_equal(np.asarray(d), want_dot)
        np.testing.assert_array_equal(np.asarray(c), want_cross)
        np.testing.assert_array_equal(ordered_dot(a, b, np.multiply), want_dot)


@pytest.mark.parametrize("dtype", ["float32", "float64", "int32", "uint32", "uint8", "bool"])
def test_materialize_returns_its_arrays_bit_for_bit(dtype):
    from shadowlab.core.numerics import materialize

    with precision_mode("float64" if dtype == "float64" else "float32"):
        if dtype == "bool":
            x = np.array([True, False, True, False])
        elif dtype.startswith("float"):
            x = np.array([np.nan, -0.0, 0.0, -np.inf, np.inf, 1.5, -3.0,
                          np.finfo(dtype).tiny], dtype)
        else:
            info = np.iinfo(dtype)
            x = np.array([info.min, info.max, 0, 7], dtype)
        y = np.asarray(jax.jit(materialize)(x))
        assert y.dtype == x.dtype
        np.testing.assert_array_equal(y.view(np.uint8), x.view(np.uint8))
        rev = x[::-1].copy()
        a, b = jax.jit(lambda u, v: materialize(u, v))(x, rev)
        np.testing.assert_array_equal(np.asarray(b).view(np.uint8), rev.view(np.uint8))


def test_materialize_computes_an_expression_once_for_several_consumers():
    """The reason it exists: without it XLA/CPU recomputes the expression in the fusion
    of each consumer (here three). If an XLA update removes the padded reduction, this
    fails and the callers (traversal, PSV build and query) lose speed, not exactness."""
    import re

    from shadowlab.core.numerics import materialize

    def make(mat):
        def f(x, idx):
            v = x
            for k in range(6):
                v = jnp.sin(v) * x + jnp.cos(v * k)
            v = mat(v)
            return jnp.zeros(64).at[idx].add(v), jnp.where(v > 0, idx, 0), v * 2 + 1
        return jax.jit(f)

    x = jnp.linspace(0, 1, 4096)
    idx = jnp.arange(4096, dtype=jnp.int32) % 64
    sines = {name: len(re.findall(r" sine\(", make(m).lower(x, idx).compile().as_text()))
             for name, m in (("plain", lambda v: v), ("materialized", materialize))}
    assert sines["materialized"] == 6 and sines["plain"] > 6, sines


@pytest.mark.parametrize("dtype", [np.float32, np.float64])
def test_norms3_equal_numpy_norm_bit_for_bit(dtype):
    """norms3 gives np.linalg.norm(x, axis=-1) bit for bit over 40 decades of scale, with
    zeros, infinities and NaN, on [N, 3] and [H, W, 3], with keepdims."""
    rng = np.random.default_rng(4)
    x = rng.normal(size=(200_000, 3)) * 10.0 ** rng.uniform(-20, 20, (200_000, 1))
    x[:3] = [[0.0, 0.0, 0.0], [np.inf, 1.0, 0.0], [np.nan, 0.0, 1.0]]
    x = x.astype(dtype)
    with np.errstate(over="ignore", invalid="ignore"):
        want, got = np.linalg.norm(x, axis=-1), norms3(x)
        assert got.dtype == want.dtype
        np.testing.assert_array_equal(got.view(np.uint8), want.view(np.uint8))
        grid = x[:40_000].reshape(200, 200, 3)
        np.testing.assert_array_equal(norms3(grid, keepdims=True),
                                      np.linalg.norm(grid, axis=-1, keepdims=True))
    np.testing.assert_array_equal(norms3(np.array([[3, 4, 12]])), [13.0])    # ints: float64
    with pytest.raises(ValueError, match="length 3"):
        norms3(np.zeros((4, 2)))


@pytest.mark.parametrize("dtype", [np.float32, np.float64, np.int32])
def test_column_bounds_equal_numpy_min_max(dtype):
    """column_bounds gives x.min(axis=0), x.max(axis=0) exactly, NaN and inf included."""
    rng = np.random.default_rng(5)
    for k in (1, 2, 3, 5):
        x = (rng.normal(size=(1000, k)) * 10.0 ** rng.uniform(-30, 30, (1000, k))).astype(
            dtype) if dtype != np.int32 else rng.integers(-2 ** 31, 2 ** 31 - 1, (1000, k),
                                                          dtype=np.int64).astype(np.int32)
        if dtype != np.int32:
            x[rng.integers(0, 1000, 3), 0] = np.inf
            x[rng.integers(0, 1000, 3), k - 1] = -np.inf
            if k > 1:
                x[7, 1] = np.nan
        lo, hi = column_bounds(x)
        assert lo.dtype == x.dtype and hi.dtype == x.dtype
        np.testing.assert_array_equal(lo, x.min(axis=0))
        np.testing.assert_array_equal(hi, x.max(axis=0))
        np.testing.assert_array_equal(column_bounds(x[::3])[0], x[::3].min(axis=0))
    with pytest.raises(ValueError):
        column_bounds(np.zeros((0, 3), dtype))
    with pytest.raises(ValueError):
        column_bounds(np.zeros(3, dtype))


@pytest.mark.parametrize("dtype", [np.float32, np.float64])
def test_max_abs_equals_numpy_abs_max(dtype):
    """max_abs gives np.abs(x).max(initial=0.0) exactly: signs, infinities, NaN, empty."""
    rng = np.random.default_rng(11)
    for shape in ((1000, 3), (17, 3, 3), (5,)):
        x = (rng.normal(size=shape) * 10.0 ** rng.uniform(-20, 20, shape)).astype(dtype)
        ref = float(np.abs(x).max(initial=0.0))
        assert max_abs(x) == ref and max_abs(-x) == ref
        assert max_abs(np.abs(x)) == ref
    x = np.array([1.0, -np.inf, 2.0], dtype)
    assert max_abs(x) == np.inf
    assert np.isnan(max_abs(np.array([np.nan, 1.0], dtype)))
    assert np.isnan(max_abs(np.array([1.0, np.nan], dtype)))
    assert max_abs(np.zeros((0, 3), dtype)) == 0.0
    assert max_abs(np.array([-0.0], dtype)) == 0.0
    # integers take np.abs (negating the minimum would wrap)
    assert max_abs(np.array([-2 ** 31, 5], np.int32)) == 2.0 ** 31
    assert max_abs(np.array([3, 250], np.uint8)) == 250.0


@pytest.mark.parametrize("dtype", [np.float32, np.float64])
def test_packed_intervals_hold_the_exact_ones(dtype):
    """pack_interval rounds each end away from zero to half the width (bfloat16 / float32)
    and never below the smallest normal; the JAX and NumPy unpacking read the same values;
    an empty interval packs exactly; an interval not around 0 is refused."""
    rng = np.random.default_rng(11)
    n = 100_000
    with np.errstate(over="ignore"):        # float32: the largest magnitudes become inf
        hi = (np.abs(rng.normal(size=n)) * 10.0 ** rng.uniform(-46, 40, n)).astype(dtype)
        lo = (-np.abs(rng.normal(size=n)) * 10.0 ** rng.uniform(-46, 40, n)).astype(dtype)
    hi[:5] = [-np.inf, 0.0, np.finfo(dtype).max, np.inf, 1.0]
    lo[:5] = [np.inf, -0.0, -np.finfo(dtype).max, 0.0, -1.0]
    words = pack_interval(lo, hi, dtype)
    assert words.dtype == dtype
    got_lo, got_hi = unpack_interval_np(words)
    assert got_lo.dtype == dtype and got_hi.dtype == dtype
    assert np.all(got_lo <= lo) and np.all(got_hi >= hi)            # outward
    half = np.float32 if dtype == np.float64 else None
    tiny = np.finfo(np.float32).tiny
    for end in (got_lo, got_hi):
        assert not np.any((end != 0) & (np.abs(end) < tiny))         # no subnormal ends
        if half is not None:                                          # float32 values
            np.testing.assert_array_equal(end.astype(np.float32).astype(dtype), end)
        else:                                                         # bfloat16 values
            assert not np.any(end.view(np.uint32) & np.uint32(0xFFFF))
    step = 2.0 ** -7 if dtype == np.float32 else 2.0 ** -23     # half type's spacing
    for end, got in ((hi, got_hi), (lo, got_lo)):               # tight: one step at most
        normal = np.isfinite(end) & (np.abs(end) > 1e-30) & (np.abs(end) < 1e30)
        assert (got[normal] / end[normal]).max() <= 1 + step
    np.testing.assert_array_equal(got_hi[:5], [-np.inf, 0.0, np.inf, np.inf, 1.0])
    np.testing.assert_array_equal(got_lo[:5], [np.inf, 0.0, -np.inf, 0.0, -1.0])
    with jax.enable_x64(dtype == np.float64):
        j_lo, j_hi = unpack_interval(jnp.asarray(words))
        j_lo, j_hi = np.asarray(j_lo * 1), np.asarray(j_hi * 1)     # through device math
    np.testing.assert_array_equal(j_lo, got_lo)
    np.testing.assert_array_equal(j_hi, got_hi)
    for bad in ((1.0, 2.0), (-1.0, -0.5), (np.nan, 1.0)):
        with pytest.raises(ValueError, match="lo <= 0 <= hi"):
            pack_interval(np.array([bad[0]]), np.array([bad[1]]), dtype)
