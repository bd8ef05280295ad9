import pytest

from shadowlab.jaxcache import enable_compilation_cache

enable_compilation_cache()


@pytest.fixture(params=["float32", "float64"])
def precision(request):
    """Every exact-method test runs in float32 (the GPU's) and float64 (x64 on)."""
    return request.param


def pytest_ignore_collect(collection_path, config):
    """With ``-m "not kernels"`` the kernel test files are not even imported, so Warp
    (and its bundled LLVM) is never loaded next to XLA in that process."""
    expr = (config.getoption("markexpr", "") or "").split()
    if expr == ["not", "kernels"] and collection_path.name.startswith("test_kernels"):
        return True
    return None


def pytest_collection_modifyitems(config, items):
    """Tag the Warp kernel tests: the README test command runs them in a process of their
    own, so Warp's bundled LLVM and XLA's never compile in the same process (a JAX
    persistent-cache write crashed once after the kernel tests had run)."""
    for item in items:
        if item.module.__name__.startswith("test_kernels"):
            item.add_marker(pytest.mark.kernels)
