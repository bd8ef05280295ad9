"""Test-session set-up: one pytest session runs the whole suite (CI: on every core with
pytest-xdist, ``-n auto --dist loadfile``, so each worker process runs whole test files
and its module-level caches and compiled shapes serve the whole file; every worker runs
this set-up for itself). The heap policy of the command line is ``system`` in the tests
(``SHADOWLAB_HEAP``, ``shadowlab.core.heap``).

Compilation caches are hermetic: every session gets a fresh temporary folder for JAX's
persistent cache (shared by the session's xdist workers) and Warp's kernel caches (one per
process) and removes it at the end, so the tests never read or write the user's caches
(``~/.cache/shadowlab``) and every session starts cold.
To keep a warm cache between sessions while iterating, point ``SHADOWLAB_TEST_CACHE`` at
a folder of your own (it is used for tests only and never removed). Live executables are
bounded before every test (``shadowlab.core.executables``; docs/xla_map_count.md).
"""

import os
import shutil
import tempfile
from pathlib import Path

import pytest

_KEEP = os.environ.get("SHADOWLAB_TEST_CACHE")
# The session's folder: made by the first process (pytest itself, or xdist's controller)
# and inherited by the xdist workers it starts, so a program one worker compiled is read
# from disk by the others (JAX's cache entries are written atomically, see
# ``core.jaxcache``). Only the process that made it removes it.
_SESSION_VAR = "SHADOWLAB_TEST_SESSION_CACHE"
_WORKER = os.environ.get("PYTEST_XDIST_WORKER")
_SESSION = os.environ.get(_SESSION_VAR) if _WORKER else None
_OWNER = not _KEEP and not _SESSION
if _KEEP:
    CACHE_ROOT = Path(_KEEP)
elif _SESSION:
    CACHE_ROOT = Path(_SESSION)
else:               # any process but an xdist worker starts a session of its own
    CACHE_ROOT = Path(tempfile.mkdtemp(prefix="shadowlab-tests-"))
    os.environ[_SESSION_VAR] = str(CACHE_ROOT)
# Set before anything compiles; subprocesses started by tests inherit them. Warp's kernel
# cache stays per process (its module builds are not known to be safe to share).
os.environ["SHADOWLAB_JAX_CACHE"] = str(CACHE_ROOT / "jax")
os.environ["SHADOWLAB_WARP_CACHE"] = str(
    CACHE_ROOT / f"warp-{os.environ.get('PYTEST_XDIST_WORKER', 'main')}")
# The command line's heap policy (``core.heap``) is glibc's own in the tests, whatever the
# user's environment says: the tests call it in long-lived worker processes. The
# policy's own tests run in child processes and set it themselves.
os.environ["SHADOWLAB_HEAP"] = "system"

from shadowlab.core import executables  # noqa: E402
from shadowlab.core.jaxcache import enable_compilation_cache  # noqa: E402

enable_compilation_cache(CACHE_ROOT / "jax")


def pytest_unconfigure(config):
    if _OWNER:
        shutil.rmtree(CACHE_ROOT, ignore_errors=True)
        if os.environ.get(_SESSION_VAR) == str(CACHE_ROOT):
            del os.environ[_SESSION_VAR]


@pytest.fixture(params=["float32", "float64"])
def precision(request):
    """Every exact-method test runs in float32 (the GPU's) and float64 (x64 on)."""
    return request.param


def pytest_ignore_collect(collection_path, config):
    """Under a marker expression that excludes ``kernels`` the kernel test files are not
    imported at all, so such a run does not pay for importing and initialising Warp."""
    expr = config.getoption("markexpr", "") or ""
    if "not kernels" in expr and collection_path.name.startswith("test_kernels"):
        return True
    return None


SOFT = {"test_soft_tiled", "test_sun_disk"}


def pytest_collection_modifyitems(config, items):
    """Markers for selective runs (the full suite runs in one process): ``kernels`` for
    the Warp kernel tests, ``soft`` for the soft-shadow tests."""
    for item in items:
        if item.module.__name__.startswith("test_kernels"):
            item.add_marker(pytest.mark.kernels)
        elif item.module.__name__ in SOFT:
            item.add_marker(pytest.mark.soft)


@pytest.fixture(autouse=True)
def _bounded_executables():
    """Keep the process under the OS's cap on mapped regions: XLA:CPU maps ~28 regions
    per live executable and segfaults at ``vm.max_map_count``, which the whole suite in
    one process would otherwise reach (``shadowlab.core.executables``)."""
    executables.guard()
    yield
