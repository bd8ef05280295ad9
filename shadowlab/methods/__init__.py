"""Shadow methods: one module per algorithm, the method interface and the registry.

``interface.py`` says what a method declares (kind, options model, counters, stages);
``registry.py`` validates, dispatches and stamps results; ``result.py`` is the result.
"""

from .interface import DEFAULT_SHADOW_EPS, MethodKind
from .registry import (MethodError, MethodInfo, Option, available, check_light,
                       compute_shadows, get, light_problem, names, register, register_kernel,
                       resolve_options)
from ..core.result import ShadowResult

__all__ = ["DEFAULT_SHADOW_EPS", "MethodError", "MethodInfo", "MethodKind", "Option",
           "ShadowResult", "available", "check_light", "compute_shadows", "get",
           "light_problem", "names", "register", "register_kernel", "resolve_options"]
