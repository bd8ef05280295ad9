"""Morton keys: layouts, encode/decode round trips (NumPy and JAX), the paper's layout."""

import jax
import jax.numpy as jnp
import numpy as np
from hypothesis import given, settings, strategies as st

from shadowlab.geometry.morton import decode, encode, grouped_layout, round_robin_layout


def test_paper_layout_1024():
    lay = round_robin_layout((7, 7, 9))
    assert len(lay) == 23
    assert lay[:21] == (0, 1, 2) * 7 and lay[21:] == (2, 2)
    # 5-bit levels from the bottom: four full levels and a 3-bit root word
    assert len(lay) - 4 * 5 == 3


def test_grouped_layout_ptsv_1024():
    lay = grouped_layout((7, 8), ((2, 3), (3, 2)))
    assert lay == (0, 0, 1, 1, 1, 0, 0, 0, 1, 1, 0, 0, 1, 1, 1)


def test_encode_matches_bit_loop():
    lay = round_robin_layout((3, 2, 4))
    for x in range(8):
        for y in range(4):
            for z in range(16):
                key = int(encode((np.uint32(x), np.uint32(y), np.uint32(z)), lay))
                used, expect = [0, 0, 0], 0
                for bit, a in enumerate(lay):
                    expect |= (((x, y, z)[a] >> used[a]) & 1) << bit
                    used[a] += 1
                assert key == expect


@settings(max_examples=60, deadline=None)
@given(bits=st.tuples(st.integers(0, 11), st.integers(0, 11), st.integers(0, 10)),
       seed=st.integers(0, 2**31 - 1))
def test_round_trip(bits, seed):
    lay = round_robin_layout(bits)
    rng = np.random.default_rng(seed)
    coords = [rng.integers(0, 1 << b, 50, dtype=np.uint64).astype(np.uint32) for b in bits]
    key = encode(coords, lay)
    assert key.dtype == np.uint32
    back = decode(key, lay, 3)
    for c, b in zip(coords, back):
        np.testing.assert_array_equal(c, b)
    # keys are a bijection: distinct coordinates give distinct keys
    assert len(np.unique(key)) == len({tuple(int(c[i]) for c in coords) for i in range(50)})


def test_32_bit_keys_in_jax_match_numpy():
    lay = round_robin_layout((10, 10, 12))
    assert len(lay) == 32
    rng = np.random.default_rng(1)
    coords = [rng.integers(0, 1 << b, 200).astype(np.uint32) for b in (10, 10, 12)]
    kn = encode(coords, lay)
    kj = jax.jit(lambda a, b, c: encode((a, b, c), lay, xp=jnp))(*coords)
    np.testing.assert_array_equal(kn, np.asarray(kj))
    assert kn.max() > 2**31          # the top bit is used, as uint32
    back = jax.jit(lambda k: decode(k, lay, 3, xp=jnp))(kj)
    for c, b in zip(coords, back):
        np.testing.assert_array_equal(c, np.asarray(b))


def test_soft_tiled_cluster_keys_are_3d_interleaved_10_bit_codes():
    """soft_tiled orders triangles by 10-bit 3-D Morton codes of their centroids:
    coordinate bit b of axis a at key bit 3 b + a."""
    q = np.random.default_rng(5).integers(0, 1024, (500, 3))
    want = np.zeros(len(q), np.uint64)
    for b in range(10):
        for a in range(3):
            want |= ((q[:, a].astype(np.uint64) >> np.uint64(b)) & np.uint64(1)) \
                << np.uint64(3 * b + a)
    got = encode(q.T, round_robin_layout((10, 10, 10)))
    assert got.dtype == np.uint32
    np.testing.assert_array_equal(got.astype(np.uint64), want)
