"""The live compiled programs of a process, and the operating system's limit on them.

XLA:CPU keeps every compiled executable in memory that it maps from the operating
system region by region: about 28 regions (code, read-only data and data per compiled
kernel) for even a small program, measured with jax 0.10 on Linux. JAX keeps every
executable alive as long as the jitted function's cache holds it, which is forever.
Linux caps a process at ``vm.max_map_count`` regions (65530 by default); past it the
next ``mmap`` fails, and XLA does not report that failure: the process segfaults inside
the next compilation or executable serialization (docs/xla_map_count.md has the
reduction and the measurements). A process that compiles a few thousand distinct
programs (the whole test suite, ``shadowlab figures`` running every experiment, a
long-lived sweep worker) reaches the cap.

:func:`guard` is the workaround at the source: when the process uses more than a
fraction of its region budget it drops every cached executable (JAX's caches and
``core.timing``'s), which unmaps them; later calls recompile what they need. The
harness calls it before every method evaluation and the test session before every test.
"""

from __future__ import annotations

import gc
from pathlib import Path

import jax

#: Fraction of ``vm.max_map_count`` above which :func:`guard` releases executables.
DEFAULT_FRACTION = 0.5
_MAPS = Path("/proc/self/maps")
_LIMIT_FILE = Path("/proc/sys/vm/max_map_count")


def map_count() -> int | None:
    """Memory regions mapped by this process now, or None where the OS does not say
    (not Linux)."""
    try:
        return _MAPS.read_bytes().count(b"\n")
    except OSError:
        return None


def map_limit() -> int | None:
    """The operating system's cap on mapped regions per process (``vm.max_map_count``),
    or None where there is none to read."""
    try:
        return int(_LIMIT_FILE.read_text().split()[0])
    except (OSError, ValueError, IndexError):
        return None


def release() -> None:
    """Drop every cached executable of this process (JAX's and shadowlab's own), so
    their mapped regions are returned to the OS. Later calls recompile as needed."""
    from . import timing

    timing.clear_compiled()
    jax.clear_caches()
    gc.collect()


def guard(fraction: float = DEFAULT_FRACTION) -> bool:
    """Release cached executables when mapped regions exceed ``fraction`` of the cap.

    Returns True when it released. Costs one read of ``/proc/self/maps`` (a few ms at
    tens of thousands of regions); does nothing where the OS gives no counts.
    """
    count, limit = map_count(), map_limit()
    if count is None or limit is None or count <= fraction * limit:
        return False
    release()
    return True
