"""Metrics against the exact reference, and plots."""

from .metrics import compare_hard, compare_soft, error_map, penumbra_mask

__all__ = ["compare_hard", "compare_soft", "error_map", "penumbra_mask"]
