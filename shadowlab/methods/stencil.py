"""``zpass`` and ``zfail``: stencil shadow volumes of per-triangle shadow quads, as counts.

What rasterizing every triangle's shadow volume would cost (Heidmann 1991; Carmack
2000, Bilodeau and Songy 1999): each triangle's volume is bounded by three shadow
quads (its edges extruded away from the light), its near cap (the triangle) and, for
ZFAIL, its far cap at infinity. Along the view ray of a pixel, a convex volume's
boundary is crossed at most twice: where the ray enters (parameter ``lo``) and leaves
(``hi``, possibly at infinity). With the ray x(l) = eye + l (p - eye), p the pixel's
view sample (l = 1) and the near plane at l_near = near / w(p):

- ZPASS updates the stencil for every boundary fragment in front of the sample:
  the entry if l_near < lo < 1, the exit if hi < 1;
- ZFAIL for every fragment behind it: the entry if lo > 1, the exit if hi > 1
  (hi = infinity is the far cap, drawn at infinity).

The final stencil value of a pixel is the number of volumes containing its sample
(ZPASS starts from the number of volumes containing the eye, the classic fix for a
camera inside a shadow volume, reported as ``eye_in_volumes``). We take that number
from the exact per-sample inclusion test of ``brute_force`` (inclusive edge planes,
the bias criterion), so the lit mask (stencil == 0) equals the reference; the
crossing parameters, computed in the working precision, only drive the update counts.
"""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp
import numpy as np

from ..scene.view import hard_light
from ..core.timing import StageTimer
from ..core.capacity import pad
from ..geometry.triangle_setup import shadow_volume_planes as setup
from ..core.capacity import bucket
from ..core.frame import BIAS_MODES, caster_terms, precision_mode, view_samples
from .registry import Option, register
from ..core.result import ShadowResult


@functools.lru_cache(maxsize=None)
def _stencil_kernel(chunk: int, zfail: bool):
    @jax.jit
    def run(points, scale, near_l, planes, at_eye, bound, active):
        """Per sample: bool shadow [S], int32 stencil updates [S].

        points [S, 3], scale [S], near_l [S] (near-plane ray parameter), planes [T, 16],
        at_eye [T, 4] plane values at the eye, bound [T], active bool [T].
        """
        px, py, pz = points[:, 0], points[:, 1], points[:, 2]
        inf = jnp.asarray(jnp.inf, points.dtype)

        def body(i, carry):
            shadow, updates = carry
            blk = jax.lax.dynamic_slice_in_dim(planes, i * chunk, chunk)
            eye = jax.lax.dynamic_slice_in_dim(at_eye, i * chunk, chunk)
            lim = jax.lax.dynamic_slice_in_dim(bound, i * chunk, chunk)
            act = jax.lax.dynamic_slice_in_dim(active, i * chunk, chunk)
            for j in range(chunk):
                p = blk[j]
                vals = [px * p[4 * k] + py * p[4 * k + 1] + pz * p[4 * k + 2] + p[4 * k + 3]
                        for k in range(4)]
                e0, e1, e2, cap = vals
                shadow = shadow | ((e0 >= 0) & (e1 >= 0) & (e2 >= 0) & (cap * scale < lim[j])
                                   & act[j])
                lo, hi = near_l, jnp.full_like(near_l, inf)
                entered = jnp.zeros(near_l.shape, bool)
                empty = jnp.zeros(near_l.shape, bool)
                for k in range(4):
                    sign = -1 if k == 3 else 1          # cap: inside is cap <= 0
                    a = sign * eye[j, k]
                    b = sign * vals[k] - a
                    root = -a / jnp.where(b == 0, 1, b)
                    rise = b > 0
                    entered = entered | (rise & (root > lo))
                    lo = jnp.where(rise, jnp.maximum(lo, root), lo)
                    hi = jnp.where(b < 0, jnp.minimum(hi, root), hi)
                    empty = empty | ((b == 0) & (a < 0))
                hit = ~empty & (lo < hi) & act[j]
                if zfail:
                    n = (hit & (lo > 1)).astype(jnp.int32) + (hit & (hi > 1)).astype(jnp.int32)
                else:
                    n = ((hit & entered & (lo < 1)).astype(jnp.int32)
                         + (hit & (hi < 1)).astype(jnp.int32))
                updates = updates + n
            return shadow, updates

        return jax.lax.fori_loop(0, planes.shape[0] // chunk, body,
                                 (jnp.zeros(points.shape[0], bool),
                                  jnp.zeros(points.shape[0], jnp.int32)))
    return run


def _stencil(scene, gbuf, light, *, zfail, precision, shadow_eps, chunk, bias):
    name = "zfail" if zfail else "zpass"
    timer = StageTimer()
    with timer.stage("samples"):
        samples = view_samples(gbuf, light)
    cam = gbuf.camera
    with precision_mode(precision) as dtype:
        t = bucket(scene.num_triangles, minimum=chunk)
        tri = pad(scene.triangles, t, dtype=dtype)
        light_h = hard_light(light).homogeneous
        planes, valid = timer.run("setup", setup, jnp.asarray(tri),
                                  jnp.asarray(light_h.astype(dtype)))
        with timer.stage("bias"):
            valid, p4, scale, bound = caster_terms(scene, samples, light_h, planes, valid,
                                                   shadow_eps, bias, dtype)
            at_eye = (p4[..., :3].astype(np.float64) @ cam.eye + p4[..., 3]).astype(dtype)
            eye_in = int(np.sum(valid & np.all(at_eye[:, :3] >= 0, axis=1) & (at_eye[:, 3] < 0)))
            depth = gbuf.depth.reshape(-1)[samples.index]
            near_l = samples.padded(cam.near / depth, dtype)
            points = jnp.asarray(samples.padded_position(dtype))
            scale_d = jnp.asarray(samples.padded(scale, dtype))
        shadow, updates = timer.run("stencil", _stencil_kernel(chunk, zfail), points, scale_d,
                                    jnp.asarray(near_l), planes, jnp.asarray(at_eye),
                                    jnp.asarray(bound), jnp.asarray(valid))
    shadow = np.asarray(shadow)[: samples.count]
    updates = np.asarray(updates)[: samples.count].astype(np.int64)
    lit = samples.scatter(~shadow, fill=False)
    casters = int(valid.sum())
    counters = {
        "samples": samples.count, "casters": casters,
        "culled_triangles": scene.num_triangles - casters,
        "tests": samples.count * casters,
        "stencil_updates": int(updates.sum()),
        "stencil_updates_per_pixel": samples.scatter(updates, fill=0),
        "eye_in_volumes": eye_in,
        "shadowed": int(shadow.sum()), "lit": int(lit.sum()),
    }
    return ShadowResult(lit, counters, dict(timer.times, total=timer.total))


_OPTIONS = {"chunk": Option(16, "triangles per unrolled loop step", allowed=(4, 8, 16, 32)),
            "bias": Option("receiver", "self-shadowing bias ('receiver' as the reference, "
                           "'cap' as the papers)", allowed=BIAS_MODES)}
_DECLARED = {"kind": "exact", "stages": ("samples", "setup", "bias", "stencil"),
             "counters": ("samples", "casters", "culled_triangles", "tests", "stencil_updates",
                          "stencil_updates_per_pixel", "eye_in_volumes", "shadowed", "lit")}


@register("zpass", doc="stencil shadow volumes (depth pass) of per-triangle shadow quads: "
          "stencil update counts", paper="Heidmann 1991 (baseline in Sintorn et al. 2014)",
          options=_OPTIONS, **_DECLARED)
def zpass(scene, gbuf, light, **opts):
    return _stencil(scene, gbuf, light, zfail=False, **opts)


@register("zfail", doc="stencil shadow volumes (depth fail, capped) of per-triangle shadow "
          "quads: stencil update counts", paper="Carmack 2000 (baseline in Sintorn et al. 2014)",
          options=_OPTIONS, **_DECLARED)
def zfail(scene, gbuf, light, **opts):
    return _stencil(scene, gbuf, light, zfail=True, **opts)
