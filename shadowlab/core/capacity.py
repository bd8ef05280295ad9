"""Static capacities: bucketed sizes, padding, and overflow retry.

A jitted kernel needs static shapes, so variable-length work (samples, casters,
frontiers, lists) is padded to a *capacity* from a small set of sizes
(:func:`bucket`): the number of distinct compiled shapes stays logarithmic in the
problem size. When a kernel cannot know its output size in advance, it writes at most
``capacity`` entries and reports how many it needed; :func:`retry_on_overflow` reruns it
with a larger bucket until nothing was dropped (the neighbour-list pattern of jax-md:
allocate, detect overflow, reallocate). :func:`run_offsets` expands per-item counts
into the exact-size lists (CSR) that such work is built from.

Kernels index and count in int32 (JAX's default integer without x64): a size that an
int32 cannot hold is refused by :func:`check_int32` with :class:`CapacityError` before
any kernel runs, never wrapped; counters that sum over a whole frame use the two-word
:func:`wide_add` (:func:`wide_total` reads them back as exact int64 values).
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np


INT32_MAX = int(np.iinfo(np.int32).max)


class CapacityError(OverflowError):
    """A size the int32 indices of a kernel cannot address (see :func:`check_int32`)."""


def check_int32(n: int, what: str, remedy: str) -> int:
    """``n`` if ``0 <= n <= INT32_MAX``, else :class:`CapacityError` naming ``what`` (the
    quantity, e.g. "silhouette cell-list entries") and ``remedy`` (what the user can
    change to make it smaller)."""
    n = int(n)
    if n < 0:
        raise CapacityError(f"{what}: {n:,} is negative: a count wrapped past its integer "
                            f"type; {remedy}")
    if n > INT32_MAX:
        raise CapacityError(f"{what}: {n:,} exceeds the int32 indices of the kernels "
                            f"({INT32_MAX:,}); {remedy}")
    return n


#: low bits kept in the low word of a two-word counter (:func:`wide_add`)
WIDE_LOW_BITS = 24


def wide_add(wide, increment, low_bits: int | None = None):
    """Add non-negative int32 ``increment`` [K] (each below ``2**31 - 2**low_bits``) to the
    two-word counters ``wide`` int32 [2, K] (row 0 the low ``low_bits`` bits, row 1 the
    carries), so a sum over a whole frame never wraps (exact up to ``2**(31 +
    low_bits)``). Traceable (jax.numpy) code; ``low_bits`` defaults to
    :data:`WIDE_LOW_BITS` (tests use small values to exercise the carry)."""
    import jax.numpy as jnp
    b = WIDE_LOW_BITS if low_bits is None else low_bits
    low = wide[0] + increment
    return jnp.stack([low & ((1 << b) - 1), wide[1] + (low >> b)])


def wide_min(wide, limit: int, low_bits: int | None = None):
    """int32: ``min(total, limit)`` of two-word counters ``wide`` [2, ...] (see
    :func:`wide_add`), traceable, for a static ``limit`` with ``limit + 2**(low_bits + 1)
    <= INT32_MAX`` (so no intermediate value wraps)."""
    import jax.numpy as jnp
    b = WIDE_LOW_BITS if low_bits is None else low_bits
    check_int32(limit + (2 << b), "wide_min limit", "use a smaller limit")
    hi = jnp.minimum(wide[1], (limit >> b) + 1)
    return jnp.minimum((hi << b) + wide[0], limit)


def wide_total(wide, low_bits: int | None = None) -> np.ndarray:
    """int64 [K]: the totals of two-word counters [2, K] (see :func:`wide_add`)."""
    b = WIDE_LOW_BITS if low_bits is None else low_bits
    w = np.asarray(wide, np.int64)
    return (w[1] << b) + w[0]


def run_offsets(counts: np.ndarray, dtype=np.int64) -> np.ndarray:
    """[sum(counts)] of ``dtype`` (int64 by default; a narrower one, which the caller
    makes sure holds sum(counts), halves the temporaries): 0, 1, ..., counts[i] - 1 for
    each run i in turn, i.e. the place within its run of every element of
    ``np.repeat(x, counts)``."""
    counts = np.asarray(counts, np.int64)
    starts = (np.cumsum(counts) - counts).astype(dtype)
    return np.arange(counts.sum(), dtype=dtype) - np.repeat(starts, counts)


def bucket(n: int, minimum: int = 1024, steps: int = 1) -> int:
    """A static capacity >= max(n, minimum, 1) from a small set of sizes.

    ``steps=1`` gives powers of two; ``steps=k`` (a power of two) gives k sizes per
    octave, the multiples of ``2**j / (2 k)`` in ``(2**(j-1), 2**j]``, so less than
    ``1 / (k + 1)`` of a capacity above the minimum is padding (11 % for ``steps=8``).
    """
    n = max(int(n), int(minimum), 1)
    top = 1 << (n - 1).bit_length()
    if steps <= 1 or top <= steps:
        return top
    grain = top // (2 * steps)
    return -(-n // grain) * grain


def pad(a: np.ndarray, capacity: int, fill=0, dtype=None) -> np.ndarray:
    """``a`` [n, ...] padded to [capacity, ...] with ``fill`` (``capacity >= n``).

    Args:
        dtype: of the result (default ``a``'s); ``a`` is cast on assignment.
    """
    a = np.asarray(a)
    out = np.full((capacity,) + a.shape[1:], fill, dtype=a.dtype if dtype is None else dtype)
    out[: len(a)] = a
    return out


def grow_to_bucket(need: int, capacity: int) -> int:
    """The default growth of :func:`retry_on_overflow`: the power of two >= ``need``."""
    return bucket(need, minimum=1)


def retry_on_overflow(step: Callable, capacity, grow: Callable = grow_to_bucket):
    """Run ``step`` with static capacities, growing them until no capacity overflowed.

    Args:
        step: ``step(capacity) -> (result, need)``. It runs the work with the given
            static capacity (a jitted kernel compiled for it) and reports, per capacity,
            the number of entries the work needed (an exact count, or a lower bound if
            ``grow`` over-allocates to make up for it). ``need > capacity`` means the
            overflowing entries were dropped and ``result`` must not be used; a negative
            need (a count that wrapped) raises :class:`CapacityError`.
        capacity: an int, or a tuple of ints for several capacities.
        grow: ``grow(need, capacity) -> new capacity`` (> capacity) for an overflowing
            capacity; one function, or a tuple of them, one per capacity.

    Returns:
        (result, capacity): the result of the first run in which every ``need <=
        capacity``, and the capacities it ran with.
    """
    single = not isinstance(capacity, tuple)
    caps = (capacity,) if single else tuple(capacity)
    grows = grow if isinstance(grow, tuple) else (grow,) * len(caps)
    while True:
        result, need = step(caps[0] if single else caps)
        needs = (need,) if single else tuple(need)
        if any(int(n) < 0 for n in needs):
            raise CapacityError(f"a kernel reported needing {[int(n) for n in needs]} "
                                "entries: a negative count wrapped past its integer type")
        if all(int(n) <= c for n, c in zip(needs, caps)):
            return result, (caps[0] if single else caps)
        caps = tuple(g(int(n), c) if int(n) > c else c for g, n, c in zip(grows, needs, caps))
