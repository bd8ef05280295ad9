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
        reference: the array [H, W] it is judged by, when attached (``with_reference``;
            ``harness.evaluate`` attaches its reference), else None.
        valid: bool [H, W] pixels that see geometry, when attached, else None.

    In Jupyter a result shows itself (``_repr_html_``, ``_repr_png_``): its counters and
    times, and the panels of :meth:`plot`.
    """

    lit: np.ndarray
    counters: dict
    timings: dict
    method: str = ""
    options: dict = dataclasses.field(default_factory=dict)
    reference: np.ndarray | None = dataclasses.field(default=None, repr=False)
    valid: np.ndarray | None = dataclasses.field(default=None, repr=False)

    def scalar_counters(self) -> dict:
        """Counters without the per-pixel maps (JSON-friendly)."""
        return {k: v for k, v in self.counters.items() if np.ndim(v) == 0}

    def counter_maps(self) -> dict:
        """The per-pixel counter maps, arrays [H, W]."""
        return {k: np.asarray(v) for k, v in self.counters.items() if np.ndim(v) > 0}

    def with_reference(self, reference: np.ndarray, valid: np.ndarray | None = None
                       ) -> "ShadowResult":
        """A copy with ``reference`` (bool or float [H, W], the array this result is
        judged by) and ``valid`` (bool [H, W]) attached, for display."""
        reference = np.asarray(reference)
        if reference.shape != np.shape(self.lit):
            raise ValueError(f"reference shape {reference.shape} differs from lit "
                             f"{np.shape(self.lit)}")
        return dataclasses.replace(self, reference=reference,
                                   valid=None if valid is None else np.asarray(valid, bool))

    def plot(self, reference: np.ndarray | None = None, valid: np.ndarray | None = None,
             counter: str | None = None):
        """A quick look: lit (or visibility), the error against ``reference`` (default:
        the attached one, if any) and one per-pixel counter heat map (``counter``,
        default ``tests_per_pixel`` or the first map). Returns a matplotlib Figure."""
        from ..analysis.plots import quick_look

        ref = self.reference if reference is None else reference
        return quick_look(self.lit, reference=ref,
                          valid=self.valid if valid is None else valid,
                          counter_maps=self.counter_maps(), counter=counter,
                          title=self.method)

    def _repr_png_(self) -> bytes:
        from ..analysis.plots import figure_png

        return figure_png(self.plot())

    def _repr_html_(self) -> str:
        import base64
        import html

        def fmt(v):
            return f"{v:.6g}" if isinstance(v, float) else str(v)

        rows = [("method", self.method or "(unnamed)"),
                ("shape", " x ".join(map(str, np.shape(self.lit))))]
        rows += [(k, fmt(v)) for k, v in self.scalar_counters().items()]
        rows += [(f"{k} s", fmt(v)) for k, v in self.timings.items()]
        table = "".join(f"<tr><td>{html.escape(str(k))}</td><td>{html.escape(str(v))}</td></tr>"
                        for k, v in rows)
        png = base64.b64encode(self._repr_png_()).decode("ascii")
        return (f"<div><table>{table}</table>"
                f'<img src="data:image/png;base64,{png}" alt="quick look"/></div>')
