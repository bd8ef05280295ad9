"""Helpers every method shares: the frame origin, precision, view samples and their
padding, the bias.

The frame (the precision model; docs/exactness.md, "Precision model")
----------------------------------------------------------------------
float32 loses what it cannot represent: at 1e5 world units its spacing is 8 mm, more
than a typical shadow offset. So no method sees world coordinates. Each frame gets an
origin :math:`o` (float64 [3]), and every coordinate a method, a kernel or the Embree
reference works with is ``world - o``, subtracted in float64 *before* any cast to
float32:

- :func:`frame_origin` picks ``o``: a point (the camera eye by default, the light for
  a light-centred method) snapped to a grid of spacing :func:`frame_cell` (the power of
  two at or above 4 x the scene's diagonal). Snapping keeps the origin fixed while the
  point moves within a cell (an animation reuses one local scene and one Embree BVH),
  leaves scenes near the world origin at ``o = 0`` (their numbers are unchanged), and
  makes ``v - o`` exact in float64 for vertices within a factor of two of ``o``. Local
  coordinates stay within about a cell of zero, so their float32 spacing is that of the
  scene's size, not of its distance from the world origin.
- :func:`localize` returns the scene, G-buffer and light in that frame: a translated
  :class:`Scene` (cached per scene and origin, so per-scene caches keep working), a
  :class:`GBuffer` whose positions and camera are local (its ``origin`` is 0), and the
  translated light. Every shared vertex gets the same float64 subtraction, so
  triangles that share an edge still share it bit for bit after the float32 cast.
- ``shadowlab.methods.compute_shadows`` and ``run_kernel`` call :func:`localize` once
  per call, so every registered method and kernel, present and future, runs in the
  local frame without code of its own; ``register(..., frame="light")`` makes a
  method light-centred. Lengths (diagonal, ``eps``) do not change under translation.
"""

from __future__ import annotations

import contextlib
import dataclasses
import math
import weakref

import jax
import numpy as np

from .capacity import bucket, pad
from .sorting import stable_argsort
from ..reference.raycast import GBuffer, facing_samples, shadow_epsilon
from ..scene.caches import per_scene_cache
from ..scene.mesh import Scene
from ..scene.view import Camera, DirectionalLight, Light, PointLight, SphereLight, hard_light

FRAME_CENTRES = ("camera", "light")


def frame_cell(scene: Scene) -> float:
    """The snapping grid of frame origins: the power of two at or above 4 x the scene's
    bounding-box diagonal (world units)."""
    return float(2.0 ** math.ceil(math.log2(max(4.0 * scene.diagonal, 1e-30))))


_WORLD = [False]


@contextlib.contextmanager
def world_coordinates():
    """For studies only: inside this block every frame origin is the world origin, as
    before frame-local coordinates existed (float32 work in world coordinates; the
    G-buffer positions are still float64 ray/plane crossings). Not thread-safe."""
    old = _WORLD[0]
    _WORLD[0] = True
    try:
        yield
    finally:
        _WORLD[0] = old


def frame_origin(scene: Scene, point) -> np.ndarray:
    """float64 [3]: ``point`` [3] (world) snapped to the grid of :func:`frame_cell`,
    so ``|point - origin| <= cell / 2`` per axis, and ``origin = 0`` whenever
    ``|point| < cell / 2`` per axis (always 0 inside :func:`world_coordinates`)."""
    if _WORLD[0]:
        return np.zeros(3)
    cell = frame_cell(scene)
    return np.round(np.asarray(point, np.float64) / cell) * cell


def centre_point(camera: Camera, light: Light, centre: str = "camera") -> np.ndarray:
    """float64 [3]: the point a frame is centred on: the camera eye, or for
    ``centre="light"`` a point light's position (the eye for a light at infinity)."""
    if centre not in FRAME_CENTRES:
        raise ValueError(f"frame centre must be one of {FRAME_CENTRES}, got {centre!r}")
    hl = hard_light(light)
    if centre == "light" and isinstance(hl, PointLight):
        return np.asarray(hl.position, np.float64)
    return np.asarray(camera.eye, np.float64)


_LOCAL_SCENES: "weakref.WeakKeyDictionary[Scene, dict]" = per_scene_cache()
_MAX_ORIGINS = 4        # local copies kept per scene (oldest dropped first)


def local_scene(scene: Scene, origin: np.ndarray) -> Scene:
    """``scene`` translated by ``-origin`` (float64 subtraction, per vertex, so shared
    vertices stay shared), cached per scene and origin; ``scene`` itself for 0."""
    origin = np.asarray(origin, np.float64)
    if not np.any(origin):
        return scene
    key = tuple(origin.tolist())
    cache = _LOCAL_SCENES.setdefault(scene, {})
    out = cache.get(key)
    if out is None:
        out = Scene(scene.vertices - origin, scene.faces, scene.object_id,
                    scene.object_names, scene.name,
                    extent=None if scene.extent is None else scene.extent - origin)
        if len(cache) >= _MAX_ORIGINS:
            cache.pop(next(iter(cache)))
        cache[key] = out
    return out


def local_light(light: Light, origin: np.ndarray) -> Light:
    """``light`` translated by ``-origin`` (directions and sizes unchanged)."""
    origin = np.asarray(origin, np.float64)
    if not np.any(origin) or isinstance(light, DirectionalLight):
        return light
    if isinstance(light, PointLight):
        return PointLight(light.position - origin)
    if isinstance(light, SphereLight) and light.position is not None:
        return dataclasses.replace(light, position=np.asarray(light.position) - origin)
    return light


def local_camera(camera: Camera, origin: np.ndarray) -> Camera:
    """``camera`` with eye and target translated by ``-origin``."""
    origin = np.asarray(origin, np.float64)
    if not np.any(origin):
        return camera
    return dataclasses.replace(camera, eye=camera.eye - origin, target=camera.target - origin)


def local_gbuffer(gbuf: GBuffer, origin: np.ndarray) -> GBuffer:
    """``gbuf`` with positions (valid pixels; 0 elsewhere) and camera relative to
    ``origin``; the result's ``origin`` is 0 (it is its own frame)."""
    origin = np.asarray(origin, np.float64)
    if not np.any(origin):
        return gbuf
    pos = np.where(gbuf.valid[..., None], gbuf.position - origin, 0.0)
    return dataclasses.replace(gbuf, position=pos, camera=local_camera(gbuf.camera, origin),
                               origin=np.zeros(3))


@dataclasses.dataclass(frozen=True, eq=False)
class Frame:
    """A frame's origin and the inputs translated into it.

    Attributes:
        origin: float64 [3], world position of the frame's origin.
        scene, gbuf, light: the inputs relative to ``origin`` (world units).
    """

    origin: np.ndarray
    scene: Scene
    gbuf: GBuffer
    light: Light


def localize(scene: Scene, gbuf: GBuffer, light: Light, centre: str = "camera") -> Frame:
    """The scene, G-buffer and light relative to the frame origin :func:`frame_origin`
    of the camera eye (``centre="camera"``) or of the light (``"light"``).

    ``gbuf`` may already be local (its ``origin`` non-zero means its positions are
    world coordinates, as :func:`~shadowlab.reference.raycast.render_gbuffer` makes
    them); the positions are translated in float64. Localizing local inputs again is a
    no-op (their origin snaps to 0).
    """
    origin = frame_origin(scene, centre_point(gbuf.camera, light, centre))
    return Frame(origin, local_scene(scene, origin), local_gbuffer(gbuf, origin),
                 local_light(light, origin))


@contextlib.contextmanager
def precision_mode(precision: str):
    """Run JAX in float64 mode for ``precision="float64"``, else leave it as it is."""
    if precision == "float64":
        with jax.enable_x64(True):
            yield np.float64
    else:
        yield np.float32


@dataclasses.dataclass(frozen=True, eq=False)
class Samples:
    """The view samples a hard-shadow method must classify.

    Attributes:
        index: int64 [S], flat pixel indices of valid, light-facing pixels.
        position: float64 [S, 3], positions in the G-buffer's coordinates (world units;
            relative to the frame origin inside a method, see :func:`localize`).
        normal: float64 [S, 3], unit geometric normals (facing camera and light).
        shape: (H, W) of the image.
    """

    index: np.ndarray
    position: np.ndarray
    normal: np.ndarray
    shape: tuple[int, int]

    @property
    def count(self) -> int:
        return int(self.index.size)

    @property
    def capacity(self) -> int:
        """The default padded length of per-sample arrays: a bucket of ``count``."""
        return bucket(self.count, steps=8)

    def padded_position(self, dtype, capacity: int | None = None) -> np.ndarray:
        """[capacity, 3] positions in ``dtype``; rows past ``count`` are zeros."""
        return pad(self.position, capacity or self.capacity, dtype=dtype)

    def padded(self, values: np.ndarray, dtype, capacity: int | None = None) -> np.ndarray:
        """``values`` [count, ...] zero-padded to [capacity, ...] in ``dtype``."""
        return pad(values, capacity or self.capacity, dtype=dtype)

    def tile_order(self, tile: int) -> np.ndarray:
        """int64 [S]: the samples reordered by ``tile`` x ``tile`` pixel tiles (tiles
        row-major, pixels row-major within a tile); ``tile=1`` is the identity."""
        if tile <= 1:
            return np.arange(self.count)
        y, x = np.divmod(self.index, self.shape[1])
        tiles_x = -(-self.shape[1] // tile)
        key = ((y // tile) * tiles_x + x // tile) * (tile * tile) + (y % tile) * tile + x % tile
        return stable_argsort(key)

    def scatter(self, values: np.ndarray, fill=0) -> np.ndarray:
        """An image [H, W] with ``values[:count]`` at the sample pixels, ``fill`` elsewhere."""
        values = np.asarray(values)[: self.count]
        out = np.full(self.shape[0] * self.shape[1], fill, dtype=values.dtype)
        out[self.index] = values
        return out.reshape(self.shape)


def view_samples(gbuf: GBuffer, light: Light) -> Samples:
    """Valid pixels whose camera-facing normal faces the light (all others are unlit)."""
    idx, position, normal = facing_samples(gbuf, light)
    return Samples(idx, position, normal, gbuf.valid.shape)


BIAS_MODES = ("receiver", "cap")


def bias_terms(samples: Samples, light_h: np.ndarray, planes: np.ndarray, eps: float,
               mode: str) -> tuple[np.ndarray, np.ndarray]:
    """Per-sample scale [S] and per-triangle bound [T] for the self-shadowing bias.

    A sample p behind a caster's cap (``cap(p) < 0``) is shadowed when
    ``cap(p) * scale[p] < bound[t]``:

    - ``mode="receiver"``: the segment from p to the light must cross the caster more
      than ``eps`` above p's tangent plane, the same criterion the Embree reference
      uses (see ``shadowlab.reference.raycast``). With a = n . (L.xyz - L.w p) and
      capL = cap(L) (homogeneous), the crossing height exceeds eps when
      ``-cap(p) * a > eps * (capL - L.w * cap(p))``, i.e.
      ``cap(p) * (a - eps * L.w) < -eps * capL``.
    - ``mode="cap"``: the papers' bias, p more than ``eps`` behind the caster's plane:
      ``cap(p) * 1 < -eps``.

    Args:
        light_h: float64 [4] homogeneous light; planes: [T, 4, 4] (row 3 the cap).
    """
    scale = bias_scale(samples, light_h, eps, mode)
    if mode == "cap":
        return scale, np.full(planes.shape[0], -eps)
    cap = np.asarray(planes[:, 3], dtype=np.float64)
    cap_at_light = cap[:, :3] @ light_h[:3] + light_h[3] * cap[:, 3]
    return scale, -eps * cap_at_light


def bias_scale(samples: Samples, light_h: np.ndarray, eps: float, mode: str) -> np.ndarray:
    """float64 [S]: the per-sample scale of :func:`bias_terms` (its per-triangle bound
    does not depend on the samples, so a structure built from the bounds can outlive
    the frame)."""
    if mode == "cap":
        return np.ones(samples.count)
    # n . (L.xyz - L.w p) on coordinate columns: no [S, 3] temporary and no einsum
    # (1.5x faster at 1M samples).
    p, n, w = samples.position, samples.normal, light_h[3]
    dots = [n[:, i] * (light_h[i] - w * p[:, i]) for i in range(3)]
    return (dots[0] + dots[1] + dots[2]) - eps * w


def cap_bias(scene: Scene, shadow_eps: float) -> float:
    """The bias ``eps`` in world units (same offset as the Embree reference)."""
    return shadow_epsilon(scene, shadow_eps)


def caster_terms(scene: Scene, samples: Samples, light_h: np.ndarray, planes, valid,
                 shadow_eps: float, bias: str, dtype):
    """The casters of a padded triangle setup and their self-shadowing bias terms.

    Args:
        planes: [T, 16] (or [T, 4, 4]) planes of the triangle setup of T >=
            ``scene.num_triangles`` triangles (rows past the scene's are padding);
        valid: bool [T] non-degenerate flags of the same setup; light_h: float64 [4].
    Returns:
        valid: bool [T] NumPy, False for padding rows; planes4: [T, 4, 4] NumPy, the
        planes' dtype; scale: float64 [S] per-sample bias scale; bound: [T] in ``dtype``,
        -inf where not valid (see :func:`bias_terms`).
    """
    valid = np.array(valid)
    valid[scene.num_triangles:] = False
    planes4 = np.asarray(planes).reshape(-1, 4, 4)
    scale, bound = bias_terms(samples, light_h, planes4, cap_bias(scene, shadow_eps), bias)
    return valid, planes4, scale, np.where(valid, bound, -np.inf).astype(dtype)
