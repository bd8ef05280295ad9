"""Acceleration structures the methods share.

- :mod:`.cluster_hierarchy`: the Morton-keyed view-sample cluster hierarchy (and PTSV's
  2D tile hierarchy), with implicit or explicit bounds.
- :mod:`.top_tree`: the TOP tree of partitioned shadow volumes, with depth.
- :mod:`.sun_disk`: the sun-disk bitmask rasterizer of tiled soft shadows.
- :mod:`.cones`: truncated cones bounding what a blocker can shadow, and their
  conservative tests against capsules, spheres and planes.
- :mod:`.tile_lists`: 16 x 16 screen tiles, the bounds of their samples, and the
  per-tile lists of blockers filled by cone tests, with a fixed capacity whose
  overflow is flagged and counted.
"""
