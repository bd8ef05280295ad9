"""shadowlab: a laboratory for real-time shadow algorithms.

The public API (see README.md)::

    import shadowlab as sl
    scene = sl.load_scene("model.obj")          # or a procedural name, e.g. "gate"
    camera = sl.Camera(eye=..., target=..., resolution=(1024, 1024))
    light = sl.PointLight(position=...)
    gbuf = sl.render_gbuffer(scene, camera)
    truth = sl.reference_shadows(scene, gbuf, light)
    res = sl.compute_shadows(scene, gbuf, light, method="brute_force")
    ev = sl.evaluate(scene, gbuf, light, "brute_force")   # + reference, metric, warm times
"""

from . import harness, methods, scene
from .core.counters import COUNTERS
from .harness import evaluate
from .methods import MethodError, ShadowResult, compute_shadows
from .reference.raycast import GBuffer, reference_shadows, render_gbuffer, soft_reference
from .scene import (Animation, Camera, DirectionalLight, PointLight, Scene, SceneError,
                    SphereLight, View, load_scene)

__version__ = "0.1.0"

__all__ = [
    "Animation", "COUNTERS", "Camera", "DirectionalLight", "GBuffer", "MethodError",
    "PointLight", "Scene", "SceneError", "ShadowResult", "SphereLight", "View",
    "compute_shadows", "evaluate", "harness", "load_scene", "methods", "reference_shadows",
    "render_gbuffer", "scene", "soft_reference", "__version__",
]
