"""Geometry shared by the methods: the canonical triangle setup (shadow-volume planes,
:mod:`.triangle_setup`) and Morton keys (:mod:`.morton`)."""

from .triangle_setup import degeneracy_tolerance, lex_less, shadow_volume_planes

__all__ = ["degeneracy_tolerance", "lex_less", "shadow_volume_planes"]
