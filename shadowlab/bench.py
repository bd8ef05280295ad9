"""``shadowlab bench``: run time against error, measured against Embree in the same run.

For each case (a scene, a view, a set of methods) it renders the G-buffer once, times
the Embree shadow-ray pass ``repeats`` times, then runs each method once cold (its
compile time is reported apart) and ``repeats`` times warm, and reports median
per-stage run times, the ratio of the method's median total to Embree's median, and
the method's error against the reference. Results are saved as JSON for plots.
"""

from __future__ import annotations

import statistics
import time
import tomllib
from importlib import resources
from pathlib import Path

import numpy as np

from . import io
from .analysis import compare_hard, compare_soft
from .methods import compute_shadows, get
from .raycast import reference_shadows, render_gbuffer, soft_reference
from .scene.view import SphereLight

# Rays per pixel of the Embree soft reference's run-time-vs-error curve.
SOFT_CURVE_RAYS = (4, 16, 64)


def _soft_curve(scene, gbuf, light, truth, eps, progress) -> list[dict]:
    """Embree's soft reference at a few ray counts: seconds and error against ``truth``.

    Each point uses another seed than the truth, so its error is its own noise.
    """
    curve = []
    for i, rays in enumerate(SOFT_CURVE_RAYS):
        t0 = time.perf_counter()
        vis = soft_reference(scene, gbuf, light, rays_per_pixel=rays, seed=1000 + i,
                             shadow_eps=eps, progress=progress)
        seconds = time.perf_counter() - t0
        curve.append({"rays": rays, "seconds": seconds, **compare_soft(vis, truth, gbuf.valid)})
    return curve


def embree_seconds_at_error(curve: list[dict], mae: float) -> float | None:
    """Embree soft-reference time for the MAE ``mae``, interpolated log-log along
    ``curve``; None outside the measured range."""
    pts = sorted((c["mae"], c["seconds"]) for c in curve if c["mae"] > 0)
    errs = np.log([p[0] for p in pts])
    secs = np.log([p[1] for p in pts])
    if not pts or not (errs[0] <= np.log(mae) <= errs[-1]):
        return None
    return float(np.exp(np.interp(np.log(mae), errs, secs)))


def default_cases(size: str = "full") -> list[dict]:
    """The built-in cases (``shadowlab/configs/bench.toml``): [{name, overrides}]."""
    text = resources.files("shadowlab").joinpath("configs/bench.toml").read_text()
    table = tomllib.loads(text)
    return table[size]["case"]


def _median_stage_times(runs: list[dict]) -> dict:
    keys = [k for k in runs[0] if not k.endswith("_compile")]
    return {k: statistics.median(r[k] for r in runs) for k in keys}


def bench_case(config, repeats: int = 5, progress: bool = True) -> dict:
    """Benchmark the first frame of ``config`` (a RunConfig); returns a JSON-able dict."""
    from tqdm import tqdm

    scene = config.build_scene()
    view = config.views(scene)[0]
    gbuf = render_gbuffer(scene, view.camera)
    eps = config.reference.shadow_eps
    ref_times = []
    truth = None
    for _ in range(repeats):
        t0 = time.perf_counter()
        truth = reference_shadows(scene, gbuf, view.light, shadow_eps=eps)
        ref_times.append(time.perf_counter() - t0)
    ref_median = statistics.median(ref_times)
    out = {"scene": scene.name, "triangles": scene.num_triangles,
           "resolution": list(view.camera.resolution), "valid_pixels": int(gbuf.valid.sum()),
           "reference": {"median_seconds": ref_median, "runs": ref_times,
                         "rays_per_second": int(truth.size and (gbuf.valid.sum() / ref_median))},
           "methods": {}}
    soft_names = [n for n in config.methods.names if get(n).soft]
    soft_truth = None
    if soft_names and isinstance(view.light, SphereLight):
        rays = config.reference.soft_rays
        t0 = time.perf_counter()
        soft_truth = soft_reference(scene, gbuf, view.light, rays_per_pixel=rays,
                                    seed=config.reference.seed, shadow_eps=eps, progress=progress)
        out["soft_reference"] = {"rays": rays, "seconds": time.perf_counter() - t0,
                                 "curve": _soft_curve(scene, gbuf, view.light, soft_truth, eps,
                                                      progress)}
    for name in config.methods.names:
        if get(name).soft and soft_truth is None:
            out["methods"][name] = {"skipped": "soft method without a sphere or sun light"}
            continue
        opts = dict(config.methods.options.get(name, {}))
        opts.setdefault("shadow_eps", eps)
        cold = compute_shadows(scene, gbuf, view.light, method=name, **opts)
        compile_s = {k: v for k, v in cold.timings.items() if k.endswith("_compile")}
        runs = []
        result = cold
        for _ in tqdm(range(repeats), desc=f"{name}", leave=False, disable=not progress):
            result = compute_shadows(scene, gbuf, view.light, method=name, **opts)
            runs.append(result.timings)
        stages = _median_stage_times(runs)
        counters = result.scalar_counters()
        row = {"stages": stages, "compile": compile_s,
               "compile_seconds": sum(compile_s.values()),
               "median_seconds": stages["total"],
               "ratio_to_reference": stages["total"] / ref_median if ref_median > 0 else None,
               "counters": counters}
        if get(name).soft:
            row["error"] = compare_soft(result.lit, soft_truth, gbuf.valid)
            row["embree_seconds_at_equal_error"] = embree_seconds_at_error(
                out["soft_reference"]["curve"], row["error"]["mae"])
            row.pop("ratio_to_reference")
        else:
            row["error"] = compare_hard(result.lit, truth, gbuf.valid)
        if "tests" in counters and stages["total"] > 0:
            row["tests_per_second"] = counters["tests"] / stages["total"]
        out["methods"][name] = row
    return out


def case_repeats(name: str | None, repeats: int) -> int:
    """``repeats``, capped by the built-in case's own ``repeats`` (bench.toml) if it has one
    (cases whose single run takes minutes)."""
    for size in ("full", "ci"):
        for c in default_cases(size):
            if c["name"] == name and "repeats" in c:
                return max(1, min(repeats, int(c["repeats"])))
    return repeats


def run_bench(configs: list, repeats: int = 5, out: str | Path | None = None,
              progress: bool = True, names: list[str] | None = None) -> dict:
    """Benchmark every config (named by ``names``); write ``out`` (JSON) if given."""
    results = {"provenance": io.provenance(), "repeats": repeats, "cases": []}
    for i, config in enumerate(configs):
        name = names[i] if names else None
        reps = case_repeats(name, repeats)
        case = bench_case(config, reps, progress)
        case["name"] = name if names else config.source
        case["repeats"] = reps
        results["cases"].append(case)
    if out:
        io.write_json(out, results)
    return results


def format_bench(results: dict) -> str:
    lines = []
    for case in results["cases"]:
        w, h = case["resolution"]
        ref = case["reference"]["median_seconds"]
        lines.append(f"[{case.get('name', '')}] {case['scene']}  {case['triangles']} triangles  {w}x{h}  "
                     f"Embree shadow rays: {1000 * ref:.1f} ms "
                     f"(median of {case.get('repeats', results['repeats'])})")
        lines.append(f"  {'method':<16} {'run ms':>9} {'compile s':>9} {'x Embree':>9} "
                     f"{'mismatch':>9} {'Gtests/s':>9}  stages (ms)")
        if "soft_reference" in case:
            curve = ", ".join(f"{c['rays']} rays {1000 * c['seconds']:.0f} ms MAE {c['mae']:.4f}"
                              for c in case["soft_reference"]["curve"])
            lines.append(f"  Embree soft reference: {curve} (truth: "
                         f"{case['soft_reference']['rays']} rays)")
        for name, m in case["methods"].items():
            if "skipped" in m:
                lines.append(f"  {name:<16} skipped: {m['skipped']}")
                continue
            if "mae" in m["error"]:
                at = m["embree_seconds_at_equal_error"]
                lines.append(f"  {name:<16} {1000 * m['median_seconds']:>9.1f} "
                             f"{m['compile_seconds']:>9.2f}  MAE {m['error']['mae']:.4f} "
                             f"RMSE {m['error']['rmse']:.4f} max {m['error']['max_error']:.3f} "
                             f"SSIM {m['error']['ssim']:.4f}; Embree at equal MAE: "
                             f"{'-' if at is None else f'{1000 * at:.0f} ms'}")
                continue
            stages = ", ".join(f"{k} {1000 * v:.1f}" for k, v in m["stages"].items()
                               if k != "total")
            rate = m.get("tests_per_second")
            lines.append(f"  {name:<16} {1000 * m['median_seconds']:>9.1f} "
                         f"{m['compile_seconds']:>9.2f} {m['ratio_to_reference']:>9.2f} "
                         f"{m['error']['mismatches']:>9} "
                         f"{'-' if rate is None else f'{rate / 1e9:.2f}':>9}  {stages}")
    return "\n".join(lines)
