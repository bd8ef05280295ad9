"""JAX's persistent compilation cache, so tests and repeated runs skip recompiling."""

from __future__ import annotations

import os
from pathlib import Path

import jax

_ENABLED = False


def enable_compilation_cache(path: str | os.PathLike | None = None) -> Path:
    """Point JAX's persistent cache at ``path`` (default ``$SHADOWLAB_JAX_CACHE`` or
    ``~/.cache/shadowlab/jax``) and cache every compiled program, however fast."""
    global _ENABLED
    target = Path(path or os.environ.get("SHADOWLAB_JAX_CACHE")
                  or Path.home() / ".cache" / "shadowlab" / "jax")
    if not _ENABLED:
        target.mkdir(parents=True, exist_ok=True)
        jax.config.update("jax_compilation_cache_dir", str(target))
        jax.config.update("jax_persistent_cache_min_compile_time_secs", 0.0)
        jax.config.update("jax_persistent_cache_min_entry_size_bytes", 0)
        _ENABLED = True
    return target
