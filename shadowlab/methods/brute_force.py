"""``brute_force``: every view sample against every triangle's shadow volume.

The slow but simple oracle. Triangle setup builds the four planes of each shadow
volume (``shadowlab.geometry.triangle_setup``, rounded the same way at every array
size); the test loops over triangles in unrolled
chunks (``lax.fori_loop``) and is vectorized over all samples, so XLA fuses each
chunk into one pass over the samples. A sample is shadowed when it is inside any
volume: inside all three edge planes (inclusive) and behind the cap by more than the
bias (option ``bias``: ``"receiver"``, the reference's criterion, or ``"cap"``, the
papers'; see ``common.bias_terms``).
"""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp
import numpy as np

from ..core.capacity import bucket, pad
from ..geometry.triangle_setup import shadow_volume_planes
from ..scene.view import hard_light
from ..core.timing import StageTimer
from ..core.frame import BIAS_MODES, bias_terms, cap_bias, precision_mode, view_samples
from .registry import Option, register
from ..core.result import ShadowResult


@functools.lru_cache(maxsize=None)
def _test_kernel(chunk: int):
    @jax.jit
    def test(points, scale, planes, bound, n_chunks):
        """bool [S]: points [S, 3] inside any volume of planes [T, 16] (T % chunk == 0).

        ``scale`` [S] and ``bound`` [T] are the bias terms of ``common.bias_terms``;
        invalid triangles have ``bound = -inf``. Only the first ``n_chunks`` chunks are
        visited: the padding of the triangle capacity costs nothing.
        """
        px, py, pz = points[:, 0], points[:, 1], points[:, 2]

        def body(i, shadow):
            blk = jax.lax.dynamic_slice_in_dim(planes, i * chunk, chunk)
            lim = jax.lax.dynamic_slice_in_dim(bound, i * chunk, chunk)
            for j in range(chunk):
                p = blk[j]
                e0 = px * p[0] + py * p[1] + pz * p[2] + p[3]
                e1 = px * p[4] + py * p[5] + pz * p[6] + p[7]
                e2 = px * p[8] + py * p[9] + pz * p[10] + p[11]
                cap = px * p[12] + py * p[13] + pz * p[14] + p[15]
                shadow = shadow | ((e0 >= 0) & (e1 >= 0) & (e2 >= 0) & (cap * scale < lim[j]))
            return shadow

        return jax.lax.fori_loop(0, n_chunks, body, jnp.zeros(points.shape[0], dtype=bool))
    return test


@register("brute_force", doc="every view sample against every triangle's shadow volume "
          "(the exact oracle)", paper="none (the exact oracle; docs/conventions.md)", kind="exact",
          counters=("samples", "casters", "culled_triangles", "tests", "tests_per_pixel",
                    "shadowed", "lit"),
          stages=("samples", "setup", "bias", "test"),
          options={"chunk": Option(16, "triangles per unrolled loop step", allowed=(4, 8, 16, 32)),
                   "bias": Option("receiver", "self-shadowing bias: 'receiver' = eps above the "
                                  "receiver's tangent plane (as the reference), 'cap' = eps "
                                  "behind the caster's plane (as the papers)",
                                  allowed=BIAS_MODES)})
def brute_force(scene, gbuf, light, *, precision, shadow_eps, chunk, bias):
    timer = StageTimer()
    with timer.stage("samples"):
        samples = view_samples(gbuf, light)
    with precision_mode(precision) as dtype:
        t = bucket(scene.num_triangles, minimum=chunk)
        tri = pad(scene.triangles, t, dtype=dtype)
        light_h = hard_light(light).homogeneous.astype(dtype)
        planes, valid = timer.run("setup", shadow_volume_planes, jnp.asarray(tri),
                                  jnp.asarray(light_h))
        with timer.stage("bias"):
            valid = np.array(valid)
            valid[scene.num_triangles:] = False
            scale, bound = bias_terms(samples, hard_light(light).homogeneous,
                                      np.asarray(planes).reshape(-1, 4, 4),
                                      cap_bias(scene, shadow_eps), bias)
            bound = np.where(valid, bound, -np.inf).astype(dtype)
            points = jnp.asarray(samples.padded_position(dtype))
            scale = jnp.asarray(samples.padded(scale, dtype))
        n_chunks = jnp.asarray(-(-scene.num_triangles // chunk), dtype=jnp.int32)
        shadow = timer.run("test", _test_kernel(chunk), points, scale, planes, jnp.asarray(bound),
                           n_chunks)
    shadow = np.asarray(shadow)[: samples.count]
    casters = int(valid.sum())
    lit_values = ~shadow
    lit = samples.scatter(lit_values, fill=False)
    counters = {
        "samples": samples.count,
        "casters": casters,
        "culled_triangles": scene.num_triangles - casters,
        "tests": samples.count * casters,
        "tests_per_pixel": samples.scatter(np.full(samples.count, casters, np.int64), fill=0),
        "shadowed": int(shadow.sum()),
        "lit": int(lit.sum()),
    }
    timings = dict(timer.times, total=timer.total)
    return ShadowResult(lit, counters, timings)
