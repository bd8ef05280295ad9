"""Pareto fronts of run time against error: which configuration is fastest at each error.

A point (seconds, error) is on the front when no other point is at least as fast with
at most its error and strictly better in one of the two. Reading the front from the
lowest error up gives the statement "to reach error e or better, the fastest is X":
each front point is the fastest way to an error no larger than its own.
"""

from __future__ import annotations

import numpy as np


def pareto_front(seconds, error) -> np.ndarray:
    """Indices of the Pareto-optimal points, ordered by increasing error (ties: faster
    first).

    Args:
        seconds: float [N] run times (seconds; lower is better).
        error: float [N] errors (lower is better). NaN entries are never on the front.

    Returns:
        int [K] indices into the inputs; along them error increases and seconds
        strictly decrease.
    """
    t = np.asarray(seconds, np.float64)
    e = np.asarray(error, np.float64)
    if t.shape != e.shape or t.ndim != 1:
        raise ValueError(f"seconds and error must be 1D of one length, got {t.shape} and "
                         f"{e.shape}")
    ok = np.flatnonzero(np.isfinite(t) & np.isfinite(e))
    order = ok[np.lexsort((t[ok], e[ok]))]          # by error, then by time
    front, best = [], np.inf
    for i in order:
        if t[i] < best:
            front.append(int(i))
            best = t[i]
    return np.asarray(front, np.int64)


def fastest_at(levels, seconds, error) -> np.ndarray:
    """For each error level, the index of the fastest point with error <= level, or -1.

    Args:
        levels: float [L] error levels; seconds, error: float [N] as in
            :func:`pareto_front`.

    Returns:
        int [L].
    """
    t = np.asarray(seconds, np.float64)
    e = np.asarray(error, np.float64)
    out = []
    for lev in np.asarray(levels, np.float64):
        ok = np.flatnonzero(np.isfinite(t) & np.isfinite(e) & (e <= lev))
        out.append(int(ok[np.argmin(t[ok])]) if ok.size else -1)
    return np.asarray(out, np.int64)


__all__ = ["fastest_at", "pareto_front"]
