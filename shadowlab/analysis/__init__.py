"""Metrics against the exact reference, and plots."""

from .metrics import compare_hard, compare_soft, error_map

__all__ = ["compare_hard", "compare_soft", "error_map"]
