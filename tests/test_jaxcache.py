"""Compilation caches: atomic persistent entries, a cache of the test session's own,
and a bounded in-memory cache of executables."""

import os
from pathlib import Path

import jax
import jax.numpy as jnp
import pytest

from shadowlab.core import jaxcache
from shadowlab.core import timing


def _cache(tmp_path):
    from jax._src.lru_cache import LRUCache

    assert jaxcache._make_writes_atomic()       # idempotent: conftest has already patched
    return LRUCache(str(tmp_path), max_size=-1)


def test_entry_round_trips(tmp_path):
    cache = _cache(tmp_path)
    cache.put("k", b"x" * 1000)
    assert cache.get("k") == b"x" * 1000
    assert [p.name for p in tmp_path.iterdir() if p.name.startswith(".tmp-")] == []


def test_an_interrupted_write_leaves_no_entry(tmp_path, monkeypatch):
    cache = _cache(tmp_path)

    def fail(src, dst):
        raise KeyboardInterrupt            # killed between writing and renaming

    monkeypatch.setattr(os, "replace", fail)
    with pytest.raises(KeyboardInterrupt):
        cache.put("k", b"y" * 1000)
    monkeypatch.undo()
    assert cache.get("k") is None          # absent, not truncated
    assert list(tmp_path.iterdir()) == []  # and no temporary file left behind


def test_the_session_never_touches_the_users_cache(tmp_path):
    """conftest points the persistent cache at the session's own folder; a later enable
    call, as ``shadowlab.cli.main`` makes, does not move it to the user's cache."""
    session = Path(os.environ["SHADOWLAB_JAX_CACHE"])
    assert Path(jax.config.jax_compilation_cache_dir) == session
    jaxcache.enable_compilation_cache(tmp_path / "jax")
    assert Path(jax.config.jax_compilation_cache_dir) == session
    jax.jit(lambda x: x * 3.25 + 17.0)(jnp.arange(13.0)).block_until_ready()
    assert not (tmp_path / "jax").exists()
    user = Path.home() / ".cache" / "shadowlab" / "jax"
    assert session != user


def test_compiled_keeps_only_the_most_recent_executables(monkeypatch):
    monkeypatch.setattr(timing, "_COMPILED", type(timing._COMPILED)())
    monkeypatch.setattr(timing, "MAX_COMPILED", 2)
    f = jax.jit(lambda x: x + 1)
    args = [jnp.zeros(n) for n in (3, 4, 5)]
    for a in args:
        assert timing.compiled(f, a)[1] > 0          # compiled, not found
    assert len(timing._COMPILED) == 2
    assert timing.compiled(f, args[2])[1] == 0.0     # most recent: kept
    assert timing.compiled(f, args[0])[1] > 0        # oldest: dropped, compiled again
