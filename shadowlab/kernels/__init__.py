"""Reference hardware kernels: the algorithms as a GPU runs them (NVIDIA Warp).

The same inputs and the same counters as the vectorized JAX methods, written in the
GPU's execution model (a thread per triangle or per pixel, atomics, compare-and-swap,
local stacks, 32-lane warps) so that every counter can be checked between the two and
the same source runs on a CUDA GPU when one is present. Tested on Warp's CPU backend.
See docs/kernels.md.

Warp is optional (``pip install -e ".[kernels]"``): ``import shadowlab`` never imports
it; :func:`available` says whether it is installed, and the functions below import
it on first use::

    from shadowlab import kernels
    if kernels.available():
        res = kernels.compute_shadows(scene, gbuf, light, method="d_psv")
        tree, stats = kernels.psv_build(build_input)
        out = kernels.psv_query(tree, points, scale, key, light_h, query="hybrid", ...)
        vis = kernels.sun_disk_visibility(...)
        res = kernels.compute_shadows(scene, gbuf, light, method="clustered_ptsv",
                                      form="lanes", passes=2)

One file per algorithm: ``psv.py`` (TOP-tree insertion and the four queries),
``clustered_ptsv.py`` (hierarchy build, triangle setup, the Algorithm 1 traversal in a
faithful 32-lane form and a fast warp-per-thread form, the merge),
``sun_disk.py`` (the per-fragment bitmask rasterizer of tiled soft shadows),
``runtime.py`` (Warp initialisation and the kernel cache), ``bench.py``
(``python -m shadowlab.kernels.bench``), ``aot.py`` (ahead-of-time CUDA compilation).
"""

from __future__ import annotations

import importlib.util

#: methods with a kernel version (``compute_shadows(method=...)``)
METHODS = ("psv", "d_psv", "d_stackless", "d_hybrid", "clustered_ptsv")
#: the PSV methods (``kernels/psv.py``)
PSV_METHODS = ("psv", "d_psv", "d_stackless", "d_hybrid")


def available() -> bool:
    """True when warp-lang is installed (the kernels can run)."""
    return importlib.util.find_spec("warp") is not None


def _require():
    if not available():
        raise ImportError("shadowlab.kernels needs NVIDIA Warp: pip install -e \".[kernels]\" "
                          "(or pip install warp-lang)")


def compute_shadows(scene, gbuf, light, method: str = "d_psv", **options):
    """Run a method with the kernels; same options and counters as
    ``shadowlab.compute_shadows`` (see ``kernels.psv.run``, ``kernels.clustered_ptsv.run``;
    the latter also takes ``form="lanes"`` (faithful) or ``"warp"`` (fast))."""
    _require()
    if method not in METHODS:
        raise ValueError(f"no kernel version of {method!r}; available: {', '.join(METHODS)}")
    if method == "clustered_ptsv":
        from . import clustered_ptsv
        return clustered_ptsv.run(scene, gbuf, light, **options)
    from . import psv
    return psv.run(method, scene, gbuf, light, **options)


def psv_build(inp, wedge: str = "conservative", schedule: str = "threads", **kw):
    """TOP-tree insertion kernel; see ``kernels.psv.build_tree``."""
    _require()
    from . import psv
    return psv.build_tree(inp, wedge, schedule=schedule, **kw)


def psv_query(tree, points, scale, key, light_h, **kw):
    """PSV / D-PSV / D-Stackless / D-Hybrid query kernel; see ``kernels.psv.query``."""
    _require()
    from . import psv
    return psv.query(tree, points, scale, key, light_h, **kw)


def sun_disk_visibility(*args, **kw):
    """Per-fragment bitmask rasterizer; see ``kernels.sun_disk.visibility``."""
    _require()
    from . import sun_disk
    return sun_disk.visibility(*args, **kw)


__all__ = ["METHODS", "PSV_METHODS", "available", "compute_shadows", "psv_build", "psv_query",
           "sun_disk_visibility"]
