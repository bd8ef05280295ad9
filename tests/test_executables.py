"""core.executables: the mapped-region budget of compiled programs (docs/xla_map_count.md)."""

import jax
import jax.numpy as jnp
import pytest

from shadowlab.core import executables, timing

pytestmark = pytest.mark.skipif(executables.map_count() is None,
                                reason="no /proc/self/maps on this OS")


def _compile_distinct(n):
    fns = [jax.jit(lambda x, i=i: jnp.sin(x * i) + jnp.cumsum(x) - jnp.sort(x))
           for i in range(n)]
    for f in fns:
        f(jnp.ones(17)).block_until_ready()
    return fns


def test_executables_map_regions_and_release_returns_them():
    executables.release()
    before = executables.map_count()
    fns = _compile_distinct(12)
    grown = executables.map_count()
    assert grown - before >= 12 * 5          # several regions per live executable
    executables.release()
    after = executables.map_count()
    assert after - before < (grown - before) / 2
    assert float(fns[0](jnp.ones(17)).sum()) == pytest.approx(
        float((jnp.sin(jnp.zeros(17)) + jnp.cumsum(jnp.ones(17)) - 1.0).sum()))


def test_release_clears_timings_compiled_executables():
    f = jax.jit(lambda x: x * 2)
    timing.compiled(f, jnp.ones(3))
    assert timing.compiled(f, jnp.ones(3))[1] == 0.0    # cached
    executables.release()
    exe, seconds = timing.compiled(f, jnp.ones(3))
    assert seconds > 0.0                                 # compiled again
    assert float(exe(jnp.ones(3)).sum()) == 6.0


def test_guard_releases_only_above_its_fraction():
    assert executables.map_limit() > 0
    assert executables.guard(fraction=1.0) is False
    _compile_distinct(2)
    assert executables.guard(fraction=0.0) is True
