"""core.sorting.stable_argsort against NumPy's stable argsort (a plain reference)."""

import numpy as np
import pytest

from shadowlab.core.sorting import RADIX_MIN, stable_argsort


CASES = [(dtype, top)
         for dtype in (np.int8, np.int16, np.int32, np.int64, np.uint8, np.uint16, np.uint32,
                       np.uint64)
         for top in (1, 300, (1 << 16) - 1, (1 << 16) + 7, 1 << 31, (1 << 47) + 5)
         if top <= np.iinfo(dtype).max]


@pytest.mark.parametrize("dtype,top", CASES)
def test_equals_numpy_stable_argsort(dtype, top):
    """Every digit count (one to three passes), many ties, narrow and wide dtypes: the
    same permutation as np.argsort(kind="stable")."""
    rng = np.random.default_rng(top % 97)
    keys = rng.integers(0, top + 1, 3 * RADIX_MIN, dtype=np.int64).astype(dtype)
    keys[::5] = keys[0]                                   # long runs of equal keys
    got = stable_argsort(keys)
    np.testing.assert_array_equal(got, np.argsort(keys, kind="stable"))
    assert got.dtype == np.intp


def test_other_inputs_fall_back_to_numpy():
    rng = np.random.default_rng(2)
    for keys in (rng.integers(-50, 50, 2 * RADIX_MIN),          # negative
                 rng.normal(size=2 * RADIX_MIN),                 # floats
                 rng.integers(0, 9, 17),                         # short
                 np.zeros(0, np.int64)):
        np.testing.assert_array_equal(stable_argsort(keys), np.argsort(keys, kind="stable"))
