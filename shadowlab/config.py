"""Run configurations: TOML files -> validated, typed, frozen config objects.

A run configuration says which scene to load, from where it is seen and lit (and how
that moves over an animation), which shadow methods to run with which options, how
the exact reference is computed and where the outputs go. The schema (every table is
optional; the built-in default, ``shadowlab/configs/default.toml``, spells out every
key with a comment)::

    [scene]
    source = "gate"          # procedural generator name, or a mesh file path
    [scene.params]           # generator parameters (procedural sources only)
    seed = 0

    [camera]                 # each key optional; missing keys: the scene's default view
    eye = [x, y, z]          # also target, up, fov_y_deg, near, far
    resolution = [w, h]

    [light]                  # optional; missing keys: the scene's default light
    type = "point"           # point | directional | sphere | sun
    position = [x, y, z]     # point, sphere
    direction = [x, y, z]    # directional, sun: the way the light travels
    radius = 0.5             # sphere (world units)
    angular_radius_deg = 0.27  # sun

    [animation]
    frames = 1
    eye_keys = [[x, y, z], ...]   # also target_keys, light_keys

    [methods]
    names = "all"            # or a list of registered method names (or one name)
    [methods.options.brute_force]
    chunk = 16

    [reference]
    shadow_eps = 1e-5
    soft_rays = 64
    seed = 0

    [output]
    dir = "runs/default"
    figures = true

Path rules: a relative ``scene.source`` resolves against the folder of the config file
that names it; a source given by ``--set`` or by the built-in default resolves against
the current directory. ``output.dir`` is kept as written (relative to the current
directory when the run starts); it defaults to ``runs/<config file stem>``.

Every problem raises :class:`ConfigError`, whose message names where the value came
from (the config file, ``--set`` for override-introduced values, or
``<built-in default>``), the dotted key, what is wrong and what is allowed.
Unknown keys are rejected at every level.

Light resolution (done by :meth:`RunConfig.views`, which knows the scene): without
``light.type`` the scene's default light keeps its type and the given keys change it;
with a type, missing keys are taken from the scene's default light where it has them
(a position from a point or sphere light, a direction from a directional light or sun;
a direction from a point light is the one from the light to the scene's centre, a
position from a directional light lies one scene diagonal up-light of the centre).
A sun's ``angular_radius_deg`` defaults to 0.27 (the real sun); a sphere light's
``radius`` has no default unless the scene's default light is a sphere.

Method options: ``shadow_eps`` (a common option of every method) defaults to
``reference.shadow_eps``, so methods and the Embree reference use the same offset
unless a method's table says otherwise.
"""

from __future__ import annotations

import dataclasses
import difflib
import math
import os
import re
import tomllib
from importlib import resources
from pathlib import Path
from typing import Any, Mapping, Sequence

import numpy as np

from .io import jsonable
from .scene.mesh import SUPPORTED_FORMATS, Scene, SceneError
from .scene.view import (Animation, Camera, DirectionalLight, Light, PointLight, SphereLight,
                         View)

__all__ = [
    "AnimationConfig", "BUILTIN_DEFAULT", "CameraConfig", "ConfigError", "DEFAULT_SOURCE",
    "LIGHT_TYPES", "LightConfig", "MethodsConfig", "OVERRIDE_LABEL", "OutputConfig",
    "ReferenceConfig", "RunConfig", "SUN_ANGULAR_RADIUS_DEG", "SceneConfig", "load_config",
    "mesh_default_view", "parse_override",
]

Vec3 = tuple[float, float, float]

#: ``RunConfig.source`` (and the label in error messages) for the packaged default.
BUILTIN_DEFAULT = "<built-in default>"
#: ``scene.source`` when a config has none (the built-in default's scene).
DEFAULT_SOURCE = "gate"
#: The label in error messages for values introduced by ``--set`` overrides.
OVERRIDE_LABEL = "--set"

#: Light types and the keys each one uses (besides ``type``).
LIGHT_TYPES: dict[str, tuple[str, ...]] = {
    "point": ("position",),
    "directional": ("direction",),
    "sphere": ("position", "radius"),
    "sun": ("direction", "angular_radius_deg"),
}
#: The default angular radius of a sun, degrees (the real sun seen from the earth).
SUN_ANGULAR_RADIUS_DEG = 0.27

_SECTIONS = ("scene", "camera", "light", "animation", "methods", "reference", "output")
_SCENE_KEYS = ("source", "params")
_CAMERA_KEYS = ("eye", "target", "up", "fov_y_deg", "near", "far", "resolution")
_LIGHT_KEYS = ("type", "position", "direction", "radius", "angular_radius_deg")
_ANIMATION_KEYS = ("frames", "eye_keys", "target_keys", "light_keys")
_METHODS_KEYS = ("names", "options")
_REFERENCE_KEYS = ("shadow_eps", "soft_rays", "seed")
_OUTPUT_KEYS = ("dir", "figures")
_KEY_SEGMENT = re.compile(r"^[A-Za-z0-9_-]+$")


class ConfigError(ValueError):
    """An invalid run configuration; the message names the file (or ``--set``), the
    dotted key, what is wrong and the allowed values."""


# --------------------------------------------------------------------------- dataclasses


@dataclasses.dataclass(frozen=True)
class SceneConfig:
    """What to load.

    Attributes:
        source: a procedural generator name, or the resolved (absolute) path of a mesh
            file.
        params: generator parameters with the generator's defaults filled in (empty for
            mesh files).
    """

    source: str
    params: dict[str, Any] = dataclasses.field(default_factory=dict)

    @property
    def is_procedural(self) -> bool:
        """True when ``source`` names a procedural generator."""
        from .scene import procedural
        return self.source in procedural.GENERATORS


@dataclasses.dataclass(frozen=True)
class CameraConfig:
    """Camera keys given by the config; ``None`` = take it from the scene's default view."""

    eye: Vec3 | None = None
    target: Vec3 | None = None
    up: Vec3 | None = None
    fov_y_deg: float | None = None
    near: float | None = None
    far: float | None = None
    resolution: tuple[int, int] | None = None


@dataclasses.dataclass(frozen=True)
class LightConfig:
    """Light keys given by the config; ``None`` = from the scene's default light.

    ``type`` is one of :data:`LIGHT_TYPES` or ``None`` (keep the default light's type).
    """

    type: str | None = None
    position: Vec3 | None = None
    direction: Vec3 | None = None
    radius: float | None = None
    angular_radius_deg: float | None = None


@dataclasses.dataclass(frozen=True)
class AnimationConfig:
    """Key-frame paths sampled to ``frames`` frames (see :class:`shadowlab.Animation`).

    ``light_keys`` are positions for point and sphere lights, directions for
    directional lights and suns.
    """

    frames: int = 1
    eye_keys: tuple[Vec3, ...] | None = None
    target_keys: tuple[Vec3, ...] | None = None
    light_keys: tuple[Vec3, ...] | None = None


@dataclasses.dataclass(frozen=True)
class MethodsConfig:
    """The methods to run, in order, and the full option set of each (defaults filled
    in, validated by :func:`shadowlab.methods.resolve_options`)."""

    names: tuple[str, ...]
    options: dict[str, dict[str, Any]] = dataclasses.field(default_factory=dict)
    all: bool = False   # names came from "all": methods that cannot run on the light are skipped


@dataclasses.dataclass(frozen=True)
class ReferenceConfig:
    """The exact reference: shadow-ray offset (fraction of the scene diagonal), rays per
    pixel and seed of the soft-shadow reference."""

    shadow_eps: float = 1e-5
    soft_rays: int = 64
    seed: int = 0


@dataclasses.dataclass(frozen=True)
class OutputConfig:
    """Where results go, and whether figures are drawn."""

    dir: str = "runs/default"
    figures: bool = True


@dataclasses.dataclass(frozen=True)
class RunConfig:
    """A validated run configuration.

    Attributes:
        source: the config file path as given, or ``"<built-in default>"``.
        overrides: the ``--set`` strings applied, in order.
    """

    scene: SceneConfig
    camera: CameraConfig
    light: LightConfig
    animation: AnimationConfig
    methods: MethodsConfig
    reference: ReferenceConfig
    output: OutputConfig
    source: str
    overrides: tuple[str, ...] = ()

    # -- metadata

    def to_dict(self) -> dict[str, Any]:
        """A plain, JSON-able dict of every setting (tuples become lists)."""
        return jsonable({
            "source": self.source,
            "overrides": list(self.overrides),
            "scene": dataclasses.asdict(self.scene),
            "camera": dataclasses.asdict(self.camera),
            "light": dataclasses.asdict(self.light),
            "animation": dataclasses.asdict(self.animation),
            "methods": {"names": list(self.methods.names), "options": self.methods.options},
            "reference": dataclasses.asdict(self.reference),
            "output": dataclasses.asdict(self.output),
        })

    # -- building

    def build_scene(self) -> Scene:
        """Load the mesh file or run the generator (``shadowlab.scene.load_scene``)."""
        from .scene import load_scene
        try:
            return load_scene(self.scene.source, **self.scene.params)
        except SceneError as exc:
            raise ConfigError(f"{self._where('scene.source', 'scene.params')}: "
                              f"scene.source = {self.scene.source!r}: {exc}") from exc

    def default_view(self, scene: Scene | None = None) -> View:
        """The scene's own view: the generator's default view, or for a mesh file a
        camera framing its bounding box and a light above and to the side
        (:func:`mesh_default_view`)."""
        if self.scene.is_procedural:
            from .scene import procedural
            try:
                return procedural.default_view(self.scene.source, scene, **self.scene.params)
            except SceneError as exc:
                raise ConfigError(f"{self._where('scene.source', 'scene.params')}: "
                                  f"scene.source = {self.scene.source!r}: {exc}") from exc
        return mesh_default_view(scene if scene is not None else self.build_scene())

    def views(self, scene: Scene | None = None) -> list[View]:
        """The frames of the run: the camera and light keys of this config merged over
        the scene's default view, sampled over the animation.

        When the config moves the camera (or the scene is a mesh file) and does not give
        both ``near`` and ``far``, the missing clip distances are fitted to the geometry
        seen over all frames (one range for the whole animation).

        Args:
            scene: the scene built by :meth:`build_scene` (built here when omitted).

        Returns:
            ``animation.frames`` views, in order.
        """
        if scene is None:
            scene = self.build_scene()
        base = self.default_view(scene)
        camera = self._camera(base.camera)
        light = self._light(base.light, scene)
        anim = self.animation
        try:
            frames = Animation(camera=camera, light=light, frames=anim.frames,
                               eye_keys=anim.eye_keys, target_keys=anim.target_keys,
                               light_keys=anim.light_keys).views()
        except ConfigError:
            raise
        except ValueError as exc:
            keys = [f"animation.{k}" for k, v in dataclasses.asdict(anim).items()
                    if v is not None]
            raise ConfigError(f"{self._where(*keys)}: animation: {exc}") from exc
        cam_cfg = self.camera
        placed = ("eye", "target", "up", "fov_y_deg")
        moved = any(getattr(cam_cfg, k) is not None for k in placed) \
            or camera.aspect != base.camera.aspect \
            or anim.eye_keys is not None or anim.target_keys is not None
        if (cam_cfg.near is None or cam_cfg.far is None) and \
                (moved or not self.scene.is_procedural):
            frames = self._refit_clip(scene, frames)
        return frames

    # -- helpers

    def _override_keys(self) -> list[str]:
        keys = []
        for text in self.overrides:
            key, _, _ = text.partition("=")
            keys.append(key.strip())
        return keys

    def _where(self, *keys: str) -> str:
        """The label for an error about ``keys``: ``--set`` if an override set one of
        them (or a table holding one), else the config source."""
        return _origin(keys, self._override_keys(), self.source)

    def _camera(self, base: Camera) -> Camera:
        changes = {k: v for k, v in dataclasses.asdict(self.camera).items() if v is not None}
        try:
            return base.replace(**changes)
        except ValueError as exc:
            keys = [f"camera.{k}" for k in changes] or ["camera"]
            raise ConfigError(f"{self._where(*keys)}: camera: {exc} (given: "
                              + (", ".join(f"{k} = {_show(v)}" for k, v in changes.items())
                                 or "nothing; the scene's default view") + ")") from exc

    def _refit_clip(self, scene: Scene, frames: list[View]) -> list[View]:
        """Replace the clip distances the config leaves open by the depth range of the
        geometry inside the view, taken over all frames."""
        lo, hi = math.inf, -math.inf
        seen: set[tuple] = set()
        for view in frames:
            cam = view.camera
            key = (tuple(cam.eye), tuple(cam.target))
            if key in seen:
                continue
            seen.add(key)
            try:
                near, far = _fit_clip(scene, cam)
            except SceneError:
                continue  # nothing in view in this frame
            lo, hi = min(lo, near), max(hi, far)
        if not math.isfinite(hi):
            keys = [f"camera.{k}" for k, v in dataclasses.asdict(self.camera).items()
                    if v is not None] + ["animation.eye_keys", "animation.target_keys"]
            raise ConfigError(f"{self._where(*keys)}: camera: no geometry of the scene is "
                              "inside the view in any frame (check camera.eye, camera.target "
                              "and the animation keys)")
        near = self.camera.near if self.camera.near is not None else lo
        far = self.camera.far if self.camera.far is not None else hi
        if not near < far:
            given = "camera.near" if self.camera.near is not None else "camera.far"
            raise ConfigError(f"{self._where(given)}: camera: {given} = "
                              f"{_show(getattr(self.camera, given.split('.')[1]))} leaves no "
                              f"depth range: the geometry in view lies between {lo:.6g} and "
                              f"{hi:.6g} (near must be < far)")
        return [View(v.camera.replace(near=near, far=far), v.light) for v in frames]

    def _light(self, base: Light, scene: Scene) -> Light:
        cfg = self.light
        base_type = _light_type(base)
        ltype = cfg.type or base_type
        where_type = self._where("light.type")
        used = LIGHT_TYPES[ltype]
        for key in _LIGHT_KEYS[1:]:
            if getattr(cfg, key) is not None and key not in used:
                origin = ("" if cfg.type else
                          f" (the scene's default light is a {base_type} light; "
                          "set light.type to change it)")
                raise ConfigError(
                    f"{self._where(f'light.{key}', 'light.type')}: light.{key} is not used by a "
                    f"{ltype} light{origin}; allowed keys for a {ltype} light: "
                    + ", ".join(("type",) + used))
        lo, hi = scene.bounds
        centre = (lo + hi) / 2
        diag = max(scene.diagonal, 1e-9)

        def position() -> np.ndarray:
            if cfg.position is not None:
                return np.asarray(cfg.position, float)
            if base_type in ("point", "sphere"):
                return np.asarray(base.position, float)
            return centre - np.asarray(base.direction, float) * diag

        def direction() -> np.ndarray:
            if cfg.direction is not None:
                return np.asarray(cfg.direction, float)
            if base_type in ("directional", "sun"):
                return np.asarray(base.direction, float)
            d = centre - np.asarray(base.position, float)
            return d if np.linalg.norm(d) > 0 else np.array([0.0, -1.0, 0.0])

        try:
            if ltype == "point":
                return PointLight(position())
            if ltype == "directional":
                return DirectionalLight(direction())
            if ltype == "sphere":
                radius = cfg.radius
                if radius is None and base_type == "sphere":
                    radius = base.radius
                if radius is None:
                    raise ConfigError(
                        f"{where_type}: light.type = 'sphere' needs light.radius (a number "
                        f"> 0, world units); the scene's default light is a {base_type} light "
                        "and has no radius")
                return SphereLight(position=position(), radius=float(radius))
            angular = cfg.angular_radius_deg
            if angular is None:
                angular = base.angular_radius_deg if base_type == "sun" else SUN_ANGULAR_RADIUS_DEG
            return SphereLight(direction=direction(), angular_radius_deg=float(angular))
        except ConfigError:
            raise
        except ValueError as exc:
            keys = [f"light.{k}" for k, v in dataclasses.asdict(cfg).items() if v is not None]
            raise ConfigError(f"{self._where(*keys)}: light: {exc}") from exc


def _light_type(light: Light) -> str:
    """The config type name of a light object."""
    if isinstance(light, PointLight):
        return "point"
    if isinstance(light, DirectionalLight):
        return "directional"
    if isinstance(light, SphereLight):
        return "sun" if light.is_sun else "sphere"
    raise TypeError(f"not a light: {light!r}")


def _fit_clip(scene: Scene, camera: Camera) -> tuple[float, float]:
    """(near, far) bracketing the geometry inside ``camera``'s view frustum
    (:func:`shadowlab.scene.procedural.fit_clip_range`).

    Raises:
        SceneError: nothing of the scene is in view.
    """
    from .scene.procedural import fit_clip_range
    return fit_clip_range(scene, camera.eye, camera.target, camera.up, camera.fov_y_deg,
                          camera.aspect)


def mesh_default_view(scene: Scene, resolution: tuple[int, int] = (256, 256),
                      fov_y_deg: float = 50.0) -> View:
    """A view for a scene that brings none: the camera looks at the bounding box's
    centre from a diagonal direction (front-right, raised), far enough back that the
    box's bounding sphere fits the vertical field of view; a point light sits above and
    to the side of the box.

    Args:
        scene: any scene.
        resolution: (width, height) of the camera (the procedural scenes' default).
        fov_y_deg: vertical field of view, degrees.

    The near and far planes bracket the bounding sphere; :meth:`RunConfig.views`
    refits them to the geometry in view.
    """
    lo, hi = scene.bounds
    centre = (lo + hi) / 2
    radius = max(float(np.linalg.norm(hi - lo)) / 2, 1e-6)
    view_dir = np.array([1.0, 0.7, 1.6])
    view_dir /= np.linalg.norm(view_dir)
    dist = 1.1 * radius / math.sin(math.radians(fov_y_deg) / 2)
    near = max(dist - radius, 0.0) * 0.5 + 1e-3 * radius
    far = (dist + radius) * 1.5
    camera = Camera(eye=centre + view_dir * dist, target=centre, up=(0.0, 1.0, 0.0),
                    fov_y_deg=fov_y_deg, near=near, far=far, resolution=resolution)
    light_pos = centre + radius * np.array([-1.2, 2.0, 0.8])
    return View(camera, PointLight(light_pos))


# --------------------------------------------------------------------------- loading


def load_config(path: str | os.PathLike | None = None,
                overrides: Sequence[str] = ()) -> RunConfig:
    """Read, override and validate a run configuration.

    Args:
        path: a TOML file; ``None`` reads the built-in default
            (``shadowlab/configs/default.toml``).
        overrides: ``key=value`` strings (the CLI's ``--set``), applied in order; the
            value is parsed as a TOML value (``[256, 256]``, ``3``, ``"x"``, ``true``),
            and taken as a bare string if it is not one.

    Returns:
        The validated :class:`RunConfig`.

    Raises:
        ConfigError: a missing or unreadable file, a TOML syntax error, a malformed
            override, an unknown key, or a value of the wrong type or range.
    """
    if path is None:
        label = BUILTIN_DEFAULT
        base_dir = Path.cwd()
        text = resources.files("shadowlab").joinpath("configs", "default.toml").read_text("utf-8")
        data = _parse_toml(text, label)
        default_out = "runs/default"
    else:
        p = Path(path)
        label = str(path)
        if not p.exists():
            raise ConfigError(f"{label}: no such config file")
        if p.is_dir():
            raise ConfigError(f"{label}: is a directory, not a config file")
        try:
            text = p.read_text(encoding="utf-8")
        except (OSError, UnicodeDecodeError) as exc:
            raise ConfigError(f"{label}: cannot be read: {exc}") from exc
        data = _parse_toml(text, label)
        base_dir = p.resolve().parent
        default_out = f"runs/{p.stem}"

    if isinstance(overrides, str):          # one override passed on its own
        overrides = (overrides,)
    override_keys = []
    for text in overrides:
        key, value = parse_override(text)
        _apply_override(data, key, value, text)
        override_keys.append(".".join(key))

    ctx = _Context(label, base_dir, override_keys)
    _check_keys(ctx, data, "", _SECTIONS)
    scene = _read_scene(ctx, _table(ctx, data, "scene"))
    camera = _read_camera(ctx, _table(ctx, data, "camera"))
    light = _read_light(ctx, _table(ctx, data, "light"))
    animation = _read_animation(ctx, _table(ctx, data, "animation"), light)
    reference = _read_reference(ctx, _table(ctx, data, "reference"))
    methods = _read_methods(ctx, _table(ctx, data, "methods"), reference)
    output = _read_output(ctx, _table(ctx, data, "output"), default_out)
    return RunConfig(scene=scene, camera=camera, light=light, animation=animation,
                     methods=methods, reference=reference, output=output, source=label,
                     overrides=tuple(overrides))


def _parse_toml(text: str, label: str) -> dict:
    try:
        return tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        message = str(exc)
        if "(at end of document)" in message:   # tomllib gives no line number there
            message = message.replace("(at end of document)",
                                      f"(at end of document, line {text.count(chr(10)) + 1})")
        raise ConfigError(f"{label}: invalid TOML: {message}") from exc


def parse_override(text: str) -> tuple[tuple[str, ...], Any]:
    """Split a ``key=value`` override into its dotted key path and its value.

    The value is parsed as a TOML value; if that fails it is kept as a bare string
    (so ``scene.source=fuzzy`` works without quotes).

    Raises:
        ConfigError: no ``=``, an empty key or key segment, or an empty value.
    """
    example = "expected key=value, e.g. camera.resolution=[256,256]"
    if not isinstance(text, str) or "=" not in text:
        raise ConfigError(f"{OVERRIDE_LABEL}: malformed override {text!r}: {example}")
    raw_key, _, raw_value = text.partition("=")
    key = tuple(part.strip() for part in raw_key.strip().split("."))
    if not raw_key.strip() or not all(_KEY_SEGMENT.match(part) for part in key):
        raise ConfigError(f"{OVERRIDE_LABEL}: malformed override {text!r}: the key must be "
                          f"dotted names such as scene.params.seed; {example}")
    raw_value = raw_value.strip()
    if not raw_value:
        raise ConfigError(f"{OVERRIDE_LABEL}: malformed override {text!r}: empty value; "
                          f"{example}")
    try:
        value = tomllib.loads(f"v = {raw_value}")["v"]
    except tomllib.TOMLDecodeError:
        value = raw_value
    return key, value


def _apply_override(data: dict, key: tuple[str, ...], value: Any, text: str) -> None:
    """Set ``data[k0][k1]...[kn] = value``, creating tables on the way."""
    table = data
    for i, part in enumerate(key[:-1]):
        nxt = table.setdefault(part, {})
        if not isinstance(nxt, dict):
            raise ConfigError(f"{OVERRIDE_LABEL}: override {text!r}: "
                              f"{'.'.join(key[:i + 1])} is a value, not a table")
        table = nxt
    table[key[-1]] = value


# --------------------------------------------------------------------------- validation


def _origin(keys: Sequence[str], override_keys: Sequence[str], label: str) -> str:
    """``--set`` when an override set one of ``keys`` exactly or a table holding it,
    else ``label`` (the config file or the built-in default)."""
    for key in keys:
        for ok in override_keys:
            if key == ok or key.startswith(ok + "."):
                return OVERRIDE_LABEL
    return label


@dataclasses.dataclass
class _Context:
    """Where values come from: the config label, its folder, the overridden keys."""

    label: str
    base_dir: Path
    override_keys: list[str]

    def where(self, *keys: str) -> str:
        """The label for a value at one of the dotted ``keys`` (see :func:`_origin`)."""
        return _origin(keys, self.override_keys, self.label)

    def error(self, key: str, message: str, *also: str) -> ConfigError:
        """A ConfigError ``<where>: <key> <message>``."""
        return ConfigError(f"{self.where(key, *also)}: {key} {message}")


def _show(value: Any) -> str:
    """A value as the user wrote it (TOML-ish): lists in brackets, strings quoted."""
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, (list, tuple)):
        return "[" + ", ".join(_show(v) for v in value) + "]"
    if isinstance(value, dict):
        return "{" + ", ".join(f"{k} = {_show(v)}" for k, v in value.items()) + "}"
    return repr(value)


def _type_name(value: Any) -> str:
    if isinstance(value, bool):
        return "a boolean"
    if isinstance(value, int):
        return "an integer"
    if isinstance(value, float):
        return "a float"
    if isinstance(value, str):
        return "a string"
    if isinstance(value, (list, tuple)):
        return "an array"
    if isinstance(value, dict):
        return "a table"
    return type(value).__name__


def _check_keys(ctx: _Context, table: Mapping, prefix: str, allowed: Sequence[str]) -> None:
    for key in table:
        if key not in allowed:
            full = f"{prefix}.{key}" if prefix else key
            close = difflib.get_close_matches(key, allowed, n=1)
            hint = f" (did you mean {close[0]!r}?)" if close else ""
            scope = f" in [{prefix}]" if prefix else ""
            raise ConfigError(f"{ctx.where(full)}: unknown key {full!r}{hint}; "
                              f"allowed keys{scope}: {', '.join(allowed)}")


def _table(ctx: _Context, parent: Mapping, key: str, full: str | None = None) -> dict:
    """``parent[key]`` (``{}`` when missing), which must be a table; ``full`` is its
    dotted key (default ``key``)."""
    value = parent.get(key, {})
    if not isinstance(value, dict):
        raise ctx.error(full or key, f"must be a table, got {_type_name(value)} {_show(value)}")
    return value


def _is_number(v: Any) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool)


def _float(ctx: _Context, key: str, value: Any, *, minimum: float | None = None,
           exclusive_min: bool = False, maximum: float | None = None,
           exclusive_max: bool = False, unit: str = "") -> float:
    """A finite number within the given bounds, as float."""
    parts = []
    if minimum is not None:
        parts.append(f"{'>' if exclusive_min else '>='} {minimum:g}")
    if maximum is not None:
        parts.append(f"{'<' if exclusive_max else '<='} {maximum:g}")
    wanted = "a finite number" + (" " + " and ".join(parts) if parts else "") + unit
    if not _is_number(value) or not math.isfinite(value):
        raise ctx.error(key, f"must be {wanted}, got {_show(value)}")
    v = float(value)
    if minimum is not None and (v < minimum or (exclusive_min and v == minimum)):
        raise ctx.error(key, f"must be {wanted}, got {_show(value)}")
    if maximum is not None and (v > maximum or (exclusive_max and v == maximum)):
        raise ctx.error(key, f"must be {wanted}, got {_show(value)}")
    return v


def _int(ctx: _Context, key: str, value: Any, *, minimum: int | None = None) -> int:
    wanted = "an integer" + (f" >= {minimum}" if minimum is not None else "")
    if not isinstance(value, int) or isinstance(value, bool) or \
            (minimum is not None and value < minimum):
        raise ctx.error(key, f"must be {wanted}, got {_show(value)}")
    return int(value)


def _bool(ctx: _Context, key: str, value: Any) -> bool:
    if not isinstance(value, bool):
        raise ctx.error(key, f"must be true or false, got {_show(value)}")
    return value


def _vec3(ctx: _Context, key: str, value: Any, *, nonzero: bool = False) -> Vec3:
    what = "a non-zero vector of 3 finite numbers" if nonzero else "3 finite numbers"
    if not isinstance(value, (list, tuple)) or len(value) != 3 or \
            not all(_is_number(v) and math.isfinite(v) for v in value):
        raise ctx.error(key, f"must be {what} [x, y, z], got {_show(value)}")
    vec = tuple(float(v) for v in value)
    if nonzero and not any(vec):
        raise ctx.error(key, f"must be {what} [x, y, z], got {_show(value)}")
    return vec


def _keys(ctx: _Context, key: str, value: Any, *, nonzero: bool = False) -> tuple[Vec3, ...]:
    if not isinstance(value, (list, tuple)) or not value:
        raise ctx.error(key, f"must be a non-empty list of [x, y, z] keys, got {_show(value)}")
    return tuple(_vec3(ctx, f"{key}[{i}]", v, nonzero=nonzero) for i, v in enumerate(value))


def _read_scene(ctx: _Context, table: dict) -> SceneConfig:
    from .scene import procedural

    _check_keys(ctx, table, "scene", _SCENE_KEYS)
    generators = list(procedural.GENERATORS)
    source = table.get("source", DEFAULT_SOURCE)
    if not isinstance(source, str) or not source.strip():
        raise ctx.error("scene.source", "must be a procedural generator name "
                        f"({', '.join(generators)}) or a mesh file path, got {_show(source)}")
    params = _table(ctx, table, "params", "scene.params")
    if source in procedural.GENERATORS:
        return SceneConfig(source, _read_params(ctx, source, params))

    # A mesh file: resolve relative paths against the config folder (cwd for --set).
    base = Path.cwd() if ctx.where("scene.source") == OVERRIDE_LABEL else ctx.base_dir
    path = Path(source).expanduser()
    resolved = path if path.is_absolute() else (base / path)
    resolved = Path(os.path.normpath(resolved))
    if not resolved.is_file():
        close = difflib.get_close_matches(source, generators, n=1)
        hint = f" (did you mean {close[0]!r}?)" if close else ""
        state = "is a directory" if resolved.is_dir() else "does not exist"
        raise ctx.error("scene.source", f"= {source!r}{hint} is neither a procedural generator "
                        f"nor an existing mesh file ({resolved} {state}); generators: "
                        f"{', '.join(generators)}; mesh formats: "
                        + ", ".join("." + e for e in SUPPORTED_FORMATS))
    ext = resolved.suffix.lower().lstrip(".")
    if ext not in SUPPORTED_FORMATS:
        raise ctx.error("scene.source", f"= {source!r}: unknown mesh format '.{ext}'; allowed: "
                        + ", ".join("." + e for e in SUPPORTED_FORMATS))
    if params:
        raise ctx.error("scene.params", f"is only for procedural sources "
                        f"({', '.join(generators)}); scene.source = {source!r} is a mesh file",
                        "scene.source")
    return SceneConfig(str(resolved), {})


def _read_params(ctx: _Context, name: str, params: dict) -> dict[str, Any]:
    """Validate generator parameters: keys against the generator's defaults, values by
    the generator's own checks (type and range); returns every parameter, defaults
    filled in."""
    from .scene import procedural

    defaults = dict(procedural.GENERATORS[name].defaults)
    unknown = [k for k in params if k not in defaults]
    if unknown:
        key = f"scene.params.{unknown[0]}"
        close = difflib.get_close_matches(unknown[0], list(defaults), n=1)
        hint = f" (did you mean {close[0]!r}?)" if close else ""
        raise ConfigError(f"{ctx.where(key)}: unknown key {key!r}{hint} for generator "
                          f"{name!r}; allowed keys in [scene.params]: "
                          + ", ".join(f"{k} (default {_show(jsonable(v))})"
                                      for k, v in defaults.items()))
    out = dict(defaults)
    for k, value in params.items():
        key = f"scene.params.{k}"
        try:
            out[k] = procedural.resolve_params(name, **{k: value})[k]
        except SceneError as exc:
            raise ConfigError(f"{ctx.where(key)}: {key} = {_show(value)} is not allowed: "
                              f"{exc}") from exc
    return out


def _read_camera(ctx: _Context, table: dict) -> CameraConfig:
    _check_keys(ctx, table, "camera", _CAMERA_KEYS)
    kw: dict[str, Any] = {}
    for name in ("eye", "target", "up"):
        if name in table:
            kw[name] = _vec3(ctx, f"camera.{name}", table[name], nonzero=(name == "up"))
    if "fov_y_deg" in table:
        kw["fov_y_deg"] = _float(ctx, "camera.fov_y_deg", table["fov_y_deg"], minimum=0,
                                 exclusive_min=True, maximum=180, exclusive_max=True,
                                 unit=" (degrees)")
    if "near" in table:
        kw["near"] = _float(ctx, "camera.near", table["near"], minimum=0, exclusive_min=True)
    if "far" in table:
        kw["far"] = _float(ctx, "camera.far", table["far"], minimum=0, exclusive_min=True)
    if "near" in kw and "far" in kw and not kw["near"] < kw["far"]:
        raise ctx.error("camera.far", f"must be greater than camera.near, got near = "
                        f"{_show(kw['near'])}, far = {_show(kw['far'])}", "camera.near")
    if "eye" in kw and "target" in kw and kw["eye"] == kw["target"]:
        raise ctx.error("camera.target", f"must differ from camera.eye, both are "
                        f"{_show(kw['eye'])}", "camera.eye")
    if "resolution" in table:
        res = table["resolution"]
        if not isinstance(res, (list, tuple)) or len(res) != 2 or not all(
                isinstance(r, int) and not isinstance(r, bool) and r >= 1 for r in res):
            raise ctx.error("camera.resolution", "must be two positive integers "
                            f"[width, height], got {_show(res)}")
        kw["resolution"] = (int(res[0]), int(res[1]))
    return CameraConfig(**kw)


def _read_light(ctx: _Context, table: dict) -> LightConfig:
    _check_keys(ctx, table, "light", _LIGHT_KEYS)
    ltype = table.get("type")
    if ltype is not None and ltype not in LIGHT_TYPES:
        raise ctx.error("light.type", f"= {_show(ltype)} is not allowed; allowed: "
                        + ", ".join(LIGHT_TYPES))
    if ltype is not None:
        used = LIGHT_TYPES[ltype]
        for key in _LIGHT_KEYS[1:]:
            if key in table and key not in used:
                hint = ""
                if ctx.where(f"light.{key}", "light.type") == OVERRIDE_LABEL:
                    hint = ("; to replace the whole light, override the table, e.g. "
                            "--set 'light={type=\"sun\", direction=[0, -1, 0]}'")
                raise ctx.error(f"light.{key}", f"is not used by a {ltype} light "
                                f"(light.type = {ltype!r}); allowed keys for a {ltype} light: "
                                + ", ".join(("type",) + used) + hint, "light.type")
    kw: dict[str, Any] = {"type": ltype}
    if "position" in table:
        kw["position"] = _vec3(ctx, "light.position", table["position"])
    if "direction" in table:
        kw["direction"] = _vec3(ctx, "light.direction", table["direction"], nonzero=True)
    if "radius" in table:
        kw["radius"] = _float(ctx, "light.radius", table["radius"], minimum=0,
                              exclusive_min=True, unit=" (world units)")
    if "angular_radius_deg" in table:
        kw["angular_radius_deg"] = _float(ctx, "light.angular_radius_deg",
                                          table["angular_radius_deg"], minimum=0,
                                          exclusive_min=True, maximum=90, exclusive_max=True,
                                          unit=" (degrees)")
    return LightConfig(**kw)


def _read_animation(ctx: _Context, table: dict, light: LightConfig) -> AnimationConfig:
    _check_keys(ctx, table, "animation", _ANIMATION_KEYS)
    frames = _int(ctx, "animation.frames", table.get("frames", 1), minimum=1)
    kw: dict[str, Any] = {"frames": frames}
    for name in ("eye_keys", "target_keys"):
        if name in table:
            kw[name] = _keys(ctx, f"animation.{name}", table[name])
    if "light_keys" in table:
        directional = light.type in ("directional", "sun")
        kw["light_keys"] = _keys(ctx, "animation.light_keys", table["light_keys"],
                                 nonzero=directional)
    return AnimationConfig(**kw)


def _read_methods(ctx: _Context, table: dict, reference: ReferenceConfig) -> MethodsConfig:
    from . import methods as registry

    _check_keys(ctx, table, "methods", _METHODS_KEYS)
    known = registry.names()
    raw = table.get("names", "all")
    every = raw == "all"
    if every:
        names = tuple(known)
    else:
        listed = [raw] if isinstance(raw, str) else raw
        if not isinstance(listed, (list, tuple)) or not listed or \
                not all(isinstance(n, str) for n in listed):
            raise ctx.error("methods.names", f'must be "all" or a non-empty list of method '
                            f"names; allowed: {', '.join(known)}; got {_show(raw)}")
        for n in listed:
            if n not in known:
                close = difflib.get_close_matches(n, known, n=1)
                hint = f" (did you mean {close[0]!r}?)" if close else ""
                raise ctx.error("methods.names", f"contains unknown method {n!r}{hint}; "
                                f"allowed: {', '.join(known)} (or \"all\")")
        dupes = sorted({n for n in listed if listed.count(n) > 1})
        if dupes:
            raise ctx.error("methods.names", f"lists {', '.join(map(repr, dupes))} more than "
                            "once")
        names = tuple(listed)

    options_table = _table(ctx, table, "options", "methods.options")
    given: dict[str, dict] = {}
    for method, opts in options_table.items():
        key = f"methods.options.{method}"
        if method not in known:
            close = difflib.get_close_matches(method, known, n=1)
            hint = f" (did you mean {close[0]!r}?)" if close else ""
            raise ConfigError(f"{ctx.where(key)}: unknown method {key!r}{hint}; allowed "
                              f"methods: {', '.join(known)}")
        if not isinstance(opts, dict):
            raise ctx.error(key, f"must be a table of options, got {_show(opts)}")
        for opt, value in opts.items():
            try:
                registry.resolve_options(method, {opt: value})
            except registry.MethodError as exc:
                raise ConfigError(f"{ctx.where(f'{key}.{opt}')}: {key}.{opt}: {exc}") from exc
        given[method] = dict(opts)

    options: dict[str, dict[str, Any]] = {}
    for method in names:
        opts = dict(given.get(method, {}))
        if "shadow_eps" in registry.get(method).options and "shadow_eps" not in opts:
            opts["shadow_eps"] = reference.shadow_eps
        try:
            options[method] = registry.resolve_options(method, opts)
        except registry.MethodError as exc:  # pragma: no cover - checked per key above
            raise ConfigError(f"{ctx.where(f'methods.options.{method}')}: "
                              f"methods.options.{method}: {exc}") from exc
    return MethodsConfig(names=names, options=options, all=every)


def _read_reference(ctx: _Context, table: dict) -> ReferenceConfig:
    _check_keys(ctx, table, "reference", _REFERENCE_KEYS)
    d = ReferenceConfig()
    return ReferenceConfig(
        shadow_eps=_float(ctx, "reference.shadow_eps", table.get("shadow_eps", d.shadow_eps),
                          minimum=0, unit=" (fraction of the scene diagonal)"),
        soft_rays=_int(ctx, "reference.soft_rays", table.get("soft_rays", d.soft_rays),
                       minimum=1),
        seed=_int(ctx, "reference.seed", table.get("seed", d.seed), minimum=0),
    )


def _read_output(ctx: _Context, table: dict, default_dir: str) -> OutputConfig:
    _check_keys(ctx, table, "output", _OUTPUT_KEYS)
    out_dir = table.get("dir", default_dir)
    if not isinstance(out_dir, str) or not out_dir.strip():
        raise ctx.error("output.dir", f"must be a non-empty path string, got {_show(out_dir)}")
    figures = _bool(ctx, "output.figures", table.get("figures", True))
    return OutputConfig(dir=out_dir, figures=figures)
