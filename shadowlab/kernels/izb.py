"""Irregular z-buffer kernels (Warp): the list build and the per-texel tracing walk.

The GPU form of ``shadowlab.methods.izb``'s two engine steps (the light-space set-up,
the CSM prepass and the fragment rasterization are the shared host code of
``methods.izb.run_frame``):

- ``count_nodes`` (a thread per sample): atomic increment of its texel's list length and
  atomic max of the list's farthest depth and depth margin; an exclusive scan gives the
  list starts; ``fill_nodes`` (a thread per sample) appends the sample at an atomic
  cursor. Under a serial schedule (Warp's CPU backend runs threads in order) every list
  holds its samples in sample order: the JAX engine's stable sort, bit for bit.
- ``trace`` (a thread per outer-conservative fragment): the fragment is depth-culled when
  its smallest depth is not in front of the list's farthest node; otherwise it walks the
  list and runs the exact per-sample test of every exact method (the same expressions)
  on each node, counting tests per node with atomics and writing shadow bits.

``run`` is ``izb`` with these kernels; the counters equal the JAX method's. Compiled with
``fuse_fp=False``: every product rounded, as written.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import warp as wp

from ..methods import izb as jizb
from ..methods.registry import call_options
from .runtime import init

wp.set_module_options({"fuse_fp": False, "enable_backward": False})


@wp.kernel
def count_nodes(slot: wp.array(dtype=wp.int32), delta: wp.array(dtype=wp.float64),
                margin: wp.array(dtype=wp.float64), length: wp.array(dtype=wp.int32),
                maxd: wp.array(dtype=wp.float64), maxm: wp.array(dtype=wp.float64)):
    s = wp.tid()
    k = slot[s]
    if k >= 0:
        wp.atomic_add(length, k, 1)
        wp.atomic_max(maxd, k, delta[s])
        wp.atomic_max(maxm, k, margin[s])


@wp.kernel
def fill_nodes(slot: wp.array(dtype=wp.int32), start: wp.array(dtype=wp.int32),
               cursor: wp.array(dtype=wp.int32), order: wp.array(dtype=wp.int32)):
    s = wp.tid()
    k = slot[s]
    if k >= 0:
        at = wp.atomic_add(cursor, k, 1)
        order[start[k] + at] = s


@wp.kernel
def trace(tri: wp.array(dtype=wp.int32), slot: wp.array(dtype=wp.int32),
          lo: wp.array(dtype=wp.float64), maxd: wp.array(dtype=wp.float64),
          maxm: wp.array(dtype=wp.float64), start: wp.array(dtype=wp.int32),
          length: wp.array(dtype=wp.int32), order: wp.array(dtype=wp.int32),
          points: wp.array2d(dtype=Any), scale: wp.array(dtype=Any),
          planes: wp.array2d(dtype=Any), bound: wp.array(dtype=Any),
          shadow: wp.array(dtype=wp.int32), tests: wp.array(dtype=wp.int32),
          stats: wp.array(dtype=wp.int32)):
    f = wp.tid()
    k = slot[f]
    if lo[f] < maxd[k] + maxm[k]:
        wp.atomic_add(stats, 0, 1)          # traced fragments
        t = tri[f]
        for i in range(length[k]):
            n = order[start[k] + i]
            px = points[n, 0]
            py = points[n, 1]
            pz = points[n, 2]
            e0 = px * planes[t, 0] + py * planes[t, 1] + pz * planes[t, 2] + planes[t, 3]
            e1 = px * planes[t, 4] + py * planes[t, 5] + pz * planes[t, 6] + planes[t, 7]
            e2 = px * planes[t, 8] + py * planes[t, 9] + pz * planes[t, 10] + planes[t, 11]
            cap = px * planes[t, 12] + py * planes[t, 13] + pz * planes[t, 14] + planes[t, 15]
            wp.atomic_add(tests, n, 1)
            zero = e0 - e0
            if e0 >= zero and e1 >= zero and e2 >= zero and cap * scale[n] < bound[t]:
                shadow[n] = 1
    else:
        wp.atomic_add(stats, 1, 1)          # depth-culled fragments


class WarpEngine:
    """The list build and tracing of ``methods.izb.run_frame`` as Warp kernels."""

    #: what :meth:`trace` reads of the outer fragments (its kernel does the depth test)
    fragment_fields = ("tri", "slot", "covered", "lo")

    def __init__(self, device: str | None = None):
        self.device = device

    def build(self, slot, delta, margin, k) -> jizb.Lists:
        dev = init(self.device)
        s = len(slot)
        slot_w = wp.array(slot.astype(np.int32), dtype=wp.int32, device=dev)
        length = wp.zeros(max(k, 1), dtype=wp.int32, device=dev)
        maxd = wp.array(np.full(max(k, 1), -np.inf), dtype=wp.float64, device=dev)
        maxm = wp.zeros(max(k, 1), dtype=wp.float64, device=dev)
        wp.launch(count_nodes, dim=s, device=dev, inputs=[
            slot_w, wp.array(np.asarray(delta, np.float64), dtype=wp.float64, device=dev),
            wp.array(np.asarray(margin, np.float64), dtype=wp.float64, device=dev),
            length, maxd, maxm])
        n_len = length.numpy()[:k].astype(np.int64)
        start = np.cumsum(n_len) - n_len                 # exclusive scan
        n = int(n_len.sum())
        order = wp.zeros(max(n, 1), dtype=wp.int32, device=dev)
        wp.launch(fill_nodes, dim=s, device=dev, inputs=[
            slot_w, wp.array(np.append(start, 0).astype(np.int32), dtype=wp.int32, device=dev),
            wp.zeros(max(k, 1), dtype=wp.int32, device=dev), order])
        return jizb.Lists(order.numpy()[:n].astype(np.int64), start, n_len,
                          maxd.numpy()[:k], maxm.numpy()[:k])

    def trace(self, frags, lists: jizb.Lists, points, scale, planes, bound, count):
        dev = init(self.device)
        tri, slot, lo = frags.compact("tri", "slot", "lo")
        pts = np.asarray(points)
        ftype = wp.float64 if pts.dtype == np.float64 else wp.float32

        def i32(a):
            a = np.asarray(a, np.int32)
            return wp.array(a if len(a) else np.zeros(1, np.int32), dtype=wp.int32, device=dev)

        def f64(a):
            a = np.asarray(a, np.float64)
            return wp.array(a if len(a) else np.zeros(1), dtype=wp.float64, device=dev)

        shadow = wp.zeros(pts.shape[0], dtype=wp.int32, device=dev)
        tests = wp.zeros(pts.shape[0], dtype=wp.int32, device=dev)
        stats = wp.zeros(2, dtype=wp.int32, device=dev)
        wp.launch(trace, dim=len(tri), device=dev, inputs=[
            i32(tri), i32(slot), f64(lo), f64(lists.maxd), f64(lists.maxm), i32(lists.start),
            i32(lists.length), i32(lists.order),
            wp.array(pts, dtype=ftype, device=dev),
            wp.array(np.asarray(scale), dtype=ftype, device=dev),
            wp.array(np.asarray(planes), dtype=ftype, device=dev),
            wp.array(np.asarray(bound), dtype=ftype, device=dev), shadow, tests, stats])
        st = stats.numpy()
        return (shadow.numpy()[:count].astype(bool), tests.numpy()[:count].astype(np.int64),
                int(st[0]), int(st[1]))


def run(scene, gbuf, light, device: str | None = None, **options):
    """``izb`` with the Warp list build and tracing; the method's options and counters."""
    opts = call_options("izb", options)
    return jizb.run_frame(scene, gbuf, light, WarpEngine(device), **opts)
