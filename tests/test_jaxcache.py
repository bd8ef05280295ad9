"""The persistent compilation cache writes entries atomically."""

import os

import pytest

from shadowlab import jaxcache


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
