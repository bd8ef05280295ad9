"""Test-session set-up: one pytest process runs the whole suite.

Compilation caches are hermetic: JAX's persistent cache is off (in-memory caches only),
and Warp's kernel cache lives in a fresh temporary folder removed at the end, so the
tests never read or write the user's caches (``~/.cache/shadowlab``) and every session
starts cold.
To keep a warm cache between sessions while iterating, point ``SHADOWLAB_TEST_CACHE`` at
a folder of your own (it is used for tests only and never removed).
"""

import os
import shutil
import tempfile
from pathlib import Path

import pytest

_KEEP = os.environ.get("SHADOWLAB_TEST_CACHE")
CACHE_ROOT = Path(_KEEP) if _KEEP else Path(tempfile.mkdtemp(prefix="shadowlab-tests-"))
# Set before anything compiles; subprocesses started by tests inherit them.
os.environ["SHADOWLAB_JAX_CACHE"] = str(CACHE_ROOT / "jax")
os.environ["SHADOWLAB_WARP_CACHE"] = str(CACHE_ROOT / "warp")

from shadowlab.core.jaxcache import disable_compilation_cache, enable_compilation_cache  # noqa: E402

# No persistent JAX cache in a plain test session: nothing would survive the session,
# and XLA:CPU's executable serialization, which the cache writer calls, has segfaulted
# late in a one-process run of the suite (see shadowlab.core.jaxcache). Opting in with
# SHADOWLAB_TEST_CACHE keeps a warm cache at that risk.
if _KEEP:
    enable_compilation_cache(CACHE_ROOT / "jax")
else:
    disable_compilation_cache()


def pytest_unconfigure(config):
    if not _KEEP:
        shutil.rmtree(CACHE_ROOT, ignore_errors=True)


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
