"""``shadowlab bench``: run time against error, measured against Embree in the same run.

For each case (a scene, a view, a set of methods) it renders the G-buffer once, times
the Embree shadow-ray pass ``repeats`` times, then evaluates each method with
``harness.evaluate`` (one warm-up call whose compile time is reported apart, then
``repeats`` warm calls), and reports median per-stage run times, the ratio of the
method's median total to Embree's median, and the method's error against the
reference its kind calls for. Results are saved as JSON for plots.

Two ratios per hard method (docs/benchmarks.md, "Protocol"):

- **static** (``ratio_to_reference``): Embree's BVH is built once, before timing, and
  excluded; the method keeps what it caches across frames (adjacency, local scene) and
  runs with its ``static_options`` (``MethodInfo``: e.g. PSV's ``reuse_tree``, which
  keeps the light's TOP tree), as a static scene under a static light would; the case's
  own options override them;
- **dynamic** (``dynamic_ratio``): every timed call starts with every per-scene cache
  dropped (``scene.caches.drop``): Embree pays its BVH build plus the trace, the method
  its whole frame (wall clock of ``compute_shadows``, including what it would cache).

The static ratio is also measured **paired** (``paired_ratio``, reported next to it, not
used for the target verdict): the Embree pass (BVH kept) runs before each of a hard
method's warm calls, and the method's median is divided by the median of those passes.
A machine whose speed drifts between the case's first Embree passes and a method's runs
(a shared or throttled one) slows both sides of the paired ratio alike; each side also
starts with the caches the other left, unlike the back-to-back passes of the static
ratio.
"""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np

from ..core import io
from ..core.machine import (BUSY_LOAD_PER_CORE, cpu_clock, machine_record,  # noqa: F401
                             machine_state, steal_between)
from ..scene import caches
from ..analysis import compare_soft
from .evaluate import References, evaluate
from ..methods import MethodKind, compute_shadows, get, light_problem
from ..reference.raycast import reference_shadows, render_gbuffer, soft_reference
from .bench_cases import (builtin_case, case_repeats, case_target, default_cases,  # noqa: F401
                          target_verdict)

# Rays per pixel of the Embree soft reference's run-time-vs-error curve.
SOFT_CURVE_RAYS = (4, 16, 64)


def _soft_curve(scene, gbuf, light, truth, eps, progress,
                rays_list=SOFT_CURVE_RAYS) -> list[dict]:
    """Embree's soft reference at a few ray counts (``rays_list``): seconds and error
    against ``truth`` (float [H, W]), one dict per ray count.

    Each point uses another seed than the truth, so its error is its own noise.
    """
    curve = []
    for i, rays in enumerate(rays_list):
        t0 = time.perf_counter()
        vis = soft_reference(scene, gbuf, light, rays_per_pixel=rays, seed=1000 + i,
                             shadow_eps=eps, progress=progress)
        seconds = time.perf_counter() - t0
        curve.append({"rays": rays, "seconds": seconds, **compare_soft(vis, truth, gbuf.valid)})
    return curve


#: the soft metrics Embree is matched on (lower is better; SSIM as 1 - SSIM)
EQUAL_ERROR_METRICS = ("mae", "rmse", "max_error", "ssim", "penumbra_mae", "penumbra_rmse",
                       "penumbra_max_error", "penumbra_ssim")


def _as_error(metric: str, value: float) -> float:
    return 1.0 - value if metric.endswith("ssim") else value


def embree_seconds_at_error(curve: list[dict], value: float, metric: str = "mae") -> float | None:
    """Embree soft-reference time at which its ``metric`` equals ``value``, interpolated
    log-log along ``curve`` (its points sorted by that error; SSIM as 1 - SSIM); None
    outside the measured range or where the value is not finite."""
    if value is None or not np.isfinite(value):
        return None
    target = _as_error(metric, value)
    pts = sorted((_as_error(metric, c[metric]), c["seconds"]) for c in curve
                 if metric in c and np.isfinite(c[metric]) and _as_error(metric, c[metric]) > 0)
    if not pts or target <= 0:
        return None
    errs = np.log([p[0] for p in pts])
    secs = np.log([p[1] for p in pts])
    if not (errs[0] <= np.log(target) <= errs[-1]):
        return None
    return float(np.exp(np.interp(np.log(target), errs, secs)))


def embree_seconds_at_equal(curve: list[dict], error: dict) -> dict:
    """{metric: Embree seconds at the method's value of that metric, or None} for every
    metric of ``EQUAL_ERROR_METRICS`` the method's ``error`` has."""
    return {m: embree_seconds_at_error(curve, error[m], m) for m in EQUAL_ERROR_METRICS
            if m in error}


def embree_seconds_beyond(curve: list[dict], error: dict) -> dict:
    """{metric: seconds of Embree's most accurate curve point in that metric} for every
    metric of ``EQUAL_ERROR_METRICS`` on which the method's ``error`` is better than the
    whole curve: Embree would need more rays than that point to match it, so this is a
    lower bound of its time at equal error (where ``embree_seconds_at_equal`` has None)."""
    out = {}
    for m in EQUAL_ERROR_METRICS:
        pts = [(_as_error(m, c[m]), c["seconds"]) for c in curve
               if m in c and np.isfinite(c[m])]
        if m in error and np.isfinite(error[m]) and pts and \
                _as_error(m, error[m]) < min(p[0] for p in pts):
            out[m] = min(pts)[1]
    return out


def bench_case(config, repeats: int = 5, progress: bool = True) -> dict:
    """Benchmark the first frame of ``config`` (a RunConfig); returns a JSON-able dict."""
    case_clock = cpu_clock()
    scene = config.build_scene()
    view = config.views(scene)[0]
    gbuf = render_gbuffer(scene, view.camera)
    eps = config.reference.shadow_eps
    refs = References(scene, gbuf, view.light, shadow_eps=eps,
                      soft_rays=config.reference.soft_rays, seed=config.reference.seed,
                      progress=progress)
    truth = refs.hard(repeats + 1)           # the first pass builds the BVH: not timed
    ref_times = refs.hard_seconds[1:]
    ref_median = float(np.median(ref_times))

    def embree_pass():
        return reference_shadows(scene, gbuf, view.light, shadow_eps=eps)
    ref_dynamic = dynamic_seconds(scene, embree_pass, repeats)     # ends with the BVH built
    bvh_dropped = False
    out = {"scene": scene.name, "triangles": scene.num_triangles,
           "resolution": list(view.camera.resolution), "valid_pixels": int(gbuf.valid.sum()),
           "reference": {"median_seconds": ref_median, "runs": ref_times,
                         "first_seconds": refs.hard_seconds[0],
                         "dynamic_median_seconds": float(np.median(ref_dynamic)),
                         "dynamic_runs": ref_dynamic,
                         "rays_per_second": int(truth.size and (gbuf.valid.sum() / ref_median))},
           "methods": {}}
    runnable = {n: light_problem(n, view.light) for n in config.methods.names}
    if any(get(n).soft and r is None for n, r in runnable.items()):
        soft_truth = refs.soft()
        out["soft_reference"] = {"rays": refs.soft_rays, "seconds": refs.soft_seconds[0],
                                 "curve": _soft_curve(scene, gbuf, view.light, soft_truth, eps,
                                                      progress)}
    for name in config.methods.names:
        if runnable[name] is not None:
            out["methods"][name] = {"skipped": runnable[name]}
            continue
        options = dict(config.methods.options.get(name, {}))
        written = config.methods.given.get(name, ())
        static = {k: v for k, v in get(name).static_options.items() if k not in written}
        soft = get(name).kind is MethodKind.SOFT
        if not soft and bvh_dropped:     # rebuilt untimed: the paired passes time traces
            embree_pass()
            bvh_dropped = False
        clock = cpu_clock()
        ev = evaluate(scene, gbuf, view.light, name, {**options, **static}, reference=refs,
                      repeats=repeats, between=None if soft else embree_pass)
        steal = steal_between(clock, cpu_clock())       # over its compile and warm runs
        options.setdefault("shadow_eps", eps)
        # soft methods are compared at equal error, not by ratio: no dynamic frame for them
        dynamic = [] if soft else dynamic_seconds(
            scene, lambda: compute_shadows(scene, gbuf, view.light, method=name, **options),
            repeats)
        bvh_dropped = bvh_dropped or bool(dynamic)      # the dynamic runs drop the caches
        stages = {k: v for k, v in ev.timings.items() if not k.endswith("_compile")}
        compile_s = {k: v for k, v in ev.timings.items() if k.endswith("_compile")}
        counters = ev.result.scalar_counters()
        row = {"static_options": static, "stages": stages, "compile": compile_s,
               "compile_seconds": ev.compile_seconds,
               "median_seconds": ev.seconds,
               "ratio_to_reference": ev.seconds / ref_median if ref_median > 0 else None,
               "dynamic_median_seconds": float(np.median(dynamic)) if dynamic else None,
               "dynamic_runs": dynamic,
               "dynamic_ratio": float(np.median(dynamic)) / out["reference"][
                   "dynamic_median_seconds"] if dynamic else None,
               "counters": counters, "error": ev.error}
        if steal is not None:
            row["steal"] = steal
        if ev.between_seconds:
            paired = float(np.median(ev.between_seconds))
            row["paired_reference_runs"] = ev.between_seconds
            row["paired_reference_median_seconds"] = paired
            row["paired_ratio"] = ev.seconds / paired if paired > 0 else None
        if ev.kind is MethodKind.SOFT:
            curve = out["soft_reference"]["curve"]
            row["embree_seconds_at_equal_error"] = embree_seconds_at_error(
                curve, row["error"]["mae"])
            row["embree_seconds_at_equal"] = embree_seconds_at_equal(curve, row["error"])
            row["embree_seconds_at_equal_lower_bound"] = embree_seconds_beyond(curve,
                                                                               row["error"])
            row.pop("ratio_to_reference")
            row.pop("dynamic_ratio")
        if "tests" in counters and ev.seconds > 0:
            row["tests_per_second"] = counters["tests"] / ev.seconds
        out["methods"][name] = row
    steal = steal_between(case_clock, cpu_clock())
    if steal is not None:
        out["steal"] = steal
    return out


def dynamic_seconds(scene, call, repeats: int) -> list[float]:
    """Wall-clock seconds of ``call()`` ``repeats`` times, each after every per-scene
    cache of ``scene`` was dropped (a frame whose geometry has just changed)."""
    times = []
    for _ in range(max(repeats, 1)):
        caches.drop(scene)
        t0 = time.perf_counter()
        call()
        times.append(time.perf_counter() - t0)
    return times


def run_bench(configs: list, repeats: int = 5, out: str | Path | None = None,
              progress: bool = True, names: list[str] | None = None,
              note: str | None = None) -> dict:
    """Benchmark every config (named by ``names``); write ``out`` (JSON) if given.
    The machine's load before and after is recorded (:func:`machine_record`)."""
    before = machine_state()
    results = {"provenance": io.provenance(), "repeats": repeats, "cases": []}
    for i, config in enumerate(configs):
        name = names[i] if names else None
        reps = case_repeats(name, repeats)
        case = bench_case(config, reps, progress)
        case["name"] = name if names else config.source
        case["repeats"] = reps
        target = case_target(name)
        if target is not None:
            case["target_ratio"] = target
        results["cases"].append(case)
    results["machine"] = machine_record(before, machine_state(), note)
    if out:
        io.write_json(out, results)
    return results


def format_bench(results: dict) -> str:
    lines = []
    m = results.get("machine")
    if m and m.get("note"):
        lines.append(f"machine: {m['note']}")
    for case in results["cases"]:
        w, h = case["resolution"]
        ref = case["reference"]["median_seconds"]
        lines.append(f"[{case.get('name', '')}] {case['scene']}  {case['triangles']} triangles  {w}x{h}  "
                     f"Embree shadow rays: {1000 * ref:.1f} ms "
                     f"(median of {case.get('repeats', results['repeats'])})")
        lines.append(f"  Embree dynamic (BVH build + trace): "
                     f"{1000 * case['reference']['dynamic_median_seconds']:.1f} ms")
        target = case.get("target_ratio")
        if target is not None:
            lines.append(f"  target: at most {target:g}x Embree (static) per method")
        lines.append(f"  {'method':<16} {'run ms':>9} {'compile s':>9} {'x Embree':>9} "
                     f"{'paired x':>9} {'dynamic x':>9} {'mismatch':>9} {'Gtests/s':>9}  "
                     f"stages (ms)")
        if "soft_reference" in case:
            curve = ", ".join(f"{c['rays']} rays {1000 * c['seconds']:.0f} ms MAE {c['mae']:.4f}"
                              for c in case["soft_reference"]["curve"])
            lines.append(f"  Embree soft reference: {curve} (truth: "
                         f"{case['soft_reference']['rays']} rays)")
        for name, m in case["methods"].items():
            if "skipped" in m:
                lines.append(f"  {name:<16} skipped: {m['skipped']}")
                continue
            if m.get("static_options"):
                lines.append(f"  {name:<16} static: " + ", ".join(
                    f"{k}={v}" for k, v in m["static_options"].items()))
            if "mae" in m["error"]:
                at = m["embree_seconds_at_equal_error"]
                lines.append(f"  {name:<16} {1000 * m['median_seconds']:>9.1f} "
                             f"{m['compile_seconds']:>9.2f}  MAE {m['error']['mae']:.4f} "
                             f"RMSE {m['error']['rmse']:.4f} max {m['error']['max_error']:.3f} "
                             f"SSIM {m['error']['ssim']:.4f}; Embree at equal MAE: "
                             f"{'-' if at is None else f'{1000 * at:.0f} ms'}")
                e = m["error"]
                if "penumbra_mae" in e:
                    lines.append(f"  {'':<16} penumbra ({e['penumbra_pixels']} px): MAE "
                                 f"{e['penumbra_mae']:.4f} RMSE {e['penumbra_rmse']:.4f} max "
                                 f"{e['penumbra_max_error']:.3f} SSIM {e['penumbra_ssim']:.4f}")
                equal = m.get("embree_seconds_at_equal", {})
                beyond = m.get("embree_seconds_at_equal_lower_bound", {})

                def at_equal(k, v):
                    if v is not None:
                        return f"{1000 * v:.0f} ms"
                    # better than Embree's most accurate point: more than its time
                    return f"> {1000 * beyond[k]:.0f} ms" if k in beyond else "-"

                if equal:
                    lines.append(f"  {'':<16} Embree at equal: " + ", ".join(
                        f"{k} {at_equal(k, v)}" for k, v in equal.items()))
                continue
            stages = ", ".join(f"{k} {1000 * v:.1f}" for k, v in m["stages"].items()
                               if k != "total")
            rate = m.get("tests_per_second")
            verdict = target_verdict(m["ratio_to_reference"], target)
            paired = m.get("paired_ratio")
            lines.append(f"  {name:<16} {1000 * m['median_seconds']:>9.1f} "
                         f"{m['compile_seconds']:>9.2f} {m['ratio_to_reference']:>9.2f} "
                         f"{'-' if paired is None else f'{paired:.2f}':>9} "
                         f"{m['dynamic_ratio']:>9.2f} {m['error']['mismatches']:>9} "
                         f"{'-' if rate is None else f'{rate / 1e9:.2f}':>9}  {stages}"
                         + (f"  [target {verdict}]" if verdict else ""))
    return "\n".join(lines)
