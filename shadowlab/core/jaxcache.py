"""JAX's persistent compilation cache, so tests and repeated runs skip recompiling.

JAX 0.10 writes a cache entry with ``Path.write_bytes`` in place. A process killed
mid-write (a timeout, Ctrl-C) leaves a truncated entry that aborts every later process
reading that key (XLA aborts while deserializing; Python cannot catch it), and a reader
racing a writer can see a partial file. ``enable_compilation_cache`` therefore replaces
the cache's ``put`` with one that writes to a temporary file in the same folder and
renames it into place (atomic on POSIX), so an entry is either complete or absent.
"""

from __future__ import annotations

import os
import tempfile
from pathlib import Path

import jax

_ENABLED = False


def _atomic_put(self, key: str, value: bytes) -> None:
    """``LRUCache.put`` for caches without eviction (ours: no size limit), written
    atomically: temporary file, flush, then ``os.replace``."""
    if not key:
        raise ValueError("key cannot be empty")
    target = Path(self.path) / f"{key}{_SUFFIX}"
    if target.exists():
        return
    fd, tmp = tempfile.mkstemp(dir=target.parent, prefix=".tmp-", suffix=_SUFFIX)
    try:
        with os.fdopen(fd, "wb") as f:
            f.write(value)
        os.replace(tmp, target)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


def _make_writes_atomic() -> bool:
    """Patch JAX's file cache to write atomically; False if this JAX has no such class
    (then its own writes are used unchanged)."""
    global _SUFFIX
    try:
        from jax._src import lru_cache
    except ImportError:
        return False
    cls = getattr(lru_cache, "LRUCache", None)
    suffix = getattr(lru_cache, "_CACHE_SUFFIX", None)
    if cls is None or suffix is None or not hasattr(cls, "put"):
        return False
    _SUFFIX = suffix
    if getattr(cls.put, "_shadowlab_atomic", False):
        return True
    original = cls.put

    def put(self, key, value):
        if getattr(self, "eviction_enabled", False):
            return original(self, key, value)      # keeps JAX's lock and eviction
        return _atomic_put(self, key, value)

    put._shadowlab_atomic = True
    cls.put = put
    return True


_SUFFIX = "-cache"
def disable_compilation_cache() -> None:
    """Turn JAX's persistent cache off for this process (a sweep's ``jax_cache=False``);
    compiled programs are then kept in memory only."""
    global _ENABLED
    jax.config.update("jax_enable_compilation_cache", False)
    _ENABLED = False


def enable_compilation_cache(path: str | os.PathLike | None = None) -> Path:
    """Point JAX's persistent cache at ``path`` (default ``$SHADOWLAB_JAX_CACHE`` or
    ``~/.cache/shadowlab/jax``) and cache every compiled program, however fast."""
    global _ENABLED
    target = Path(path or os.environ.get("SHADOWLAB_JAX_CACHE")
                  or Path.home() / ".cache" / "shadowlab" / "jax")
    if not _ENABLED:
        target.mkdir(parents=True, exist_ok=True)
        _make_writes_atomic()
        jax.config.update("jax_enable_compilation_cache", True)
        jax.config.update("jax_compilation_cache_dir", str(target))
        jax.config.update("jax_persistent_cache_min_compile_time_secs", 0.0)
        jax.config.update("jax_persistent_cache_min_entry_size_bytes", 0)
        _ENABLED = True
    return target
