"""The method registry: declarations, option validation, dispatch and result stamping.

A method is a function ``fn(scene, gbuf, light, **options) -> ShadowResult`` registered
with :func:`register` (see ``interface.py`` for what it declares). Every method accepts
the common options in ``COMMON_OPTIONS``. :func:`compute_shadows` is the one way a
method runs: it checks the light (:func:`check_light`), validates the options, calls the
method, checks its counters against the declaration and the counter table, and stamps
the method name, the resolved options and the total run time into the result. Warp
kernel versions hang off the same entries (:func:`register_kernel`, :func:`run_kernel`).
"""

from __future__ import annotations

import dataclasses
import time
from typing import Callable

from ..core.counters import check as check_counters
from ..core.frame import FRAME_CENTRES, localize
from ..geometry import caster_culling
from .interface import (DEFAULT_PRESET, DEFAULT_SHADOW_EPS, REGISTRY_OPTIONS, MethodError,
                        MethodInfo, MethodKind, Option, OptionsModel, preset_option)

COMMON_OPTIONS: dict[str, Option] = {
    "precision": Option("float32", "floating-point precision of the computation",
                        allowed=("float32", "float64")),
    "shadow_eps": Option(DEFAULT_SHADOW_EPS, "cap-plane bias as a fraction of the scene "
                         "diagonal (the same offset the Embree reference uses)", kind=float,
                         minimum=0.0),
    "cull_casters": Option("off", "drop the triangles that shadow no sample of the frame "
                           "before the method runs (shared stage, exact): 'hull' outside "
                           "the hull of the samples' shadow rays, 'hull_averted' also "
                           "closed objects' triangles facing away from the light (hard "
                           "shadows), 'hull_receivers' also triangles behind every sample "
                           "of their light-space footprint (hard shadows), 'all' every "
                           "step", allowed=caster_culling.CULL_MODES),
}

_REGISTRY: dict[str, MethodInfo] = {}


#: stages every method reports: ``host`` (:func:`with_host_time`)
SHARED_STAGES = ("host",)


def _with_shared_stages(stages) -> tuple[str, ...]:
    """A method's declared stages and the shared ones (none where it declares none)."""
    return tuple(dict.fromkeys((*stages, *SHARED_STAGES))) if stages else ()


def register(name: str, *, doc: str, options: dict[str, Option] | None = None,
             kind: MethodKind | str | None = None, counters: tuple[str, ...] | None = None,
             stages: tuple[str, ...] = (), exact: bool = True, soft: bool = False,
             paper: str = "", presets: dict[str, dict] | None = None,
             frame: str = "camera", static_options: dict | None = None):
    """Decorator that adds a method to the registry.

    ``frame`` ("camera" or "light") centres the frame-local coordinates the method
    runs in (``shadowlab.core.frame.localize``, applied by :func:`compute_shadows` and
    :func:`run_kernel`).

    ``kind`` defaults from the older flags: ``soft`` -> soft, else ``exact`` -> exact,
    else approximate. ``counters`` (names from ``shadowlab.core.counters.COUNTERS``) and
    ``stages`` (the shared ``SHARED_STAGES`` added) are checked on every result.
    ``presets`` ({name: {option: value}}, e.g. ``{"paper": {...}}`` for the paper's own
    choices) add the option ``preset``
    (default ``DEFAULT_PRESET``: the options' defaults); every preset value is validated
    here. ``static_options`` ({option: value}, validated here) are what the method
    may keep across calls under a static light and geometry (``MethodInfo``).
    """
    if kind is None:
        kind = MethodKind.SOFT if soft else (MethodKind.EXACT if exact else
                                              MethodKind.APPROXIMATE)
    kind = MethodKind(kind)
    if frame not in FRAME_CENTRES:
        raise ValueError(f"register({name!r}): frame must be one of {FRAME_CENTRES}, "
                         f"got {frame!r}")
    if counters is not None:
        check_counters(dict.fromkeys(counters))

    def deco(fn):
        opts = dict(COMMON_OPTIONS)
        opts.update(options or {})
        sets = {k: dict(v) for k, v in (presets or {}).items()}
        if sets:
            if DEFAULT_PRESET in sets or "preset" in opts:
                raise ValueError(f"method {name!r}: the preset {DEFAULT_PRESET!r} is the "
                                 "defaults, and 'preset' is not an option name")
            opts["preset"] = preset_option(sets)
        old = _REGISTRY.get(name)
        info = MethodInfo(name, fn, doc, opts, kind,
                          None if counters is None else tuple(counters),
                          _with_shared_stages(stages), paper, old.kernel if old else None, sets,
                          frame, dict(static_options or {}))
        for preset, values in sets.items():
            if "preset" in values:
                raise ValueError(f"method {name!r}: preset {preset!r} sets 'preset'")
            info.model.resolve(values)          # MethodError on a bad preset value
        info.model.resolve(info.static_options)
        _REGISTRY[name] = info
        return fn
    return deco


def register_kernel(name: str, fn: Callable) -> None:
    """Attach the Warp kernel version ``fn(scene, gbuf, light, **options)`` to method
    ``name`` (already registered)."""
    info = get(name)
    _REGISTRY[name] = dataclasses.replace(info, kernel=fn)


def get(name: str) -> MethodInfo:
    _load_builtin()
    if name not in _REGISTRY:
        raise MethodError(f"unknown method {name!r}; available: {', '.join(sorted(_REGISTRY))}")
    return _REGISTRY[name]


def names() -> list[str]:
    _load_builtin()
    return sorted(_REGISTRY)


def available() -> dict[str, dict]:
    """Method name -> {doc, kind, exact, soft, kernel, paper, counters, stages,
    presets: {name: {option: value}}, static_options: {option: value},
    options: {name: {default, allowed, doc}}}."""
    _load_builtin()
    return {
        name: {
            "doc": info.doc, "kind": info.kind.value, "exact": info.exact, "soft": info.soft,
            "kernel": info.kernel is not None, "paper": info.paper,
            "counters": list(info.counters or ()), "stages": list(info.stages),
            "presets": {k: dict(v) for k, v in info.presets.items()},
            "static_options": dict(info.static_options),
            "options": {k: {"default": o.default, "allowed": o.describe_allowed(), "doc": o.doc}
                        for k, o in info.options.items()},
        }
        for name, info in sorted(_REGISTRY.items())
    }


def options_model(name: str) -> type[OptionsModel]:
    """The pydantic model of method ``name``'s options."""
    return get(name).model


def resolve_options(name: str, options: dict) -> dict:
    """All options of ``name`` with defaults filled in; raises MethodError on bad input."""
    return get(name).resolve_options(options)


def call_options(name: str, options: dict) -> dict:
    """The options method ``name``'s function (or kernel) takes: :func:`resolve_options`
    with a ``preset`` applied and not passed on."""
    info = get(name)
    return info.call_options(info.resolve_options(options))


def light_problem(name: str, light) -> str | None:
    """Why ``light`` does not suit method ``name`` (e.g. a soft method on a point light),
    or None."""
    return get(name).light_problem(light)


def check_light(name: str, light) -> None:
    """MethodError if ``light`` does not suit method ``name``."""
    get(name).check_light(light)


def check_result(info: MethodInfo, result) -> None:
    """The result's counters are in the counter table and are exactly the declared ones,
    and its stages are declared (MethodError otherwise)."""
    try:
        check_counters(result.counters)
    except KeyError as exc:
        raise MethodError(f"method {info.name!r}: {exc.args[0]}") from None
    if info.counters is not None:
        missing = sorted(set(info.counters) - set(result.counters))
        extra = sorted(set(result.counters) - set(info.counters))
        if missing or extra:
            raise MethodError(f"method {info.name!r}: counters differ from its declaration: "
                              f"missing {missing}, undeclared {extra}")
    if info.stages:
        stages = {k.removesuffix("_compile") for k in result.timings} - {"total"}
        extra = sorted(stages - set(info.stages))
        if extra:
            raise MethodError(f"method {info.name!r}: undeclared timing stage(s) {extra}; "
                              f"declared: {', '.join(info.stages)}")


def stamp(result, name: str, options: dict):
    """``result`` with the method name, the resolved options and ``timings["total"]`` (the
    sum of the stage run times, ``host`` included, compile excluded) filled in."""
    timings = dict(result.timings)
    timings["total"] = sum(v for k, v in timings.items()
                           if k != "total" and not k.endswith("_compile"))
    return dataclasses.replace(result, method=name, options=dict(options), timings=timings)


def compute_shadows(scene, gbuf, light, method: str = "brute_force", **options):
    """Run a registered method; see ``shadowlab.methods.available()`` for names and options.

    The method runs on the scene, G-buffer and light translated to its frame origin
    (``shadowlab.core.frame.localize``: world minus origin in float64, then float32).

    Returns:
        ShadowResult with ``lit`` [H, W], ``counters``, ``timings`` (seconds per stage,
        ``<stage>_compile`` apart, ``total``), ``method`` and the resolved ``options``.
    """
    info = get(method)
    info.check_light(light)
    opts = info.resolve_options(options)
    local = localize(scene, gbuf, light, info.frame)
    casters, gbuf, culled = _cull(info, local, opts["cull_casters"])
    t0 = time.perf_counter()
    result = info.fn(casters, gbuf, local.light, **info.call_options(opts))
    wall = time.perf_counter() - t0
    check_result(info, result)
    return stamp(culled(with_host_time(result, wall)), method, opts)


def with_host_time(result, wall: float):
    """``result`` with the part of the method's wall time ``wall`` (seconds) that none of
    its stages recorded (host code between them: gathers, list assembly, copies of the
    results) added to the stage ``host``, so that ``total`` is the whole call, compile
    apart, for every method."""
    timings = dict(result.timings)
    inner = sum(v for k, v in timings.items() if k != "total")
    timings["host"] = timings.get("host", 0.0) + max(wall - inner, 0.0)
    return dataclasses.replace(result, timings=timings)


def _cull(info: MethodInfo, local, mode: str):
    """The shared caster culling stage (``geometry.caster_culling``) on the frame-local
    scene: (the scene and G-buffer the method gets, its triangle ids renumbered; a
    function that adds the stage's counters and time to a result, the identity when
    ``mode`` is off)."""
    if mode == "off":
        return local.scene, local.gbuf, lambda result: result
    t0 = time.perf_counter()
    cull = caster_culling.cull_casters(local.scene, local.gbuf, local.light, mode,
                                       soft=info.soft)
    casters = caster_culling.subset_scene(local.scene, cull.keep)
    gbuf = caster_culling.subset_gbuffer(local.gbuf, cull.keep)
    seconds = time.perf_counter() - t0

    def add(result):
        return dataclasses.replace(
            result, counters={**result.counters, "culled_casters": cull.culled,
                              "culled_casters_hull": cull.hull,
                              "culled_casters_averted": cull.averted,
                              "culled_casters_receivers": cull.receivers},
            timings={**result.timings, "cull_casters": seconds})
    return casters, gbuf, add


def run_kernel(scene, gbuf, light, method: str, **options):
    """Run the Warp kernel version of ``method`` (MethodError if it has none). Kernel
    options beyond the method's own (``schedule``, ``form``, ...) pass through; the
    kernel resolves the method options itself and names its result ``kernels.<method>``."""
    info = get(method)
    if info.kernel is None:
        with_kernel = ", ".join(n for n in names() if get(n).kernel is not None)
        raise MethodError(f"no kernel version of {method!r}; available: {with_kernel}")
    info.check_light(light)
    options = dict(options)
    mode = info.model.validate_one("cull_casters", options.pop("cull_casters", "off"))
    local = localize(scene, gbuf, light, info.frame)
    casters, gbuf, culled = _cull(info, local, mode)
    t0 = time.perf_counter()
    result = info.kernel(casters, gbuf, local.light, **options)
    result = culled(with_host_time(result, time.perf_counter() - t0))
    check_counters(result.counters)
    return result


# Modules under shadowlab.methods whose import registers their methods.
BUILTIN_MODULES: tuple[str, ...] = ("brute_force", "psv", "clustered_ptsv", "ptsv", "stencil",
                                    "soft_tiled", "shadow_map", "izb", "silhouette")


def _load_builtin():
    import importlib

    for module in BUILTIN_MODULES:
        importlib.import_module(f"{__package__}.{module}")
    # The kernel package registers its kernels; it imports Warp only when one runs.
    importlib.import_module("shadowlab.kernels")


__all__ = ["BUILTIN_MODULES", "COMMON_OPTIONS", "DEFAULT_PRESET", "DEFAULT_SHADOW_EPS", "MethodError",
           "MethodInfo", "MethodKind", "Option", "available", "check_light", "check_result",
           "compute_shadows", "get", "light_problem", "names", "options_model", "register",
           "register_kernel", "resolve_options", "run_kernel", "stamp"]
