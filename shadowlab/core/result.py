"""What every method returns."""

from __future__ import annotations

import dataclasses

import numpy as np


@dataclasses.dataclass(frozen=True, eq=False)
class ShadowResult:
    """The output of ``compute_shadows``.

    Attributes:
        lit: bool [H, W] (True = lit) for hard-shadow methods, or float [H, W] visibility
            in [0, 1] for soft-shadow methods.
        counters: names from ``shadowlab.core.counters.COUNTERS``; ints, floats, or int arrays
            [H, W] for ``*_per_pixel`` maps.
        timings: seconds per stage; ``<stage>_compile`` is compile time kept apart;
            ``total`` is the sum of run times, compile excluded.
        method: the registry name (stamped by ``registry.compute_shadows``; a method
            function leaves it empty).
        options: the full option set used, defaults filled in (stamped likewise).
    """

    lit: np.ndarray
    counters: dict
    timings: dict
    method: str = ""
    options: dict = dataclasses.field(default_factory=dict)

    def scalar_counters(self) -> dict:
        """Counters without the per-pixel maps (JSON-friendly)."""
        return {k: v for k, v in self.counters.items() if np.ndim(v) == 0}

    def counter_maps(self) -> dict:
        """The per-pixel counter maps, arrays [H, W]."""
        return {k: np.asarray(v) for k, v in self.counters.items() if np.ndim(v) > 0}
