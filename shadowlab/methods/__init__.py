"""Shadow methods: one module per algorithm, and the registry that dispatches to them."""

from .registry import (MethodError, MethodInfo, Option, available, compute_shadows, get,
                       names, register, resolve_options)
from .result import ShadowResult

__all__ = ["MethodError", "MethodInfo", "Option", "ShadowResult", "available",
           "compute_shadows", "get", "names", "register", "resolve_options"]
