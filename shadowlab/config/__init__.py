"""Run configurations: TOML files -> validated, typed, frozen config objects.

A run configuration says which scene to load, from where it is seen and lit (and how
that moves over an animation), which shadow methods to run with which options, how
the exact reference is computed and where the outputs go. The schema (every table is
optional; the built-in default, ``shadowlab/configs/default.toml``, spells out every
key with a comment)::

    [scene]
    source = "gate"          # procedural generator name, or a mesh file path
    [scene.params]           # generator parameters (procedural sources only)
    seed = 0

    [camera]                 # each key optional; missing keys: the scene's default view
    eye = [x, y, z]          # also target, up, fov_y_deg, near, far
    resolution = [w, h]

    [light]                  # optional; missing keys: the scene's default light
    type = "point"           # point | directional | sphere | sun
    position = [x, y, z]     # point, sphere
    direction = [x, y, z]    # directional, sun: the way the light travels
    radius = 0.5             # sphere (world units)
    angular_radius_deg = 0.27  # sun

    [animation]
    frames = 1
    eye_keys = [[x, y, z], ...]   # also target_keys, light_keys

    [methods]
    names = "all"            # or a list of registered method names (or one name)
    [methods.options.brute_force]
    chunk = 16

    [reference]
    shadow_eps = 1e-5
    soft_rays = 64
    seed = 0

    [output]
    dir = "runs/default"
    figures = true

Path rules: a relative ``scene.source`` resolves against the folder of the config file
that names it; a source given by ``--set`` or by the built-in default resolves against
the current directory. ``output.dir`` is kept as written (relative to the current
directory when the run starts); it defaults to ``runs/<config file stem>``.

Every problem raises :class:`ConfigError`, whose message names where the value came
from (the config file, ``--set`` for override-introduced values, or
``<built-in default>``), the dotted key, what is wrong and what is allowed.
Unknown keys are rejected at every level. A config whose frames would need more memory
than the machine allows is refused by :func:`load_config` (:mod:`.resources`).

Modules: :mod:`.schema` (one pydantic model per table; the validated config objects),
:mod:`.loading` (TOML, ``--set`` overrides, checks against the registries),
:mod:`.errors` (:class:`ConfigError`, pydantic errors as messages), :mod:`.views`
(scene, camera and light resolution), :mod:`.resources` (the memory estimate).

Light resolution (done by :meth:`RunConfig.views`, which knows the scene; see
:mod:`.views`): without ``light.type`` the scene's default light keeps its type and the
given keys change it; with a type, missing keys come from the scene's default light
where it has them.

Method options: ``shadow_eps`` (a common option of every method) defaults to
``reference.shadow_eps``, so methods and the Embree reference use the same offset
unless a method's table says otherwise.
"""

from .errors import BUILTIN_DEFAULT, OVERRIDE_LABEL, ConfigError
from .loading import load_config, parse_override
from .schema import (DEFAULT_SOURCE, LIGHT_TYPES, SUN_ANGULAR_RADIUS_DEG, AnimationConfig,
                     CameraConfig, LightConfig, MethodsConfig, OutputConfig, ReferenceConfig,
                     RunConfig, SceneConfig)
from .views import mesh_default_view

__all__ = [
    "AnimationConfig", "BUILTIN_DEFAULT", "CameraConfig", "ConfigError", "DEFAULT_SOURCE",
    "LIGHT_TYPES", "LightConfig", "MethodsConfig", "OVERRIDE_LABEL", "OutputConfig",
    "ReferenceConfig", "RunConfig", "SUN_ANGULAR_RADIUS_DEG", "SceneConfig", "load_config",
    "mesh_default_view", "parse_override",
]
