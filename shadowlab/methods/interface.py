"""What a shadow method is: its kind, its options as one typed model, its counters and stages.

A method is a function ``fn(scene, gbuf, light, **options) -> ShadowResult`` plus a
:class:`MethodInfo` that declares

- ``kind`` (:class:`MethodKind`): ``exact`` hard shadows (must equal
  ``reference_shadows``), ``approximate`` hard shadows (a lit mask with a documented
  error, e.g. a shadow map), or ``soft`` (visibility in [0, 1] for an area light);
- ``options``: ``{name: Option}``; the registry turns them into one pydantic model
  (``MethodInfo.model``) that validates, fills defaults and refuses unknown names;
- ``counters``: the names (from ``shadowlab.core.counters.COUNTERS``) every result carries;
- ``stages``: the names of the timing stages the method may report (seconds);
- ``presets``: optional named option sets, ``{name: {option: value}}``. A method with
  presets gets the option ``preset`` (default ``DEFAULT_PRESET``, "accurate": the
  options' own defaults, which are the method's most accurate configuration); a named
  preset (e.g. "paper": the paper's own choices) replaces those defaults, and options
  given explicitly still win over it.

The registry (``registry.py``) owns what every method would otherwise repeat:
validation, the light check, stamping name, options and total time into the result.
"""

from __future__ import annotations

import dataclasses
import enum
import functools
from typing import Annotated, Any, Callable, ClassVar, Literal

import pydantic

# The cap-plane bias as a fraction of the scene diagonal has one default, the Embree
# reference's (``raycast.DEFAULT_SHADOW_EPS``): every method's ``shadow_eps`` option, the
# run config's ``reference.shadow_eps`` and the boundary analysis use it.
from ..reference.raycast import DEFAULT_SHADOW_EPS
from ..scene.view import DirectionalLight, PointLight, SphereLight


#: the preset every method with presets starts from: its options' own defaults
DEFAULT_PRESET = "accurate"
#: common options the registry applies before the method runs (not passed to it)
REGISTRY_OPTIONS = ("cull_casters",)


class MethodError(ValueError):
    """Unknown method or option, an option value outside its allowed set or bounds, or a
    light the method cannot shade."""


class MethodKind(str, enum.Enum):
    """What a method computes, and so which reference and metric it is judged by."""

    EXACT = "exact"              # hard shadows equal to reference_shadows
    APPROXIMATE = "approximate"  # hard shadows with an error (shadow maps)
    SOFT = "soft"                # visibility in [0, 1] of an area light


@dataclasses.dataclass(frozen=True)
class Option:
    """One method option.

    Either ``allowed`` (a closed set of values; ``True`` and ``1`` are told apart), or
    ``kind`` (the Python type(s) accepted; an int is accepted for a float) with optional
    inclusive bounds ``minimum`` and ``maximum``.
    """

    default: Any
    doc: str
    allowed: tuple | None = None          # a closed set of values
    kind: type | tuple | None = None      # the Python type(s) accepted otherwise
    minimum: float | None = None          # inclusive lower bound for numbers
    maximum: float | None = None          # inclusive upper bound for numbers

    def describe_allowed(self) -> str:
        if self.allowed is not None:
            return ", ".join(repr(a) for a in self.allowed)
        kinds = self.kind if isinstance(self.kind, tuple) else (self.kind,)
        text = " or ".join(k.__name__ for k in kinds if k is not None) or "any"
        if self.minimum is not None:
            text += f" >= {self.minimum}"
        if self.maximum is not None:
            text += f"{' and' if self.minimum is not None else ''} <= {self.maximum}"
        return text

    def annotation(self):
        """The pydantic type of this option (a Literal, or a strict bounded number)."""
        if self.allowed is not None:
            return Annotated[Literal[self.allowed], pydantic.BeforeValidator(
                functools.partial(_exact_member, self.allowed))]
        kinds = self.kind if isinstance(self.kind, tuple) else (self.kind,)
        if kinds == (None,):
            return Any
        bounds = {k: v for k, v in (("ge", self.minimum), ("le", self.maximum))
                  if v is not None}
        types = [Annotated[k, pydantic.Strict()] for k in kinds]
        if float in kinds:
            # An int is a float (converted), a bool is not a number.
            types = [Annotated[float, pydantic.BeforeValidator(_int_as_float)]] + \
                [t for k, t in zip(kinds, types) if k is not float]
        base = types[0] if len(types) == 1 else _union(types)
        return Annotated[base, pydantic.Field(**bounds)] if bounds else base

    def validate(self, method: str, name: str, value):
        """``value`` checked (and an int converted for a float option); MethodError if not."""
        return options_model(method, ((name, self),)).validate_one(name, value)


def _union(types):
    import typing

    return typing.Union[tuple(types)]


def _exact_member(allowed: tuple, value):
    """The allowed member equal to ``value``; a bool never stands for a number (True is
    not 1) nor a number for a bool."""
    for a in allowed:
        if isinstance(value, bool) == isinstance(a, bool) and _equal(value, a):
            return a
    raise ValueError("not an allowed value")


def _equal(value, a) -> bool:
    try:
        return bool(value == a)
    except (TypeError, ValueError):       # e.g. an array compared with a string
        return False


def _int_as_float(value):
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise ValueError("not a number")
    return float(value)


class OptionsModel(pydantic.BaseModel):
    """Base of every method's options model: unknown names are refused, values strict."""

    model_config = pydantic.ConfigDict(extra="forbid", frozen=True)

    #: set on each generated model
    method: ClassVar[str] = ""
    specs: ClassVar[dict[str, Option]] = {}

    @classmethod
    def resolve(cls, options: dict) -> dict:
        """All options with defaults filled in; MethodError naming the method, the option,
        the value and the allowed values or bounds."""
        unknown = sorted(set(options) - set(cls.specs))
        if unknown:
            raise MethodError(f"method {cls.method!r}: unknown option(s) {', '.join(unknown)}; "
                              f"allowed options: {', '.join(sorted(cls.specs))}")
        try:
            return cls(**options).model_dump()
        except pydantic.ValidationError as exc:
            name = str(exc.errors()[0]["loc"][0])
            raise _option_error(cls.method, name, cls.specs[name], options[name]) from None

    @classmethod
    def validate_one(cls, name: str, value):
        return cls.resolve({name: value})[name]


def _option_error(method: str, name: str, spec: Option, value) -> MethodError:
    if spec.allowed is not None:
        return MethodError(f"method {method!r}: option {name}={value!r} is not allowed; "
                           f"allowed values: {spec.describe_allowed()}")
    return MethodError(f"method {method!r}: option {name}={value!r} must be "
                       f"{spec.describe_allowed()}")


@functools.lru_cache(maxsize=None)
def options_model(method: str, specs: tuple[tuple[str, Option], ...]) -> type[OptionsModel]:
    """The pydantic model of ``specs`` ((name, Option) pairs) for ``method``."""
    fields = {name: (spec.annotation(), spec.default) for name, spec in specs}
    model = pydantic.create_model(f"{method}_options", __base__=OptionsModel, **fields)
    model.method = method
    model.specs = dict(specs)
    return model


@dataclasses.dataclass(frozen=True)
class MethodInfo:
    """A registered method (see the module docstring).

    Attributes:
        counters: counter names every result carries, or None when not declared.
        stages: timing stage names the method may report (a run reports a subset).
        kernel: the Warp reference kernel version, ``fn(scene, gbuf, light, **options)``,
            or None (set by ``registry.register_kernel``).
        presets: ``{name: {option: value}}`` named option sets besides the defaults
            (``DEFAULT_PRESET``); empty when the method has none (and then no ``preset``
            option).
        frame: where the frame origin is centred for this method, "camera" or "light"
            (``shadowlab.core.frame.localize``); the method and its kernel get the
            scene, G-buffer and light relative to it.
        static_options: options that let the method keep light-dependent structures
            across calls when the light and the geometry are static (as Embree keeps
            its BVH); ``shadowlab bench`` sets them for its static ratio. Empty when the
            method keeps nothing of the kind.
    """

    name: str
    fn: Callable
    doc: str
    options: dict[str, Option]
    kind: MethodKind
    counters: tuple[str, ...] | None = None
    stages: tuple[str, ...] = ()
    paper: str = ""
    kernel: Callable | None = None
    presets: dict = dataclasses.field(default_factory=dict)
    frame: str = "camera"
    static_options: dict = dataclasses.field(default_factory=dict)

    @property
    def exact(self) -> bool:
        """Hard shadows that must equal reference_shadows."""
        return self.kind is MethodKind.EXACT

    @property
    def soft(self) -> bool:
        """Visibility in [0, 1] of an area light (needs a SphereLight)."""
        return self.kind is MethodKind.SOFT

    @property
    def model(self) -> type[OptionsModel]:
        """The options as one pydantic model (defaults, types, bounds, allowed sets)."""
        return options_model(self.name, tuple(self.options.items()))

    def resolve_options(self, options: dict) -> dict:
        """All options with defaults filled in: the ``preset``'s values where the method
        has presets, options given explicitly winning; MethodError on bad input."""
        if self.presets and "preset" in options:
            name = self.model.validate_one("preset", options["preset"])
            options = {**self.presets.get(name, {}), **options}
        return self.model.resolve(options)

    def call_options(self, resolved: dict) -> dict:
        """The resolved options the method function takes (``preset`` is resolved
        already, and the registry applies ``REGISTRY_OPTIONS`` itself: neither is
        passed on)."""
        return {k: v for k, v in resolved.items()
                if not (self.presets and k == "preset") and k not in REGISTRY_OPTIONS}

    def light_problem(self, light) -> str | None:
        """Why ``light`` cannot be used with this method, or None if it can."""
        if not isinstance(light, (PointLight, DirectionalLight, SphereLight)):
            return (f"light must be a PointLight, DirectionalLight or SphereLight, got "
                    f"{type(light).__name__}")
        if self.soft and not isinstance(light, SphereLight):
            return (f"computes soft shadows and needs a sphere or sun light; the light is a "
                    f"{type(light).__name__} (set light.type to sphere or sun)")
        return None

    def check_light(self, light) -> None:
        """MethodError if ``light`` does not suit the method."""
        problem = self.light_problem(light)
        if problem is not None:
            raise MethodError(f"method {self.name!r} {problem}" if problem.startswith("computes")
                              else problem)


def preset_option(presets: dict) -> Option:
    """The ``preset`` option of a method with ``presets`` ({name: {option: value}})."""
    names = (DEFAULT_PRESET,) + tuple(n for n in presets if n != DEFAULT_PRESET)
    listed = "; ".join(f"{n!r}: " + ", ".join(f"{k}={v!r}" for k, v in vals.items())
                       for n, vals in presets.items())
    return Option(DEFAULT_PRESET, f"named option set: {DEFAULT_PRESET!r} = the defaults "
                  f"(most accurate); {listed}; options given explicitly win",
                  allowed=names)


__all__ = ["DEFAULT_PRESET", "DEFAULT_SHADOW_EPS", "MethodError", "MethodInfo", "MethodKind", "Option",
           "OptionsModel", "options_model", "preset_option"]
