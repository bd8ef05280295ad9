"""Ground truth: Embree ray casting (:mod:`.raycast`: G-buffer, exact hard shadows, the
soft-shadow reference) and the analysis of mismatches at shadow boundaries
(:mod:`.boundary`)."""
