"""One evaluation entry point: a method, its reference, its metric, one timing protocol.

Timing protocol (every caller gets the same): ``warmup`` calls first, whose compile
time (the ``<stage>_compile`` entries) is kept apart, then ``repeats`` warm calls; the
reported run time of each stage and of ``total`` is the median over the warm calls
(seconds, compile excluded). With ``repeats = 0`` the warm-up call is the measurement.
A caller may pass ``between``: a call timed right before each warm call (the bench times
the Embree pass there, so that each method run has a reference run next to it).

Reference and metric are chosen here and nowhere else, from the method's kind:

- ``exact`` and ``approximate`` hard methods: the Embree shadow-ray mask
  (``reference_shadows``), compared with ``analysis.compare_hard`` on valid pixels plus
  ``unexplained``: mismatches on no shadow boundary (``analysis.boundary``; None when
  there are more than ``EXPLAIN_LIMIT`` mismatches to examine);
- ``soft`` methods: the Monte Carlo visibility (``soft_reference``), compared with
  ``analysis.compare_soft`` (MAE, RMSE, max error, SSIM over the valid pixels, and the
  same over the penumbra region: true visibility strictly between 0 and 1, dilated).
"""

from __future__ import annotations

import dataclasses
import statistics
import time
from typing import Callable

import numpy as np

from ..analysis import compare_hard, compare_soft
from ..core import executables
from ..reference.boundary import unexplained_count
from ..methods.interface import DEFAULT_SHADOW_EPS, MethodKind
from ..methods.registry import compute_shadows, get
from ..core.result import ShadowResult

DEFAULT_WARMUP = 1      # warm-up calls (compile kept apart)
DEFAULT_REPEATS = 3     # warm calls whose median is reported
EXPLAIN_LIMIT = 200     # mismatched pixels examined for lying on a shadow boundary


class References:
    """The references of one frame (scene, G-buffer, light), computed on first use.

    Args:
        shadow_eps: the Embree reference's cap-plane bias (fraction of the diagonal).
        soft_rays, seed: rays per pixel and seed of the soft reference.
        hard, soft: already computed references (bool / float [H, W]) to use instead.

    ``hard_seconds`` and ``soft_seconds`` list the wall-clock seconds of each pass run.
    """

    def __init__(self, scene, gbuf, light, *, shadow_eps: float = DEFAULT_SHADOW_EPS,
                 soft_rays: int = 64, seed: int = 0, hard: np.ndarray | None = None,
                 soft: np.ndarray | None = None, progress: bool = False):
        self.scene, self.gbuf, self.light = scene, gbuf, light
        self.shadow_eps, self.soft_rays, self.seed = shadow_eps, soft_rays, seed
        self.progress = progress
        self._hard, self._soft = hard, soft
        self.hard_seconds: list[float] = []
        self.soft_seconds: list[float] = []

    def hard(self, repeats: int = 1) -> np.ndarray:
        """bool [H, W] lit mask of Embree shadow rays; the pass is run (and timed) until
        it has run ``repeats`` times."""
        from ..reference.raycast import reference_shadows

        while self._hard is None or len(self.hard_seconds) < repeats:
            t0 = time.perf_counter()
            self._hard = reference_shadows(self.scene, self.gbuf, self.light,
                                           shadow_eps=self.shadow_eps)
            self.hard_seconds.append(time.perf_counter() - t0)
        return self._hard

    def soft(self) -> np.ndarray:
        """float [H, W] visibility in [0, 1] of the area light (Monte Carlo, Embree)."""
        from ..reference.raycast import soft_reference

        if self._soft is None:
            t0 = time.perf_counter()
            self._soft = soft_reference(self.scene, self.gbuf, self.light,
                                        rays_per_pixel=self.soft_rays, seed=self.seed,
                                        shadow_eps=self.shadow_eps, progress=self.progress)
            self.soft_seconds.append(time.perf_counter() - t0)
        return self._soft

    @property
    def has_soft(self) -> bool:
        return self._soft is not None

    def for_kind(self, kind: MethodKind) -> np.ndarray:
        """The reference a method of ``kind`` is judged by."""
        return self.soft() if kind is MethodKind.SOFT else self.hard()


def hard_metric(result: ShadowResult, truth: np.ndarray, refs: References,
                mask: np.ndarray | None = None) -> dict:
    """``compare_hard`` on valid pixels (inside ``mask`` bool [H, W] if given) plus
    ``unexplained`` (mismatches on no shadow boundary; None above ``EXPLAIN_LIMIT``)."""
    keep = refs.gbuf.valid if mask is None else refs.gbuf.valid & mask
    error = compare_hard(result.lit, truth, keep)
    error["unexplained"] = (
        unexplained_count(refs.scene, refs.gbuf, refs.light, result.lit, truth, mask,
                          refs.shadow_eps, limit=EXPLAIN_LIMIT)
        if error["mismatches"] <= EXPLAIN_LIMIT else None)
    return error


def soft_metric(result: ShadowResult, truth: np.ndarray, refs: References) -> dict:
    """``compare_soft``: MAE, RMSE, max error and SSIM on valid pixels and on the
    penumbra region (``penumbra_*``)."""
    return compare_soft(result.lit, truth, refs.gbuf.valid)


def default_metric(kind: MethodKind) -> Callable:
    """The metric a method of ``kind`` is judged by."""
    return soft_metric if kind is MethodKind.SOFT else hard_metric


@dataclasses.dataclass
class Evaluation:
    """What :func:`evaluate` measured.

    Attributes:
        result: the last call's ShadowResult (lit [H, W], counters, its own timings),
            with the reference and valid mask attached (its display shows the error).
        error: the metric's dict (see the module docstring).
        timings: seconds: the median over the warm calls of each stage and of ``total``
            (compile excluded), and ``<stage>_compile`` summed over all calls.
        cold: the first call's timings (compile included as ``<stage>_compile``).
        runs: the timings of each warm call.
        reference: the reference array the metric compared against.
        between_seconds: wall-clock seconds of each ``between`` call (one before each
            warm call; empty without ``between``).
    """

    method: str
    kind: MethodKind
    result: ShadowResult
    error: dict
    timings: dict
    cold: dict
    runs: list
    reference: np.ndarray
    between_seconds: list = dataclasses.field(default_factory=list)

    @property
    def seconds(self) -> float:
        """Median warm run time of the whole method (compile excluded)."""
        return self.timings["total"]

    @property
    def compile_seconds(self) -> float:
        return float(sum(v for k, v in self.timings.items() if k.endswith("_compile")))

    @property
    def warm(self) -> bool:
        """False when no warm call was made (``repeats = 0``)."""
        return bool(self.runs)


def median_timings(runs: list[dict], calls: list[dict]) -> dict:
    """Per-stage medians of ``runs`` (a stage absent from a run counts 0 s there), and
    ``<stage>_compile`` summed over ``calls``."""
    stages = sorted({k for r in runs for k in r if not k.endswith("_compile")},
                    key=lambda k: (k == "total", k))
    out = {k: statistics.median(r.get(k, 0.0) for r in runs) for k in stages}
    for k in sorted({k for r in calls for k in r if k.endswith("_compile")}):
        out[k] = float(sum(r.get(k, 0.0) for r in calls))
    return out


def evaluate(scene, gbuf, light, method: str, options: dict | None = None,
             reference: References | np.ndarray | None = None,
             metric: Callable | None = None, repeats: int = DEFAULT_REPEATS,
             warmup: int = DEFAULT_WARMUP, between: Callable[[], object] | None = None
             ) -> Evaluation:
    """Run ``method`` under the timing protocol and measure its error.

    Args:
        options: method options (``shadow_eps`` defaults to the reference's).
        reference: a :class:`References` of this frame (shared between methods), a
            reference array [H, W], or None (computed here).
        metric: ``fn(result, truth, refs) -> dict``; default by the method's kind.
        repeats: warm calls (median reported); 0 measures the warm-up call itself.
        warmup: calls before the warm ones (at least one call is always made).
        between: called (and timed) before each warm call: the calls alternate, so a
            machine whose speed drifts during the runs slows both alike.

    Raises:
        MethodError: unknown method or option, bad value, or a light it cannot use.
        TypeError: ``between`` is neither None nor callable (before any work).
    """
    if between is not None and not callable(between):
        raise TypeError(f"evaluate: 'between' must be a callable taking no arguments or "
                        f"None, not {type(between).__name__}")
    info = get(method)
    info.check_light(light)
    options = dict(options or {})
    if isinstance(reference, References):
        refs = reference
    else:
        eps = options.get("shadow_eps", DEFAULT_SHADOW_EPS)
        given = {} if reference is None else {
            "soft" if info.kind is MethodKind.SOFT else "hard": np.asarray(reference)}
        refs = References(scene, gbuf, light, shadow_eps=eps, **given)
    options.setdefault("shadow_eps", refs.shadow_eps)
    info.resolve_options(options)              # refuse bad options before any work
    executables.guard()                        # before the warm-up, never between warm calls
    calls = []
    result = None
    for _ in range(max(warmup, 0 if repeats else 1)):
        result = compute_shadows(scene, gbuf, light, method=method, **options)
        calls.append(result.timings)
    runs, between_seconds = [], []
    for _ in range(repeats):
        if between is not None:
            t0 = time.perf_counter()
            between()
            between_seconds.append(time.perf_counter() - t0)
        result = compute_shadows(scene, gbuf, light, method=method, **options)
        runs.append(result.timings)
    all_calls = calls + runs
    timings = median_timings(runs or all_calls[:1], all_calls)
    truth = refs.for_kind(info.kind)
    error = (metric or default_metric(info.kind))(result, truth, refs)
    result = result.with_reference(truth, refs.gbuf.valid)     # for its display
    return Evaluation(method, info.kind, result, error, timings, all_calls[0], runs, truth,
                      between_seconds)


__all__ = ["DEFAULT_REPEATS", "DEFAULT_WARMUP", "EXPLAIN_LIMIT", "Evaluation", "References",
           "default_metric", "evaluate", "hard_metric", "median_timings", "soft_metric"]
