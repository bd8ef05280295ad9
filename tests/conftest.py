import pytest

from shadowlab.jaxcache import enable_compilation_cache

enable_compilation_cache()


@pytest.fixture(params=["float32", "float64"])
def precision(request):
    """Every exact-method test runs in float32 (the GPU's) and float64 (x64 on)."""
    return request.param


def pytest_ignore_collect(collection_path, config):
    """Under a marker expression that excludes ``kernels`` the kernel test files are not
    even imported, so Warp (and its bundled LLVM) never loads next to XLA there."""
    expr = config.getoption("markexpr", "") or ""
    if "not kernels" in expr and collection_path.name.startswith("test_kernels"):
        return True
    return None


ISOLATED = {"test_soft_tiled": "soft", "test_sun_disk": "soft"}


def pytest_collection_modifyitems(config, items):
    """Tag the tests the README test command runs in processes of their own: the Warp
    kernel tests (Warp's bundled LLVM never loads next to XLA), and the soft-shadow tests
    (``soft``): on a cold cache, XLA segfaults serializing one soft_tiled executable for
    the persistent cache when the process has compiled the rest of the suite before
    (reproduced twice; the same tests pass cold on their own). Not diagnosed further."""
    for item in items:
        if item.module.__name__.startswith("test_kernels"):
            item.add_marker(pytest.mark.kernels)
        elif item.module.__name__ in ISOLATED:
            item.add_marker(getattr(pytest.mark, ISOLATED[item.module.__name__]))
