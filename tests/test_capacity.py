"""Static capacities (``core.capacity``): bucket sizes, padding, overflow retry."""

import functools

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from shadowlab.core.capacity import (INT32_MAX, CapacityError, bucket, check_int32, pad,
                                     retry_on_overflow, wide_add, wide_min, wide_total)


def _sizes(steps, limit):
    """All bucket sizes up to ``limit``, ascending: powers of two up to ``steps``, then
    ``steps`` evenly spaced sizes in each octave (2**(j-1), 2**j]."""
    out, top = [], 1
    while top <= limit:
        if top <= steps:
            out.append(top)
        else:
            out += [top // 2 + i * top // (2 * steps) for i in range(1, steps + 1)]
        top *= 2
    return out


@pytest.mark.parametrize("steps", [1, 2, 4, 8])
@pytest.mark.parametrize("minimum", [1, 16, 192, 1024])
def test_bucket_is_the_smallest_allowed_size(steps, minimum):
    sizes = np.array(_sizes(steps, 1 << 16))
    for n in range(0, 5000, 7):
        want = sizes[np.searchsorted(sizes, max(n, minimum, 1))]
        got = bucket(n, minimum=minimum, steps=steps)
        assert got == want, (n, got, want)
        if n > max(minimum, 2 * steps):
            assert (got - n) / got < 1 / (steps + 1)


def test_bucket_keeps_the_former_top_tree_lane_capacity():
    def former(n):     # top_tree's lane rule before it used bucket
        top = 1 << (max(n, 256) - 1).bit_length()
        return top * 3 // 4 if n <= top * 3 // 4 else top
    assert all(bucket(n, minimum=192, steps=2) == former(n) for n in range(0, 20000))


def test_pad():
    a = np.arange(6, dtype=np.int32).reshape(3, 2)
    out = pad(a, 5, fill=-1)
    assert out.dtype == np.int32 and out.shape == (5, 2)
    assert out.tolist() == [[0, 1], [2, 3], [4, 5], [-1, -1], [-1, -1]]
    f = pad(np.array([1.5, 2.5]), 4, dtype=np.float32)
    assert f.dtype == np.float32 and f.tolist() == [1.5, 2.5, 0, 0]
    assert pad(a, 3).tolist() == a.tolist()


@functools.partial(jax.jit, static_argnames="capacity")
def _select(x, threshold, *, capacity):
    """Indices of x > threshold into a list of static ``capacity`` (extra ones dropped)
    and the exact count."""
    keep = x > threshold
    idx = jnp.nonzero(keep, size=capacity, fill_value=-1)[0]
    return idx, jnp.sum(keep)


def test_retry_grows_an_overflowing_capacity_and_equals_a_big_run():
    x = jnp.asarray(np.random.default_rng(0).uniform(size=3000))
    calls = []

    def step(cap):
        calls.append(cap)
        idx, count = _select(x, 0.3, capacity=cap)
        return idx, int(count)

    idx, cap = retry_on_overflow(step, 64)
    count = int(np.sum(np.asarray(x) > 0.3))
    assert calls == [64, bucket(count, minimum=1)] and cap == calls[-1]
    big, _ = _select(x, 0.3, capacity=4096)
    np.testing.assert_array_equal(np.asarray(idx)[:count], np.asarray(big)[:count])
    np.testing.assert_array_equal(np.asarray(idx)[:count], np.flatnonzero(np.asarray(x) > 0.3))
    calls.clear()
    retry_on_overflow(step, 4096)                 # enough from the start: one run
    assert calls == [4096]


def test_retry_with_several_capacities_grows_only_those_that_overflow():
    x = jnp.asarray(np.random.default_rng(1).uniform(size=2000))
    calls = []

    def step(caps):
        calls.append(caps)
        lo, n_lo = _select(-x, -0.1, capacity=caps[0])       # x < 0.1: about 200
        hi, n_hi = _select(x, 0.5, capacity=caps[1])         # x > 0.5: about 1000
        return (lo, hi), (int(n_lo), int(n_hi))

    grow_lo = lambda need, cap: max(bucket(need, minimum=1), 4 * cap)   # noqa: E731
    (lo, hi), caps = retry_on_overflow(step, (512, 16), grow=(grow_lo, lambda n, c: 2 * c))
    assert calls[0] == (512, 16) and all(c[0] == 512 for c in calls)
    assert [c[1] for c in calls] == [16 * 2 ** i for i in range(len(calls))]
    assert caps[1] >= np.sum(np.asarray(x) > 0.5) > caps[1] // 2
    np.testing.assert_array_equal(np.asarray(hi)[: np.sum(np.asarray(x) > 0.5)],
                                  np.flatnonzero(np.asarray(x) > 0.5))


def test_run_offsets_count_within_each_run():
    from shadowlab.core.capacity import run_offsets

    assert run_offsets([2, 0, 3, 1]).tolist() == [0, 1, 0, 1, 2, 0]
    assert run_offsets([]).tolist() == []


def test_run_offsets_in_a_narrow_type_equal_the_wide_ones():
    from shadowlab.core.capacity import run_offsets

    counts = np.random.default_rng(3).integers(0, 9, 500)
    narrow = run_offsets(counts, np.int32)
    assert narrow.dtype == np.int32
    np.testing.assert_array_equal(narrow, run_offsets(counts))


@pytest.mark.parametrize("low_bits", [2, 24])
def test_wide_counters_sum_past_int32_exactly(low_bits):
    """Increments whose int32 sum wraps several times: the two-word totals equal Python's
    integers, and ``wide_min`` equals min(total, limit) along the way."""
    rng = np.random.default_rng(1)
    inc = rng.integers(0, 2 ** 21, (3000, 3)).astype(np.int32)
    inc[:, 0] = 2 ** 21 - 1                       # column 0 alone reaches 6.3e9
    limit = 5_000_000

    @jax.jit
    def run(inc):
        def body(i, c):
            wide, mins = c
            wide = wide_add(wide, inc[i], low_bits)
            return wide, mins.at[i].set(wide_min(wide, limit, low_bits))
        return jax.lax.fori_loop(0, inc.shape[0], body,
                                 (jnp.zeros((2, 3), jnp.int32), jnp.zeros((3000, 3), jnp.int32)))

    wide, mins = run(jnp.asarray(inc))
    want = np.cumsum(inc.astype(np.int64), axis=0)
    assert want[-1, 0] > 2 * INT32_MAX
    np.testing.assert_array_equal(wide_total(wide, low_bits), want[-1])
    np.testing.assert_array_equal(np.asarray(mins), np.minimum(want, limit))


def test_check_int32_names_the_quantity_and_the_remedy():
    assert check_int32(INT32_MAX, "entries", "render less") == INT32_MAX
    with pytest.raises(CapacityError, match=r"entries: 2,147,483,648 exceeds .*render less"):
        check_int32(INT32_MAX + 1, "entries", "render less")
    with pytest.raises(CapacityError):
        wide_min(jnp.zeros((2, 1), jnp.int32), INT32_MAX - 100)   # its sum could wrap


def test_retry_refuses_a_count_that_wrapped():
    """A need below zero can only be an integer count that wrapped: refused, never taken
    for 'nothing overflowed'."""
    with pytest.raises(CapacityError, match="wrapped"):
        retry_on_overflow(lambda cap: ("result", -(2 ** 31) + 5), 1024)
    with pytest.raises(CapacityError, match="wrapped"):
        retry_on_overflow(lambda caps: ("result", (3, -1)), (8, 8))
