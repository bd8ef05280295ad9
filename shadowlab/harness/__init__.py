"""The evaluation harness: method + reference + metric under one timing protocol.

``evaluate`` is what ``shadowlab run``, ``shadowlab bench``, the experiments and
notebooks call; ``References`` picks and caches the reference of a frame (Embree
shadow rays for hard methods, the Monte Carlo soft reference for soft ones).
"""

from .evaluate import (DEFAULT_REPEATS, DEFAULT_WARMUP, EXPLAIN_LIMIT, Evaluation, References,
                       default_metric, evaluate, hard_metric, soft_metric)

__all__ = ["DEFAULT_REPEATS", "DEFAULT_WARMUP", "EXPLAIN_LIMIT", "Evaluation", "References",
           "default_metric", "evaluate", "hard_metric", "soft_metric"]
