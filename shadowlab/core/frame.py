"""Helpers every method shares: precision, view samples and their padding, the bias."""

from __future__ import annotations

import contextlib
import dataclasses

import jax
import numpy as np

from .capacity import bucket, pad
from ..reference.raycast import GBuffer, facing_samples, shadow_epsilon
from ..scene.mesh import Scene
from ..scene.view import Light


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
        position: float64 [S, 3], world positions.
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

    def padded_position(self, dtype, capacity: int | None = None) -> np.ndarray:
        """[capacity, 3] positions in ``dtype``; rows past ``count`` are zeros."""
        return pad(self.position, capacity or bucket(self.count, steps=8), dtype=dtype)

    def padded(self, values: np.ndarray, dtype, capacity: int | None = None) -> np.ndarray:
        """``values`` [count, ...] zero-padded to [capacity, ...] in ``dtype``."""
        return pad(values, capacity or bucket(self.count, steps=8), dtype=dtype)

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
    if mode == "cap":
        return np.ones(samples.count), np.full(planes.shape[0], -eps)
    to_light = light_h[:3] - light_h[3] * samples.position
    a = np.einsum("ij,ij->i", samples.normal, to_light)
    cap = np.asarray(planes[:, 3], dtype=np.float64)
    cap_at_light = cap[:, :3] @ light_h[:3] + light_h[3] * cap[:, 3]
    return a - eps * light_h[3], -eps * cap_at_light


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
