"""Engines: generic, jit-compiled loops that methods drive with their own tests.

- :mod:`.traversal`: level-synchronous traversal of 32-ary trees in fixed-capacity
  frontiers of (item, node, job) entries, with a per-node test callback, compaction
  into power-of-two buckets, overflow retry and counters.
"""
