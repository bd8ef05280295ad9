"""Reference hardware kernels: the algorithms as a GPU runs them (NVIDIA Warp).

The same inputs and the same counters as the vectorized JAX methods, written in the
GPU's execution model (a thread per triangle or per pixel, atomics, compare-and-swap,
local stacks, 32-lane warps) so that every counter can be checked between the two and
the same source runs on a CUDA GPU when one is present. Tested on Warp's CPU backend.
See docs/kernels.md.

Warp is optional (``pip install -e ".[kernels]"``): ``import shadowlab`` never imports
it; :func:`available` says whether it is installed, and the functions below import
it on first use::

    from .. import kernels
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
``izb.py`` (the irregular z-buffer's list build and per-texel tracing walk),
``runtime.py`` (Warp initialisation and the kernel cache), ``bench.py``
(``python -m shadowlab.kernels.bench``), ``aot.py`` (ahead-of-time CUDA compilation).
"""

from __future__ import annotations

import importlib.util

from ..methods import registry

#: the PSV methods (``kernels/psv.py``)
PSV_METHODS = ("psv", "d_psv", "d_stackless", "d_hybrid")


def available() -> bool:
    """True when warp-lang is installed (the kernels can run)."""
    return importlib.util.find_spec("warp") is not None


def _require():
    if not available():
        raise ImportError("shadowlab.kernels needs NVIDIA Warp: pip install -e \".[kernels]\" "
                          "(or pip install warp-lang)")


def _psv_kernel(method: str):
    def run(scene, gbuf, light, **options):
        """``kernels.psv.run`` for this method (Warp is imported here, on first use)."""
        _require()
        from . import psv
        return psv.run(method, scene, gbuf, light, **options)
    return run


def _clustered_ptsv_kernel(scene, gbuf, light, **options):
    """``kernels.clustered_ptsv.run`` (Warp is imported here, on first use)."""
    _require()
    from . import clustered_ptsv
    return clustered_ptsv.run(scene, gbuf, light, **options)


def _izb_kernel(scene, gbuf, light, **options):
    """``kernels.izb.run`` (Warp is imported here, on first use)."""
    _require()
    from . import izb
    return izb.run(scene, gbuf, light, **options)


# The kernel versions hang off the method registry's entries.
for _name in PSV_METHODS:
    registry.register_kernel(_name, _psv_kernel(_name))
registry.register_kernel("clustered_ptsv", _clustered_ptsv_kernel)
registry.register_kernel("izb", _izb_kernel)


def methods() -> list[str]:
    """The registered methods that have a kernel version."""
    return [n for n in registry.names() if registry.get(n).kernel is not None]


def __getattr__(name):
    if name == "METHODS":        # the kernel-backed methods, read from the registry
        return tuple(methods())
    raise AttributeError(name)


def compute_shadows(scene, gbuf, light, method: str = "d_psv", **options):
    """Run a method with the kernels; same options and counters as
    ``shadowlab.compute_shadows`` (see ``kernels.psv.run``, ``kernels.clustered_ptsv.run``;
    the latter also takes ``form="lanes"`` (faithful) or ``"warp"`` (fast)). The kernel
    is looked up in the method registry (``MethodInfo.kernel``)."""
    _require()
    return registry.run_kernel(scene, gbuf, light, method, **options)


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


def silhouette_multiplicity(scene, light_h, eye, **kw):
    """Per-edge multiplicity of silhouette shadow volumes; see
    ``kernels.silhouette.multiplicity``."""
    _require()
    from . import silhouette
    return silhouette.multiplicity(scene, light_h, eye, **kw)


def silhouette_visibility(a, b, light_h, camera, mode, **kw):
    """Clip-space visibility test of silhouette side quads; see
    ``kernels.silhouette.side_visibility_mask``."""
    _require()
    from . import silhouette
    return silhouette.side_visibility_mask(a, b, light_h, camera, mode, **kw)


__all__ = ["METHODS", "PSV_METHODS", "available", "compute_shadows", "methods", "psv_build",
           "psv_query", "silhouette_multiplicity", "silhouette_visibility",
           "sun_disk_visibility"]
