"""Morton (bit-interleaved) keys with explicit bit layouts, for NumPy and traced JAX.

A *layout* is a tuple of axis numbers, one per key bit, least significant bit first:
``layout[i] = a`` means key bit ``i`` holds the next unused bit of coordinate ``a``.
Keys are uint32, so a layout has at most 32 bits. Every function here takes an array
module ``xp`` (``numpy`` or ``jax.numpy``) and uses only uint32 arithmetic with
logical shifts by small Python ints (never literals above 2**31), so it traces.

Layouts used by shadowlab:

- :func:`round_robin_layout`: interleave x, y, z, x, y, z, ... from the least
  significant bit, dropping an axis once its bits are used up. With (7, 7, 9) bits
  (a 1024 x 1024 image in 8 x 8 tiles, 512 depth slices) this is 21 interleaved bits
  topped by the two remaining z bits: the 23-bit cluster key of Sintorn et al. 2014,
  split into 5-bit levels from the bottom (a 3-bit root word, then four 5-bit levels).
  That is our reading of the paper's Fig. 2 ("a slightly rearranged Morton order"),
  which is not reproduced in the text; see docs/clustered_ptsv.md.
- :func:`grouped_layout`: fill 5-bit groups with a per-group quota of bits per axis
  (PTSV's 2D tree alternates 8 x 4 and 4 x 8 children).
"""

from __future__ import annotations

import numpy as np

MAX_BITS = 32


def round_robin_layout(bits: tuple[int, ...]) -> tuple[int, ...]:
    """Axes interleaved from the LSB, each dropped when its ``bits[a]`` are used."""
    left = list(bits)
    if sum(left) > MAX_BITS:
        raise ValueError(f"a key with {sum(left)} bits does not fit in uint32")
    out = []
    while any(left):
        for a in range(len(left)):
            if left[a]:
                out.append(a)
                left[a] -= 1
    return tuple(out)


def grouped_layout(bits: tuple[int, ...], quotas: tuple[tuple[int, ...], ...],
                   group: int = 5) -> tuple[int, ...]:
    """Groups of ``group`` bits from the LSB; group g takes ``quotas[g % len(quotas)][a]``
    bits of axis a (axis order within a group), topping up from any axis with bits
    left when an axis runs out. The last (most significant) group may be partial."""
    left = list(bits)
    if sum(left) > MAX_BITS:
        raise ValueError(f"a key with {sum(left)} bits does not fit in uint32")
    out: list[int] = []
    g = 0
    while any(left):
        quota = quotas[g % len(quotas)]
        take = [min(q, l) for q, l in zip(quota, left)]
        room = group - sum(take)
        for a in range(len(left)):               # top up from axes with bits to spare
            extra = min(room, left[a] - take[a])
            take[a] += extra
            room -= extra
        for a in range(len(left)):
            out += [a] * take[a]
            left[a] -= take[a]
        g += 1
    return tuple(out)


def axis_bits(layout: tuple[int, ...], axis: int, below: int | None = None) -> int:
    """How many of ``axis``'s bits sit in key bits ``[0, below)`` (all bits if None)."""
    part = layout if below is None else layout[:below]
    return sum(1 for a in part if a == axis)


def encode(coords, layout: tuple[int, ...], xp=np):
    """uint32 keys [...] from integer coordinates (a sequence of arrays [...], one per axis)."""
    one = xp.uint32(1)
    cs = [xp.asarray(c).astype(xp.uint32) for c in coords]
    key = xp.zeros(xp.broadcast_shapes(*[c.shape for c in cs]), dtype=xp.uint32)
    used = [0] * len(cs)
    for i, a in enumerate(layout):
        bit = (cs[a] >> used[a]) & one
        key = key | (bit << i)
        used[a] += 1
    return key


def decode(key, layout: tuple[int, ...], naxes: int, xp=np):
    """Tuple of uint32 coordinate arrays [...] from uint32 keys [...] (inverse of encode)."""
    one = xp.uint32(1)
    key = xp.asarray(key).astype(xp.uint32)
    cs = [xp.zeros(key.shape, dtype=xp.uint32) for _ in range(naxes)]
    used = [0] * naxes
    for i, a in enumerate(layout):
        cs[a] = cs[a] | (((key >> i) & one) << used[a])
        used[a] += 1
    return tuple(cs)
