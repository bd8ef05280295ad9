"""The method registry: names, options with defaults and allowed values, dispatch.

A method is a function ``fn(scene, gbuf, light, **options) -> ShadowResult`` registered
with :func:`register`. Every method accepts the common options in ``COMMON_OPTIONS``.
"""

from __future__ import annotations

import dataclasses
from typing import Any, Callable

from ..counters import check as check_counters
from ..scene.view import DirectionalLight, PointLight, SphereLight


class MethodError(ValueError):
    """Unknown method or option, or an option value outside its allowed set."""


@dataclasses.dataclass(frozen=True)
class Option:
    """One method option.

    ``allowed`` is a tuple of allowed values, or a (type, predicate, description)
    check given by ``kind``/``check`` below.
    """

    default: Any
    doc: str
    allowed: tuple | None = None          # a closed set of values
    kind: type | tuple | None = None      # the Python type(s) accepted otherwise
    minimum: float | None = None          # inclusive lower bound for numbers

    def describe_allowed(self) -> str:
        if self.allowed is not None:
            return ", ".join(repr(a) for a in self.allowed)
        kinds = self.kind if isinstance(self.kind, tuple) else (self.kind,)
        text = " or ".join(k.__name__ for k in kinds if k is not None) or "any"
        if self.minimum is not None:
            text += f" >= {self.minimum}"
        return text

    def validate(self, method: str, name: str, value):
        if self.allowed is not None:
            if value not in self.allowed:
                raise MethodError(f"method {method!r}: option {name}={value!r} is not allowed; "
                                  f"allowed values: {self.describe_allowed()}")
            return value
        if self.kind is not None:
            kinds = self.kind if isinstance(self.kind, tuple) else (self.kind,)
            if float in kinds and isinstance(value, int) and not isinstance(value, bool):
                value = float(value)
            if isinstance(value, bool) and bool not in kinds:
                raise MethodError(f"method {method!r}: option {name}={value!r} must be "
                                  f"{self.describe_allowed()}")
            if not isinstance(value, kinds):
                raise MethodError(f"method {method!r}: option {name}={value!r} must be "
                                  f"{self.describe_allowed()}")
        if self.minimum is not None and value < self.minimum:
            raise MethodError(f"method {method!r}: option {name}={value!r} must be "
                              f"{self.describe_allowed()}")
        return value


COMMON_OPTIONS: dict[str, Option] = {
    "precision": Option("float32", "floating-point precision of the computation",
                        allowed=("float32", "float64")),
    "shadow_eps": Option(1e-5, "cap-plane bias as a fraction of the scene diagonal "
                         "(the same offset the Embree reference uses)", kind=float, minimum=0.0),
}


@dataclasses.dataclass(frozen=True)
class MethodInfo:
    name: str
    fn: Callable
    doc: str
    options: dict[str, Option]
    exact: bool                 # hard shadows that must equal reference_shadows
    soft: bool = False          # returns visibility in [0, 1] for area lights
    paper: str = ""


_REGISTRY: dict[str, MethodInfo] = {}


def register(name: str, *, doc: str, options: dict[str, Option] | None = None,
             exact: bool = True, soft: bool = False, paper: str = ""):
    """Decorator that adds a method to the registry."""
    def deco(fn):
        opts = dict(COMMON_OPTIONS)
        opts.update(options or {})
        _REGISTRY[name] = MethodInfo(name, fn, doc, opts, exact, soft, paper)
        return fn
    return deco


def get(name: str) -> MethodInfo:
    _load_builtin()
    if name not in _REGISTRY:
        raise MethodError(f"unknown method {name!r}; available: {', '.join(sorted(_REGISTRY))}")
    return _REGISTRY[name]


def names() -> list[str]:
    _load_builtin()
    return sorted(_REGISTRY)


def available() -> dict[str, dict]:
    """Method name -> {doc, exact, soft, paper, options: {name: {default, allowed, doc}}}."""
    _load_builtin()
    return {
        name: {
            "doc": info.doc, "exact": info.exact, "soft": info.soft, "paper": info.paper,
            "options": {k: {"default": o.default, "allowed": o.describe_allowed(), "doc": o.doc}
                        for k, o in info.options.items()},
        }
        for name, info in sorted(_REGISTRY.items())
    }


def resolve_options(name: str, options: dict) -> dict:
    """All options of ``name`` with defaults filled in; raises MethodError on bad input."""
    info = get(name)
    unknown = sorted(set(options) - set(info.options))
    if unknown:
        raise MethodError(f"method {name!r}: unknown option(s) {', '.join(unknown)}; "
                          f"allowed options: {', '.join(sorted(info.options))}")
    out = {}
    for key, opt in info.options.items():
        out[key] = opt.validate(name, key, options.get(key, opt.default))
    return out


def compute_shadows(scene, gbuf, light, method: str = "brute_force", **options):
    """Run a registered method; see ``shadowlab.methods.available()`` for names and options.

    Returns:
        ShadowResult with ``lit`` [H, W], ``counters`` and ``timings`` (seconds).
    """
    info = get(method)
    if not isinstance(light, (PointLight, DirectionalLight, SphereLight)):
        raise MethodError(f"light must be a PointLight, DirectionalLight or SphereLight, "
                          f"got {type(light).__name__}")
    if info.soft and not isinstance(light, SphereLight):
        raise MethodError(f"method {method!r} computes soft shadows and needs a SphereLight")
    opts = resolve_options(method, options)
    result = info.fn(scene, gbuf, light, **opts)
    check_counters(result.counters)
    return result


# Modules under shadowlab.methods whose import registers their methods.
BUILTIN_MODULES: tuple[str, ...] = ("brute_force", "psv", "clustered_ptsv", "ptsv", "stencil",
                                    "soft_tiled")


def _load_builtin():
    import importlib

    for module in BUILTIN_MODULES:
        importlib.import_module(f"{__package__}.{module}")
