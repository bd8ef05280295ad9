"""The harness: running methods against the reference, timing them and reporting."""
