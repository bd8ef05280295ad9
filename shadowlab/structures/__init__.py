"""Acceleration structures the methods share.

- :mod:`.cones`: truncated cones bounding what a blocker can shadow, and their
  conservative tests against capsules, spheres and planes.
- :mod:`.tile_lists`: 16 x 16 screen tiles, the bounds of their samples, and the
  per-tile lists of blockers filled by cone tests, with a fixed capacity whose
  overflow is flagged and counted.
"""
