"""From a validated :class:`~shadowlab.config.schema.RunConfig` to scenes and views.

Light resolution (:func:`run_views`): without ``light.type`` the scene's default light
keeps its type and the given keys change it; with a type, missing keys are taken from
the scene's default light where it has them (a position from a point or sphere light,
a direction from a directional light or sun; a direction from a point light is the one
from the light to the scene's centre, a position from a directional light lies one
scene diagonal up-light of the centre). A sun's ``angular_radius_deg`` defaults to 0.27
(the real sun); a sphere light's ``radius`` has no default unless the scene's default
light is a sphere.
"""

from __future__ import annotations

import math

import numpy as np

from ..scene.mesh import Scene, SceneError
from ..scene.view import (Animation, Camera, DirectionalLight, Light, PointLight, SphereLight,
                          View)
from .errors import ConfigError, show
from .schema import LIGHT_TYPES, SUN_ANGULAR_RADIUS_DEG, LightConfig, RunConfig

_LIGHT_KEYS = tuple(LightConfig.model_fields)


def _given(model) -> dict:
    """The keys of a config table that the config sets (not None)."""
    return {k: v for k, v in model.model_dump().items() if v is not None}


def build_scene(config: RunConfig) -> Scene:
    """Load the mesh file or run the generator (``shadowlab.scene.load_scene``)."""
    from ..scene import load_scene
    try:
        return load_scene(config.scene.source, **config.scene.params)
    except SceneError as exc:
        raise ConfigError(f"{config.where('scene.source', 'scene.params')}: "
                          f"scene.source = {config.scene.source!r}: {exc}") from exc


def default_view(config: RunConfig, scene: Scene | None = None) -> View:
    """The scene's own view: the generator's default view, or :func:`mesh_default_view`."""
    if config.scene.is_procedural:
        from ..scene import procedural
        try:
            return procedural.default_view(config.scene.source, scene, **config.scene.params)
        except SceneError as exc:
            raise ConfigError(f"{config.where('scene.source', 'scene.params')}: "
                              f"scene.source = {config.scene.source!r}: {exc}") from exc
    return mesh_default_view(scene if scene is not None else build_scene(config))


def run_views(config: RunConfig, scene: Scene | None = None) -> list[View]:
    """The frames of the run: the camera and light keys of ``config`` merged over the
    scene's default view, sampled over the animation.

    When the config moves the camera (or the scene is a mesh file) and does not give
    both ``near`` and ``far``, the missing clip distances are fitted to the geometry
    seen over all frames (one range for the whole animation).

    Args:
        scene: the scene built by :func:`build_scene` (built here when omitted).

    Returns:
        ``animation.frames`` views, in order.
    """
    if scene is None:
        scene = build_scene(config)
    base = default_view(config, scene)
    camera = _camera(config, base.camera)
    light = _light(config, base.light, scene)
    anim = config.animation
    try:
        frames = Animation(camera=camera, light=light, frames=anim.frames,
                           eye_keys=anim.eye_keys, target_keys=anim.target_keys,
                           light_keys=anim.light_keys).views()
    except ConfigError:
        raise
    except ValueError as exc:
        keys = [f"animation.{k}" for k in _given(anim)]
        raise ConfigError(f"{config.where(*keys)}: animation: {exc}") from exc
    cam_cfg = config.camera
    placed = ("eye", "target", "up", "fov_y_deg")
    moved = any(getattr(cam_cfg, k) is not None for k in placed) \
        or camera.aspect != base.camera.aspect \
        or anim.eye_keys is not None or anim.target_keys is not None
    if (cam_cfg.near is None or cam_cfg.far is None) and \
            (moved or not config.scene.is_procedural):
        frames = _refit_clip(config, scene, frames)
    return frames


def _camera(config: RunConfig, base: Camera) -> Camera:
    changes = _given(config.camera)
    try:
        return base.replace(**changes)
    except ValueError as exc:
        keys = [f"camera.{k}" for k in changes] or ["camera"]
        raise ConfigError(f"{config.where(*keys)}: camera: {exc} (given: "
                          + (", ".join(f"{k} = {show(v)}" for k, v in changes.items())
                             or "nothing; the scene's default view") + ")") from exc


def _refit_clip(config: RunConfig, scene: Scene, frames: list[View]) -> list[View]:
    """Replace the clip distances the config leaves open by the depth range of the
    geometry inside the view, taken over all frames."""
    from ..scene.procedural import clip_ranges

    lo, hi = math.inf, -math.inf
    for r in clip_ranges(scene, [v.camera for v in frames]):
        if r is not None:                    # None: nothing in view in this frame
            lo, hi = min(lo, r[0]), max(hi, r[1])
    cam_cfg = config.camera
    if not math.isfinite(hi):
        keys = [f"camera.{k}" for k in _given(cam_cfg)] + ["animation.eye_keys",
                                                           "animation.target_keys"]
        raise ConfigError(f"{config.where(*keys)}: camera: no geometry of the scene is "
                          "inside the view in any frame (check camera.eye, camera.target "
                          "and the animation keys)")
    near = cam_cfg.near if cam_cfg.near is not None else lo
    far = cam_cfg.far if cam_cfg.far is not None else hi
    if not near < far:
        given = "camera.near" if cam_cfg.near is not None else "camera.far"
        raise ConfigError(f"{config.where(given)}: camera: {given} = "
                          f"{show(getattr(cam_cfg, given.split('.')[1]))} leaves no "
                          f"depth range: the geometry in view lies between {lo:.6g} and "
                          f"{hi:.6g} (near must be < far)")
    return [View(v.camera.replace(near=near, far=far), v.light) for v in frames]


def _light(config: RunConfig, base: Light, scene: Scene) -> Light:
    cfg = config.light
    base_type = light_type(base)
    ltype = cfg.type or base_type
    where_type = config.where("light.type")
    used = LIGHT_TYPES[ltype]
    for key in _LIGHT_KEYS[1:]:
        if getattr(cfg, key) is not None and key not in used:
            origin = ("" if cfg.type else
                      f" (the scene's default light is a {base_type} light; "
                      "set light.type to change it)")
            raise ConfigError(
                f"{config.where(f'light.{key}', 'light.type')}: light.{key} is not used by a "
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
        keys = [f"light.{k}" for k in _given(cfg)]
        raise ConfigError(f"{config.where(*keys)}: light: {exc}") from exc


def light_type(light: Light) -> str:
    """The config type name of a light object (a key of :data:`LIGHT_TYPES`)."""
    if isinstance(light, PointLight):
        return "point"
    if isinstance(light, DirectionalLight):
        return "directional"
    if isinstance(light, SphereLight):
        return "sun" if light.is_sun else "sphere"
    raise TypeError(f"not a light: {light!r}")


def mesh_default_view(scene: Scene, resolution: tuple[int, int] = (256, 256),
                      fov_y_deg: float = 50.0) -> View:
    """A view for a scene that brings none: the camera looks at the bounding box's
    centre from a diagonal direction (front-right, raised), far enough back that the
    box's bounding sphere fits the vertical field of view; a point light sits above and
    to the side of the box.

    Args:
        scene: any scene.
        resolution: (width, height) of the camera, pixels (the procedural scenes'
            default).
        fov_y_deg: vertical field of view, degrees.

    The near and far planes bracket the bounding sphere; :func:`run_views` refits them
    to the geometry in view.
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
