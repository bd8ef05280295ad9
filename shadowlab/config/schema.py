"""The run configuration schema: one frozen pydantic model per table.

Each table of a run config (see :mod:`shadowlab.config`) is validated by the model of
the same name (``[camera]`` by :class:`CameraConfig`, ...); the validated models are
also what :class:`RunConfig` holds, so a config object is its own schema. Every model
forbids unknown keys, takes numbers strictly (no booleans for numbers, no floats for
integers, finite floats only) and is frozen.

Each field carries a ``wanted`` text ("a finite number > 0 and < 180 (degrees)") in
its ``json_schema_extra``, built here from the same bounds that pydantic enforces;
:func:`shadowlab.config.errors.from_validation_error` quotes it in the error message.
Checks that need more than the table (generator parameters, method names and options,
mesh paths, the light type of ``animation.light_keys``) are done by
:mod:`shadowlab.config.loading`, which knows the registries and the file's folder.
"""

from __future__ import annotations

from typing import Annotated, Any, Literal, Optional

from pydantic import (AfterValidator, BaseModel, ConfigDict, Field, StrictBool, StrictFloat,
                      StrictInt, StrictStr, model_validator)
from pydantic_core import PydanticCustomError

from ..core.io import jsonable
from ..reference.raycast import DEFAULT_SHADOW_EPS
from ..scene import procedural
from ..scene.mesh import Scene
from ..scene.view import View

#: ``scene.source`` when a config has none (the built-in default's scene).
DEFAULT_SOURCE = "gate"

#: Light types and the keys each one uses (besides ``type``).
LIGHT_TYPES: dict[str, tuple[str, ...]] = {
    "point": ("position",),
    "directional": ("direction",),
    "sphere": ("position", "radius"),
    "sun": ("direction", "angular_radius_deg"),
}
#: The default angular radius of a sun, degrees (the real sun seen from the earth).
SUN_ANGULAR_RADIUS_DEG = 0.27

LightType = Literal["point", "directional", "sphere", "sun"]

_TABLE = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)


def _wanted(text: str, **extra) -> Any:
    """Field metadata: the ``wanted`` text of error messages (and ``item_wanted`` or
    ``table``)."""
    return Field(json_schema_extra={"wanted": text, **extra})


def number(kind: type, *, gt: float | None = None, ge: float | None = None,
           lt: float | None = None, le: float | None = None, unit: str = "",
           optional: bool = False) -> Any:
    """A strict int or finite float type with bounds, its ``wanted`` text built from
    the same bounds ("an integer >= 1", "a finite number > 0 and < 90 (degrees)")."""
    fmt = (lambda b: f"{b}") if kind is int else (lambda b: f"{b:g}")
    parts = [f"{op} {fmt(b)}" for op, b in ((">", gt), (">=", ge), ("<", lt), ("<=", le))
             if b is not None]
    wanted = ("an integer" if kind is int else "a finite number") \
        + (" " + " and ".join(parts) if parts else "") + unit
    base = Annotated[StrictInt if kind is int else StrictFloat,
                     Field(gt=gt, ge=ge, lt=lt, le=le)]
    return Annotated[Optional[base] if optional else base, _wanted(wanted)]


def _nonzero(vec: tuple[float, float, float]) -> tuple[float, float, float]:
    if not any(vec):
        raise PydanticCustomError("nonzero_vector", "must not be the zero vector")
    return vec


_XYZ = tuple[StrictFloat, StrictFloat, StrictFloat]
_VEC3 = "3 finite numbers [x, y, z]"
NONZERO_VEC3 = "a non-zero vector of 3 finite numbers [x, y, z]"
Vec3 = Annotated[Optional[_XYZ], _wanted(_VEC3)]
NonZeroVec3 = Annotated[Optional[Annotated[_XYZ, AfterValidator(_nonzero)]],
                        _wanted(NONZERO_VEC3)]
Keys = Annotated[Optional[Annotated[tuple[_XYZ, ...], Field(min_length=1)]],
                 _wanted("a non-empty list of [x, y, z] keys", item_wanted=_VEC3)]
Resolution = Annotated[Optional[tuple[Annotated[StrictInt, Field(ge=1)],
                                      Annotated[StrictInt, Field(ge=1)]]],
                       _wanted("two positive integers [width, height]")]
Table = Annotated[dict[str, Any], _wanted("a table", table=True)]


def _cross(key: str, message: str, *also: str, override_hint: str = "") -> PydanticCustomError:
    """An error about ``key`` found by a model validator (it may involve ``also``)."""
    return PydanticCustomError("config_cross_field", "{key} {message}",
                               {"key": key, "message": message, "also": list(also),
                                "override_hint": override_hint})


class RunFile(BaseModel):
    """The top level of a run config: which tables there are (each checked by its own
    model below, in this order)."""

    model_config = _TABLE
    scene: Table = {}
    camera: Table = {}
    light: Table = {}
    animation: Table = {}
    methods: Table = {}
    reference: Table = {}
    output: Table = {}


class SceneTable(BaseModel):
    """``[scene]`` as written (the source is resolved by the loader)."""

    model_config = _TABLE
    source: Annotated[StrictStr, Field(pattern=r"\S"), _wanted(
        "a procedural generator name (" + ", ".join(procedural.GENERATORS)
        + ") or a mesh file path")] = DEFAULT_SOURCE
    params: Table = {}


class SceneConfig(BaseModel):
    """What to load.

    Attributes:
        source: a procedural generator name, or the resolved (absolute) path of a mesh
            file.
        params: generator parameters with the generator's defaults filled in (empty for
            mesh files), validated by the generator's model
            (:func:`shadowlab.scene.procedural.params_model`).
    """

    model_config = ConfigDict(frozen=True)
    source: str
    params: dict[str, Any] = {}

    @property
    def is_procedural(self) -> bool:
        """True when ``source`` names a procedural generator."""
        return self.source in procedural.GENERATORS


class CameraConfig(BaseModel):
    """Camera keys given by the config; ``None`` = take it from the scene's default view.

    Positions in world units, angles in degrees, resolution in pixels (width, height).
    """

    model_config = _TABLE
    eye: Vec3 = None
    target: Vec3 = None
    up: NonZeroVec3 = None
    fov_y_deg: number(float, gt=0, lt=180, unit=" (degrees)", optional=True) = None
    near: number(float, gt=0, optional=True) = None
    far: number(float, gt=0, optional=True) = None
    resolution: Resolution = None

    @model_validator(mode="after")
    def _consistent(self):
        if self.near is not None and self.far is not None and not self.near < self.far:
            raise _cross("camera.far", f"must be greater than camera.near, got near = "
                         f"{self.near!r}, far = {self.far!r}", "camera.near")
        if self.eye is not None and self.eye == self.target:
            raise _cross("camera.target", f"must differ from camera.eye, both are "
                         f"[{', '.join(map(repr, self.eye))}]", "camera.eye")
        return self


class LightConfig(BaseModel):
    """Light keys given by the config; ``None`` = from the scene's default light.

    ``type`` is one of :data:`LIGHT_TYPES` or ``None`` (keep the default light's type);
    ``radius`` in world units, ``angular_radius_deg`` in degrees; ``direction`` is the
    way the light travels.
    """

    model_config = _TABLE
    type: Optional[LightType] = None
    position: Vec3 = None
    direction: NonZeroVec3 = None
    radius: number(float, gt=0, unit=" (world units)", optional=True) = None
    angular_radius_deg: number(float, gt=0, lt=90, unit=" (degrees)", optional=True) = None

    @model_validator(mode="after")
    def _keys_of_the_type(self):
        if self.type is None:
            return self
        used = LIGHT_TYPES[self.type]
        for key in ("position", "direction", "radius", "angular_radius_deg"):
            if getattr(self, key) is not None and key not in used:
                raise _cross(f"light.{key}", f"is not used by a {self.type} light "
                             f"(light.type = {self.type!r}); allowed keys for a {self.type} "
                             "light: " + ", ".join(("type",) + used), "light.type",
                             override_hint="; to replace the whole light, override the "
                             "table, e.g. --set 'light={type=\"sun\", direction=[0, -1, 0]}'")
        return self


class AnimationConfig(BaseModel):
    """Key-frame paths sampled to ``frames`` frames (see :class:`shadowlab.Animation`).

    ``light_keys`` are positions for point and sphere lights, directions for
    directional lights and suns (then non-zero; checked by the loader, which knows the
    light type).
    """

    model_config = _TABLE
    frames: number(int, ge=1) = 1
    eye_keys: Keys = None
    target_keys: Keys = None
    light_keys: Keys = None


class MethodsTable(BaseModel):
    """``[methods]`` as written (names and options are checked against the registry
    by the loader)."""

    model_config = _TABLE
    names: Any = "all"
    options: Table = {}


class MethodsConfig(BaseModel):
    """The methods to run, in order, and the full option set of each (defaults filled
    in, validated by :func:`shadowlab.methods.resolve_options`)."""

    model_config = ConfigDict(frozen=True)
    names: tuple[str, ...]
    options: dict[str, dict[str, Any]] = {}
    all: bool = False   # names came from "all": methods that cannot run on the light are skipped
    given: dict[str, tuple[str, ...]] = {}   # per method, the options the config wrote


class ReferenceConfig(BaseModel):
    """The exact reference: shadow-ray offset (fraction of the scene diagonal), rays per
    pixel and seed of the soft-shadow reference."""

    model_config = _TABLE
    shadow_eps: number(float, ge=0, unit=" (fraction of the scene diagonal)") = DEFAULT_SHADOW_EPS
    soft_rays: number(int, ge=1) = 64
    seed: number(int, ge=0) = 0


class OutputConfig(BaseModel):
    """Where results go (relative to the current directory), and whether figures are
    drawn."""

    model_config = _TABLE
    dir: Annotated[StrictStr, Field(pattern=r"\S"), _wanted("a non-empty path string")] \
        = "runs/default"
    figures: Annotated[StrictBool, _wanted("true or false")] = True


class RunConfig(BaseModel):
    """A validated run configuration.

    Attributes:
        source: the config file path as given, or ``"<built-in default>"``.
        overrides: the ``--set`` strings applied, in order.
    """

    model_config = ConfigDict(frozen=True)
    scene: SceneConfig
    camera: CameraConfig
    light: LightConfig
    animation: AnimationConfig
    methods: MethodsConfig
    reference: ReferenceConfig
    output: OutputConfig
    source: str
    overrides: tuple[str, ...] = ()

    def to_dict(self) -> dict[str, Any]:
        """A plain, JSON-able dict of every setting (tuples become lists)."""
        data = self.model_dump()
        data["methods"].pop("all")
        order = ("source", "overrides", "scene", "camera", "light", "animation", "methods",
                 "reference", "output")
        return jsonable({k: data[k] for k in order})

    def build_scene(self) -> Scene:
        """Load the mesh file or run the generator (``shadowlab.scene.load_scene``)."""
        from . import views
        return views.build_scene(self)

    def default_view(self, scene: Scene | None = None) -> View:
        """The scene's own view: the generator's default view, or for a mesh file a
        camera framing its bounding box and a light above and to the side
        (:func:`shadowlab.config.mesh_default_view`)."""
        from . import views
        return views.default_view(self, scene)

    def views(self, scene: Scene | None = None) -> list[View]:
        """The frames of the run (:func:`shadowlab.config.views.run_views`): the camera
        and light keys of this config merged over the scene's default view, sampled
        over the animation; ``animation.frames`` views, in order."""
        from . import views
        return views.run_views(self, scene)

    def where(self, *keys: str) -> str:
        """The label for an error about ``keys``: ``--set`` if an override set one of
        them (or a table holding one), else the config source."""
        from .errors import origin
        return origin(keys, [t.partition("=")[0].strip() for t in self.overrides],
                      self.source)
