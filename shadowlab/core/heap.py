"""The process's heap policy: whether memory freed between frames goes back to the
operating system.

A frame allocates and frees host arrays of tens of MB (NumPy host stages, XLA's CPU
buffers). glibc's ``malloc`` serves each block above its mmap threshold (128 KiB,
raised dynamically to at most 32 MiB) with fresh pages and unmaps them when it is
freed, and trims the top of the heap when more than its trim threshold is free (128
KiB, twice the mmap threshold once that has risen). So
every frame touches new pages, and the kernel pays a page fault for each: zeroing a
4 KiB page, or a 2 MiB huge page, which NumPy requests for large arrays
(``madvise``). Measured on a 2-core virtual machine (docs/benchmarks.md, "Heap policy
(session 56)"): ``silhouette`` on fuzzy 100k at 1024x1024 took 1.1-2.1 s of system time
per call (35-40 k faults) of a 5.3-7.8 s call under ``"system"``, and 0.6-0.8 s (3-14 k
faults) of a 4.3-4.5 s call under ``"retain"``.

Policies (``HEAP_POLICIES``):

- ``"retain"``: freed memory stays in the process for the next frame. Large blocks come
  from the heap instead of their own mappings (``M_MMAP_MAX = 0``), and the heap is
  trimmed only when more than ``TRIM_THRESHOLD`` bytes at its top are free. The
  resident size then stays near the largest frame's peak instead of falling back
  between frames, and can grow somewhat beyond it by fragmentation (a throw-away script
  that ran five exact methods on fuzzy 100k: 2.5-2.7 GB maximum resident size under
  ``"system"``, 2.9-3.2 GB under ``"retain"``).
- ``"system"``: glibc's defaults, untouched.

Only glibc has these knobs (``mallopt``); elsewhere (musl, macOS, Windows) every policy
leaves the allocator as it is and :func:`heap_policy` says ``"system"``. The default is
``"system"``: ``"retain"`` removes most page faults, which made the host-heavy methods
faster (``silhouette`` on fuzzy 100k 4.3-4.5 against 5.3-7.8 s, ``izb`` 0.72-0.77
against 0.87-0.89 s), but ``d_hybrid``'s query on fuzzy 100k was slower under it in
every comparison (4.7-5.0 against 3.8-4.1 s), for reasons not found. The command line
takes ``--heap retain`` (or ``SHADOWLAB_HEAP=retain``); the library changes nothing
until :func:`set_heap_policy` is called, since the policy is process-wide. The policy
in force is recorded with every timed result (``core.machine.machine_state``).
"""

from __future__ import annotations

import ctypes
import ctypes.util
import os

HEAP_POLICIES = ("retain", "system")
#: the environment variable the command line (and ``bench --cold``'s child processes)
#: read the policy from when none is given
HEAP_ENV = "SHADOWLAB_HEAP"
DEFAULT_POLICY = "system"
#: with ``"retain"``, free memory at the heap's top beyond this many bytes is returned
#: (mallopt takes a C int: the largest one, about 2 GiB)
TRIM_THRESHOLD = 2 ** 31 - 1

# mallopt parameters (malloc.h) and glibc's defaults for them
_M_TRIM_THRESHOLD = -1
_M_MMAP_MAX = -4
_DEFAULT_MMAP_MAX = 65536
_DEFAULT_TRIM_THRESHOLD = 128 * 1024

_applied = "system"


def _libc():
    """glibc's C library, or None where the process does not run on glibc."""
    try:
        libc = ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6")
        version = libc.gnu_get_libc_version
    except (OSError, AttributeError):
        return None
    version.restype = ctypes.c_char_p
    return libc if version() else None


def resolve_policy(policy: str | None = None) -> str:
    """The policy to apply: ``policy``, else ``$SHADOWLAB_HEAP``, else ``"system"``.

    Raises:
        ValueError: a policy that is not one of ``HEAP_POLICIES``, naming its source.
    """
    source = "heap policy"
    if policy is None:
        policy = os.environ.get(HEAP_ENV)
        source = HEAP_ENV if policy else source
        policy = policy or DEFAULT_POLICY
    if policy not in HEAP_POLICIES:
        raise ValueError(f"{source} must be one of {', '.join(HEAP_POLICIES)}; "
                         f"got {policy!r}")
    return policy


def set_heap_policy(policy: str | None = None) -> str:
    """Apply a heap policy to this process (module docstring); returns the policy now in
    force: ``"retain"`` only where glibc accepted it.

    ``"system"`` after ``"retain"`` restores glibc's default limits (64 Ki mappings, a
    128 KiB trim threshold), but not its dynamic threshold, which an explicit setting
    switches off for the life of the process; the free memory above the trim threshold
    is released at once (``malloc_trim``).

    Raises:
        ValueError: an unknown policy (:func:`resolve_policy`).
    """
    global _applied
    policy = resolve_policy(policy)
    if policy == _applied:
        return _applied
    libc = _libc()
    if libc is None:
        return _applied
    if policy == "retain":
        if libc.mallopt(_M_MMAP_MAX, 0):
            if libc.mallopt(_M_TRIM_THRESHOLD, TRIM_THRESHOLD):
                _applied = "retain"
            else:                       # all or nothing: mappings allowed again
                libc.mallopt(_M_MMAP_MAX, _DEFAULT_MMAP_MAX)
    else:
        libc.mallopt(_M_MMAP_MAX, _DEFAULT_MMAP_MAX)
        libc.mallopt(_M_TRIM_THRESHOLD, _DEFAULT_TRIM_THRESHOLD)
        libc.malloc_trim(ctypes.c_size_t(0))
        _applied = "system"
    return _applied


def heap_policy() -> str:
    """The heap policy in force in this process (``"system"`` until
    :func:`set_heap_policy` applied another)."""
    return _applied
