"""Stable sorting of integer keys by 16-bit radix passes.

NumPy's stable sort is a radix sort for 16-bit (and narrower) integers and a merge sort
for wider ones; on a million int64 keys the merge sort takes 2-4 times as long as two
radix passes. :func:`stable_argsort` sorts non-negative integer keys least-significant
digit first, one stable uint16 argsort per 16 bits of the largest key.
"""

from __future__ import annotations

import numpy as np

#: below this many keys the plain stable argsort is as fast
RADIX_MIN = 1 << 12


def stable_argsort(keys: np.ndarray) -> np.ndarray:
    """int64 [N]: the permutation ``np.argsort(keys, kind="stable")`` of the keys [N].

    Non-negative integer keys wider than 16 bits (at least ``RADIX_MIN`` of them) are
    sorted by LSD radix passes over 16-bit digits; any other input goes to
    ``np.argsort``.
    """
    keys = np.asarray(keys)
    if keys.ndim != 1 or keys.dtype.kind not in "iu" or len(keys) < RADIX_MIN \
            or keys.dtype.itemsize <= 2:        # NumPy radix-sorts 16-bit keys itself
        return np.argsort(keys, kind="stable")
    if keys.dtype.kind == "i" and keys.min() < 0:
        return np.argsort(keys, kind="stable")
    top = int(keys.max())
    order = np.argsort((keys & 0xFFFF).astype(np.uint16), kind="stable")
    shift = 16
    while top >> shift:
        digit = ((keys >> shift) & 0xFFFF).astype(np.uint16)
        order = order[np.argsort(digit[order], kind="stable")]
        shift += 16
    return order
