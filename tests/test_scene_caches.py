"""The per-scene cache registry: dropping a scene's caches forgets every derived value,
and what is rebuilt afterwards is equal to what was cached."""

import numpy as np

from shadowlab.core import frame
from shadowlab.methods import compute_shadows
from shadowlab.reference import raycast
from shadowlab.scene import caches, procedural


def test_drop_forgets_every_cache_and_the_results_do_not_change():
    params = {"blocks": 2, "posts": 3, "offset": [1e5, 0.0, 1e5]}   # a non-zero frame origin
    scene = procedural.make("city", **params)
    view = procedural.default_view("city", scene, **params)
    gbuf = raycast.render_gbuffer(scene, view.camera.replace(resolution=(24, 24)))
    before = compute_shadows(scene, gbuf, view.light, method="silhouette")
    truth = raycast.reference_shadows(scene, gbuf, view.light)
    held = (raycast._EMBREE_CACHE.get(scene), frame._LOCAL_SCENES.get(scene))
    assert all(held), "the run should have cached a BVH and a frame-local scene"
    local = next(iter(frame._LOCAL_SCENES[scene].values()))
    assert "_adjacency_cache" in local.__dict__ and "triangles" in scene.__dict__

    caches.drop(scene)
    assert scene not in raycast._EMBREE_CACHE and scene not in frame._LOCAL_SCENES
    assert "_adjacency_cache" not in local.__dict__ and "triangles" not in scene.__dict__
    after = compute_shadows(scene, gbuf, view.light, method="silhouette")
    np.testing.assert_array_equal(after.lit, before.lit)
    np.testing.assert_array_equal(raycast.reference_shadows(scene, gbuf, view.light), truth)
    assert after.scalar_counters() == before.scalar_counters()


def test_a_registered_cache_is_dropped_and_entries_die_with_their_scene():
    import gc

    cache = caches.per_scene_cache()
    scene = procedural.make("gate")
    cache[scene] = {"x": 1}
    caches.drop(scene)
    assert scene not in cache
    cache[scene] = 2
    del scene
    gc.collect()
    assert len(cache) == 0
