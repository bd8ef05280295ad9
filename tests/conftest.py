import pytest

from shadowlab.jaxcache import enable_compilation_cache

enable_compilation_cache()


@pytest.fixture(params=["float32", "float64"])
def precision(request):
    """Every exact-method test runs in float32 (the GPU's) and float64 (x64 on)."""
    return request.param
