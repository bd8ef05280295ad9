"""Warp set-up shared by every kernel file: kernel cache, device, quiet initialisation.

Importing this module imports ``warp``; everything else in ``shadowlab`` works without
it (``shadowlab.kernels.available()`` says whether it is installed).

The kernel cache is ``$SHADOWLAB_WARP_CACHE`` or ``~/.cache/shadowlab/warp``. Warp
keys a compiled module by a hash of its source and options, so a second process (a
second test run) loads the compiled module in milliseconds instead of compiling it
again (a few seconds per kernel file on the CPU backend).
"""

from __future__ import annotations

import os
from pathlib import Path

import warp as wp

_READY = False


def cache_dir() -> Path:
    """Where compiled kernels are kept (``$SHADOWLAB_WARP_CACHE`` or the default)."""
    return Path(os.environ.get("SHADOWLAB_WARP_CACHE")
                or Path.home() / ".cache" / "shadowlab" / "warp")


def init(device: str | None = None) -> str:
    """Initialise Warp once (cache directory, quiet) and return the device name.

    The device is ``device``, else ``$SHADOWLAB_WARP_DEVICE``, else ``"cpu"``: the
    kernels are checked on the CPU backend; a CUDA device runs the same source.
    """
    global _READY
    if not _READY:
        target = cache_dir()
        target.mkdir(parents=True, exist_ok=True)
        from warp._src import context

        if context.runtime is None:        # the cache directory is read by wp.init()
            wp.config.kernel_cache_dir = str(target)
        wp.config.log_level = wp.LOG_WARNING
        # Cooperative CPU blocks (fibers) for the lane-per-thread forms (32-thread blocks).
        wp.config.enable_cpu_blocks = True
        wp.init()
        _READY = True
    return device or os.environ.get("SHADOWLAB_WARP_DEVICE") or "cpu"
