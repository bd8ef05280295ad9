"""Per-scene caches, registered in one place so that a benchmark can drop them all.

Several modules keep work derived from a :class:`~shadowlab.scene.mesh.Scene` across
frames, as Embree keeps its BVH: the frame-local translated scene
(``core.frame.local_scene``), the Embree BVH (``reference.raycast.embree_scene``), and,
on the scene object itself, its triangle array, bounds, mesh report and edge adjacency.
Each module-level cache is created with :func:`per_scene_cache`; :func:`drop` forgets
everything any of them holds for one scene. ``shadowlab bench`` uses it to time a
*dynamic* frame (nothing cached, geometry as if it had just changed) beside the usual
*static* one (docs/benchmarks.md, "Protocol").
"""

from __future__ import annotations

import weakref

_REGISTRY: list[weakref.WeakKeyDictionary] = []

#: attributes a Scene caches on itself (functools.cached_property values and dicts)
SCENE_ATTRIBUTES = ("triangles", "bounds", "_report_cache", "_adjacency_cache")


def per_scene_cache() -> weakref.WeakKeyDictionary:
    """A new {scene: value} cache that :func:`drop` clears; entries die with the scene."""
    cache: weakref.WeakKeyDictionary = weakref.WeakKeyDictionary()
    _REGISTRY.append(cache)
    return cache


def drop(scene) -> None:
    """Forget every cached value derived from ``scene``: the registered caches' entries
    (and, recursively, those of scenes derived from it, such as its frame-local
    translations) and the values cached on the scene object."""
    for cache in _REGISTRY:
        held = cache.pop(scene, None)
        if isinstance(held, dict):
            for value in held.values():
                if value is not scene and hasattr(value, "faces"):    # a derived Scene
                    drop(value)
    for name in SCENE_ATTRIBUTES:
        scene.__dict__.pop(name, None)


__all__ = ["SCENE_ATTRIBUTES", "drop", "per_scene_cache"]
