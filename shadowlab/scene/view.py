"""Cameras, lights and key-frame animations.

Conventions (docs/conventions.md): view space looks down -Z, clip space is OpenGL's
([-w, w] on every axis), pixel (0, 0) is the top-left pixel and primary rays pass
through pixel centres. Resolutions are (width, height); image arrays are [H, W].
"""

from __future__ import annotations

import dataclasses
import math
from typing import Sequence, Union

import numpy as np

from ..core.numerics import norms3


def _vec3(x, name: str) -> np.ndarray:
    a = np.asarray(x, dtype=np.float64).reshape(-1)
    if a.shape != (3,) or not np.isfinite(a).all():
        raise ValueError(f"{name} must be 3 finite numbers, got {x!r}")
    return a


def _normalize(v: np.ndarray) -> np.ndarray:
    return v / np.linalg.norm(v)


def look_at_basis(eye: np.ndarray, target: np.ndarray, up: np.ndarray
                  ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(right, up, back) orthonormal world vectors of a view from ``eye`` towards
    ``target`` (float64 [3] each); the view looks along -back."""
    back = _normalize(eye - target)
    right = _normalize(np.cross(up, back))
    up = np.cross(back, right)
    return right, up, back


def look_at(eye: np.ndarray, target: np.ndarray, up: np.ndarray) -> np.ndarray:
    """float64 [4, 4]: world -> view (right-handed, looking down -Z)."""
    r, u, b = look_at_basis(eye, target, up)
    m = np.eye(4)
    m[0, :3], m[1, :3], m[2, :3] = r, u, b
    m[:3, 3] = -m[:3, :3] @ eye
    return m


def perspective(fov_y_deg: float, aspect: float, near: float, far: float) -> np.ndarray:
    """float64 [4, 4]: OpenGL perspective projection, view -> clip (fov in degrees,
    aspect = width / height, 0 < near < far in world units)."""
    f = 1.0 / math.tan(math.radians(fov_y_deg) / 2)
    n, fa = near, far
    m = np.zeros((4, 4))
    m[0, 0] = f / aspect
    m[1, 1] = f
    m[2, 2] = (fa + n) / (n - fa)
    m[2, 3] = 2 * fa * n / (n - fa)
    m[3, 2] = -1.0
    return m


@dataclasses.dataclass(frozen=True, eq=False)
class Camera:
    """A look-at pinhole camera.

    Args:
        eye, target, up: world positions / direction (3 floats each).
        fov_y_deg: vertical field of view, degrees, in (0, 180).
        near, far: clip distances along the view axis, world units, 0 < near < far.
        resolution: (width, height) in pixels.
    """

    eye: Sequence[float]
    target: Sequence[float]
    up: Sequence[float] = (0.0, 1.0, 0.0)
    fov_y_deg: float = 60.0
    near: float = 0.1
    far: float = 1000.0
    resolution: tuple[int, int] = (1024, 1024)

    def __post_init__(self):
        eye = _vec3(self.eye, "camera eye")
        target = _vec3(self.target, "camera target")
        up = _vec3(self.up, "camera up")
        object.__setattr__(self, "eye", eye)
        object.__setattr__(self, "target", target)
        object.__setattr__(self, "up", up)
        fwd = target - eye
        if np.linalg.norm(fwd) == 0:
            raise ValueError("camera eye and target coincide")
        if np.linalg.norm(np.cross(fwd, up)) <= 1e-9 * np.linalg.norm(fwd) * np.linalg.norm(up):
            raise ValueError("camera up is parallel to the viewing direction")
        if not 0 < self.fov_y_deg < 180:
            raise ValueError(f"camera fov_y_deg must be in (0, 180), got {self.fov_y_deg}")
        if not 0 < self.near < self.far:
            raise ValueError(f"camera needs 0 < near < far, got near={self.near}, far={self.far}")
        res = tuple(int(r) for r in self.resolution)
        if len(res) != 2 or min(res) < 1:
            raise ValueError(f"camera resolution must be (width, height) >= 1, got {self.resolution}")
        object.__setattr__(self, "resolution", res)

    @property
    def width(self) -> int:
        return self.resolution[0]

    @property
    def height(self) -> int:
        return self.resolution[1]

    @property
    def aspect(self) -> float:
        return self.width / self.height

    def basis(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(right, up, back) orthonormal world vectors; the camera looks along -back."""
        return look_at_basis(self.eye, self.target, self.up)

    def view_matrix(self) -> np.ndarray:
        """float64 [4, 4]: world -> view (right-handed, looking down -Z)."""
        return look_at(self.eye, self.target, self.up)

    def projection_matrix(self) -> np.ndarray:
        """float64 [4, 4]: OpenGL perspective projection, view -> clip."""
        return perspective(self.fov_y_deg, self.aspect, self.near, self.far)

    def view_projection(self) -> np.ndarray:
        """float64 [4, 4]: world -> clip."""
        return self.projection_matrix() @ self.view_matrix()

    def primary_rays(self) -> tuple[np.ndarray, np.ndarray]:
        """Rays through pixel centres.

        Returns:
            origins float64 [H, W, 3] (all the eye), directions float64 [H, W, 3], unit.
        """
        w, h = self.resolution
        t = math.tan(math.radians(self.fov_y_deg) / 2)
        xs = ((np.arange(w) + 0.5) / w * 2 - 1) * t * self.aspect
        ys = (1 - (np.arange(h) + 0.5) / h * 2) * t
        r, u, b = self.basis()
        d = xs[None, :, None] * r + ys[:, None, None] * u - b
        d /= norms3(d, keepdims=True)
        return np.broadcast_to(self.eye, d.shape).copy(), d

    def replace(self, **changes) -> "Camera":
        return dataclasses.replace(self, **changes)


@dataclasses.dataclass(frozen=True, eq=False)
class PointLight:
    """A point light at ``position`` (world units)."""

    position: Sequence[float]

    def __post_init__(self):
        object.__setattr__(self, "position", _vec3(self.position, "light position"))

    @property
    def homogeneous(self) -> np.ndarray:
        """float64 [4]: (x, y, z, 1)."""
        return np.append(self.position, 1.0)

    def to_light(self, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Unit directions [..., 3] from ``points`` [..., 3] to the light, and distances
        [...], float64: d / max(|d|, 1e-300) for d = position - point, with |d| as
        :func:`norms3` sums it. Computed per coordinate column (no [..., 3] temporaries:
        half the time of the row-wise form on a million points, the same bits)."""
        points = np.asarray(points)
        d = [self.position[k] - points[..., k] for k in range(3)]
        dist = np.sqrt(d[0] * d[0] + d[1] * d[1] + d[2] * d[2])
        scale = np.maximum(dist, 1e-300)
        out = np.empty(points.shape, np.float64)
        for k in range(3):
            np.divide(d[k], scale, out=out[..., k])
        return out, dist


@dataclasses.dataclass(frozen=True, eq=False)
class DirectionalLight:
    """A light at infinity; ``direction`` is the way its light travels (into the scene)."""

    direction: Sequence[float]

    def __post_init__(self):
        d = _vec3(self.direction, "light direction")
        if np.linalg.norm(d) == 0:
            raise ValueError("light direction must be non-zero")
        object.__setattr__(self, "direction", _normalize(d))

    @property
    def homogeneous(self) -> np.ndarray:
        """float64 [4]: (-direction, 0), the point at infinity towards the light."""
        return np.append(-self.direction, 0.0)

    def to_light(self, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        d = np.broadcast_to(-self.direction, points.shape)
        return d.copy(), np.full(points.shape[:-1], np.inf)


@dataclasses.dataclass(frozen=True, eq=False)
class SphereLight:
    """An area light: a sphere at ``position`` with ``radius`` (world units), or a sun
    along ``direction`` (the way its light travels) with ``angular_radius_deg``.

    Hard-shadow methods use its centre (a PointLight or DirectionalLight).
    """

    position: Sequence[float] | None = None
    radius: float | None = None
    direction: Sequence[float] | None = None
    angular_radius_deg: float | None = None

    def __post_init__(self):
        sphere = self.position is not None or self.radius is not None
        sun = self.direction is not None or self.angular_radius_deg is not None
        if sphere == sun:
            raise ValueError("SphereLight needs either position and radius (a sphere) or "
                             "direction and angular_radius_deg (a sun), not both")
        if sphere:
            if self.position is None or self.radius is None or not self.radius > 0:
                raise ValueError("a sphere light needs a position and a radius > 0")
            object.__setattr__(self, "position", _vec3(self.position, "light position"))
        else:
            if self.direction is None or self.angular_radius_deg is None \
                    or not 0 < self.angular_radius_deg < 90:
                raise ValueError("a sun needs a direction and 0 < angular_radius_deg < 90")
            d = _vec3(self.direction, "light direction")
            object.__setattr__(self, "direction", _normalize(d))

    @property
    def is_sun(self) -> bool:
        return self.direction is not None

    @property
    def center_light(self) -> Union[PointLight, DirectionalLight]:
        return DirectionalLight(self.direction) if self.is_sun else PointLight(self.position)

    @property
    def homogeneous(self) -> np.ndarray:
        return self.center_light.homogeneous

    def to_light(self, points: np.ndarray):
        return self.center_light.to_light(points)


Light = Union[PointLight, DirectionalLight, SphereLight]


def hard_light(light: Light) -> Union[PointLight, DirectionalLight]:
    """The point or directional light a hard-shadow method uses for ``light``."""
    return light.center_light if isinstance(light, SphereLight) else light


@dataclasses.dataclass(frozen=True, eq=False)
class View:
    """One frame: a camera and a light."""

    camera: Camera
    light: Light


def _interp(keys: np.ndarray, t: np.ndarray) -> np.ndarray:
    """Piecewise-linear interpolation of key rows [k, d] at parameters t in [0, 1]."""
    k = len(keys)
    if k == 1:
        return np.repeat(keys, len(t), axis=0)
    s = t * (k - 1)
    i = np.minimum(np.floor(s).astype(int), k - 2)
    f = (s - i)[:, None]
    return keys[i] * (1 - f) + keys[i + 1] * f


@dataclasses.dataclass(frozen=True, eq=False)
class Animation:
    """Camera and light key-frame paths, sampled to ``frames`` evenly spaced frames.

    Keys are interpolated piecewise-linearly over uniform time (key i at i/(k-1)).

    Args:
        camera: the camera (fov, near, far, resolution, up) used for every frame.
        frames: number of frames to sample (>= 1).
        eye_keys, target_keys: [k, 3] camera positions and targets (default: the
            camera's own, fixed).
        light: the light whose position (or direction) is animated.
        light_keys: [k, 3] light positions (point/sphere) or directions
            (directional/sun); default fixed.
    """

    camera: Camera
    light: Light
    frames: int = 1
    eye_keys: Sequence[Sequence[float]] | None = None
    target_keys: Sequence[Sequence[float]] | None = None
    light_keys: Sequence[Sequence[float]] | None = None

    def __post_init__(self):
        if int(self.frames) < 1:
            raise ValueError(f"animation frames must be >= 1, got {self.frames}")
        for name in ("eye_keys", "target_keys", "light_keys"):
            keys = getattr(self, name)
            if keys is not None:
                arr = np.asarray(keys, dtype=np.float64)
                if arr.ndim != 2 or arr.shape[1] != 3 or len(arr) < 1 or not np.isfinite(arr).all():
                    raise ValueError(f"animation {name} must be a list of [x, y, z] keys")

    def views(self) -> list[View]:
        """The sampled frames, in order."""
        n = int(self.frames)
        t = np.linspace(0.0, 1.0, n) if n > 1 else np.zeros(1)
        cam = self.camera
        eyes = _interp(np.asarray(self.eye_keys if self.eye_keys is not None else [cam.eye], float), t)
        targets = _interp(np.asarray(self.target_keys if self.target_keys is not None
                                     else [cam.target], float), t)
        out = []
        light_vals = None
        if self.light_keys is not None:
            light_vals = _interp(np.asarray(self.light_keys, float), t)
        for i in range(n):
            c = cam.replace(eye=eyes[i], target=targets[i])
            light = self.light
            if light_vals is not None:
                light = _move_light(light, light_vals[i])
            out.append(View(c, light))
        return out


def _move_light(light: Light, value: np.ndarray) -> Light:
    if isinstance(light, PointLight):
        return PointLight(value)
    if isinstance(light, DirectionalLight):
        return DirectionalLight(value)
    if light.is_sun:
        return dataclasses.replace(light, direction=value)
    return dataclasses.replace(light, position=value)
