"""The per-fragment bitmask rasterizer kernel (Warp, CPU) equals the rasterizer composed
from the JAX primitives of methods/sun_disk.py bit for bit, on random inputs and on
exact ties (cell centres on edges)."""

import zlib

import numpy as np
import pytest

pytest.importorskip("warp")

from shadowlab.kernels import sun_disk as ks  # noqa: E402
from shadowlab.structures import sun_disk as sd  # noqa: E402


def _inputs(seed, f=400, t=6, snap=None):
    """Random fragments; ``snap`` (a Grid): vertices projecting onto the grid's cell
    centres and cell boundaries, half the fragments with dyadic s and z so that the
    paper projection and the edge functions are exact (cell centres exactly on edges)."""
    rng = np.random.default_rng(seed)
    s = rng.uniform(0.05, 0.3, f).astype(np.float32)
    z = rng.uniform(-0.3, 3.0, (f, t, 3))
    if snap is not None:
        z = np.where(z > 0.05, z, 1.0)
        dyadic = rng.uniform(size=f) < 0.5
        s = np.where(dyadic, 2.0 ** -rng.integers(2, 5, f), s).astype(np.float32)
        z = np.where(dyadic[:, None, None], 2.0 ** rng.integers(-1, 2, (f, t, 3)), z)
        kx = rng.integers(-2, 2 * snap.cols + 3, (f, t, 3))
        ky = rng.integers(-2, 2 * snap.rows + 3, (f, t, 3))
        cells = np.stack([-1 + kx / snap.cols, -1 + ky / snap.rows], -1)
        xy = cells * (s[:, None, None, None] * z[..., None])
    else:
        xy = rng.uniform(-1.6, 1.6, (f, t, 3, 2)) * (
            s[:, None, None, None] * np.abs(z[..., None]) + 0.02)
    d = np.concatenate([xy, z[..., None]], -1).astype(np.float32)
    n = rng.normal(size=(f, 3))
    n[:, 2] = np.abs(n[:, 2]) + 0.3
    n = (n / np.linalg.norm(n, axis=1, keepdims=True)).astype(np.float32)
    active = rng.uniform(size=(f, t)) < 0.9
    zl = rng.uniform(2.0, 4.0, f).astype(np.float32)
    return d, s, n, active, zl


CASES = [("paper", False, False), ("paper", False, True),
         ("homogeneous", False, True), ("homogeneous", True, False)]


def _seed(*key):
    return zlib.crc32(repr(key).encode()) % 1000


@pytest.mark.parametrize("grid", sd.GRID_NAMES)
@pytest.mark.parametrize("projection,sphere,horizon", CASES)
def test_kernel_equals_jax_bit_for_bit(grid, projection, sphere, horizon):
    d, s, n, active, zl = _inputs(_seed(grid, projection, sphere, horizon))
    kw = dict(grid=grid, projection=projection, eps=1e-3, z_light=zl if sphere else None,
              active=active, horizon=horizon)
    k = ks.visibility(d, s, n, **kw)
    j = ks.jax_visibility(d, s, n, **kw)
    assert np.array_equal(k["words"], j["words"])
    assert np.array_equal(k["visibility"], j["visibility"])
    assert np.array_equal(k["rasterized"], j["rasterized"])
    # not a trivial agreement: some fragments partly covered, some words cleared
    assert 0.05 < k["visibility"].mean() < 0.95


def _exact_ties(d, s, active, g):
    """Active (fragment, triangle, cell) triples whose cell centre lies exactly on an
    edge of the paper projection (float64 arithmetic, exact for the dyadic fragments)."""
    q = d[..., :2].astype(np.float64) / np.maximum(
        1e-4, s[:, None, None, None].astype(np.float64) * np.abs(d[..., 2:3]))
    x, y = g.centres()
    ties = np.zeros(d.shape[:2] + (g.rows, g.cols), bool)
    for i in range(3):
        p, r = q[..., i, :], q[..., (i + 1) % 3, :]
        f = ((r[..., 0] - p[..., 0])[..., None, None] * (y[:, None] - p[..., 1, None, None])
             - (r[..., 1] - p[..., 1])[..., None, None] * (x[None, :] - p[..., 0, None, None]))
        ties |= f == 0
    return int((ties & active[..., None, None]).sum())


@pytest.mark.parametrize("grid", sd.GRID_NAMES)
@pytest.mark.parametrize("projection,sphere,horizon", CASES)
def test_exact_ties_equal(grid, projection, sphere, horizon):
    """Vertices snapped to cell centres and boundaries put cell centres exactly on edges,
    where the bit is decided by the last bit of the edge function: still bit-identical."""
    g = sd.grid(grid)
    d, s, n, active, zl = _inputs(_seed(projection, sphere, horizon, grid), snap=g)
    kw = dict(grid=grid, projection=projection, eps=1e-3,
              z_light=zl if sphere else None, active=active, horizon=horizon)
    k = ks.visibility(d, s, n, **kw)
    j = ks.jax_visibility(d, s, n, **kw)
    assert np.array_equal(k["words"], j["words"])
    assert np.array_equal(k["visibility"], j["visibility"])
    assert np.array_equal(k["rasterized"], j["rasterized"])
    if grid == "16x16":                 # the inputs do hold exact ties
        assert _exact_ties(d, s, active, g) > 1000


def test_unoccluded_fragment_sees_the_whole_disk():
    g = sd.grid("16x16")
    d, s, n, _, _ = _inputs(3, f=8, t=2)
    k = ks.visibility(d, s, n, grid="16x16", active=np.zeros((8, 2), bool))
    assert np.array_equal(k["words"], np.tile(g.disk_mask(), (8, 1)))
    assert np.all(k["visibility"] == 1.0) and np.all(k["rasterized"] == 0)
    assert g.disk_bits == 208
