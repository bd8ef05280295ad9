"""Geometric primitives shared by the methods: shadow-volume planes and clip space."""

from .planes import (edge_plane, in_shadow_volume, plane_distance, shadow_volume_planes,
                     to_clip_space)

__all__ = ["edge_plane", "in_shadow_volume", "plane_distance", "shadow_volume_planes",
           "to_clip_space"]
