"""``shadowlab run``: scene -> frames -> G-buffer -> reference and methods -> outputs.

For every frame of the configured view or animation it renders the G-buffer with
Embree, computes the exact reference (timed: it is the bar every method is measured
against), and evaluates every configured method with ``harness.evaluate``: the
reference and metric its kind calls for, and the harness's timing protocol (a warm-up
call with compile time kept apart, then the median of warm calls; with several frames
the first frame warms up and each frame is one warm call). Outputs (all written
atomically, and only once the run has finished):

- ``metrics.json``: the resolved config, provenance, per-frame and summary metrics;
- ``shadows.npz``: reference and method masks [F, H, W], valid masks, counter maps;
- ``figures/``: reference vs method vs error map, and per-pixel counter heat maps.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np

from ..core import io
from .evaluate import DEFAULT_REPEATS, EXPLAIN_LIMIT, References, evaluate
from ..methods import MethodError, light_problem
from ..reference.raycast import render_gbuffer

__all__ = ["EXPLAIN_LIMIT", "RunOutput", "format_skipped", "format_table", "run",
           "runnable_methods", "skipped_receivers"]


@dataclasses.dataclass
class RunOutput:
    """What a run produced: the metrics dict, the arrays, and the files written."""

    metrics: dict
    arrays: dict
    files: list


def _method_summary(frames: list[dict], name: str) -> dict:
    rows = [f["methods"][name] for f in frames]
    times = [r["timings"]["total"] for r in rows]
    ratios = [r["timings"]["total"] / f["reference_seconds"] for r, f in zip(rows, frames)
              if f["reference_seconds"] > 0]
    out = {"frames": len(rows), "median_seconds": float(np.median(times)),
           "compile_seconds": float(sum(v for r in rows for k, v in r["timings"].items()
                                        if k.endswith("_compile"))),
           "median_ratio_to_reference": float(np.median(ratios)) if ratios else None}
    if "mismatches" in rows[0]["error"]:
        out["mismatches"] = int(sum(r["error"]["mismatches"] for r in rows))
        unexplained = [r["error"]["unexplained"] for r in rows]
        out["unexplained"] = None if None in unexplained else int(sum(unexplained))
        out["max_mismatch_fraction"] = float(max(r["error"]["mismatch_fraction"] for r in rows))
    else:
        out["mae"] = float(np.mean([r["error"]["mae"] for r in rows]))
        out["max_error"] = float(max(r["error"]["max_error"] for r in rows))
    if "tests" in rows[0]["counters"]:
        out["tests"] = int(sum(r["counters"]["tests"] for r in rows))
    return out


def runnable_methods(config, views) -> tuple[list[str], dict[str, str]]:
    """The methods to run on these views, and {name: reason} for those skipped.

    Soft-shadow methods need an area light (SphereLight). With ``methods.names = "all"``
    they are skipped (and reported) on a point or directional light; named explicitly
    they are an error, before any work is done.
    """
    light = views[0].light
    methods, skipped = [], {}
    for name in config.methods.names:
        reason = light_problem(name, light)
        if reason is not None:
            if not config.methods.all:
                raise MethodError(f"method {name!r} {reason}")
            skipped[name] = reason
            continue
        methods.append(name)
    return methods, skipped


def skipped_receivers(gbuf, light) -> dict:
    """Pixels every method skips in this frame: ``sky`` (no surface) and ``back_facing``
    (a surface facing away from the light, unlit without a test)."""
    from ..reference.raycast import facing_samples
    from ..scene.view import hard_light

    facing = len(facing_samples(gbuf, hard_light(light))[0])
    valid = int(gbuf.valid.sum())
    return {"sky": int(gbuf.valid.size - valid), "back_facing": valid - facing}


def format_skipped(metrics: dict, limit: int = 8) -> list[str]:
    """Per frame (the first ``limit``): the pixels skipped and, per method run with the
    ``cull_casters`` option, the triangles the shared culling stage removed."""
    lines = []
    frames = metrics["frames"]
    for f in frames[:limit]:
        sk = f.get("skipped")
        if sk is None:
            continue
        culled = [f"{name} {row['counters']['culled_casters']}"
                  for name, row in f["methods"].items() if "culled_casters" in row["counters"]]
        lines.append(f"frame {f['frame']}: skipped {sk['sky']} sky and {sk['back_facing']} "
                     f"back-facing pixels" + (f"; casters culled: {', '.join(culled)}"
                                              if culled else ""))
    if len(frames) > limit:
        lines.append(f"... {len(frames) - limit} more frames in metrics.json")
    return lines


def run(config, out_dir: str | Path | None = None, progress: bool = True,
        write: bool = True, repeats: int | None = None, warmup: int = 1) -> RunOutput:
    """Run ``config`` (a ``shadowlab.config.RunConfig``); write outputs to ``out_dir``
    (default ``config.output.dir``) unless ``write`` is False.

    Timing: before its first frame each method is called ``warmup`` times (compile time
    kept apart), then ``repeats`` warm calls per frame give the frame's median times
    (default: ``harness.DEFAULT_REPEATS`` for one frame, 1 for an animation, whose
    summary is the median over frames).
    """
    from tqdm import tqdm

    scene = config.build_scene()
    views = config.views(scene)
    methods, skipped = runnable_methods(config, views)
    if repeats is None:
        repeats = DEFAULT_REPEATS if len(views) == 1 else 1
    ref_cfg = config.reference
    frames: list[dict] = []
    arrays: dict[str, list] = {"valid": [], "reference": []}
    soft_truth = {}
    bar = tqdm(views, desc=f"{scene.name}", unit="frame", disable=not progress)
    for index, view in enumerate(bar):
        gbuf = render_gbuffer(scene, view.camera)
        refs = References(scene, gbuf, view.light, shadow_eps=ref_cfg.shadow_eps,
                          soft_rays=ref_cfg.soft_rays, seed=ref_cfg.seed)
        truth = refs.hard()
        arrays["valid"].append(gbuf.valid)
        arrays["reference"].append(truth)
        frame = {"frame": index, "valid_pixels": int(gbuf.valid.sum()),
                 "reference_lit": int(truth.sum()), "reference_seconds": refs.hard_seconds[0],
                 "skipped": skipped_receivers(gbuf, view.light), "methods": {}}
        for name in methods:
            bar.set_postfix_str(name)
            ev = evaluate(scene, gbuf, view.light, name, config.methods.options.get(name, {}),
                          reference=refs, repeats=repeats, warmup=warmup if index == 0 else 0)
            res = ev.result
            frame["methods"][name] = {"error": ev.error, "counters": res.scalar_counters(),
                                      "timings": ev.timings, "cold_timings": ev.cold,
                                      "warm_runs": len(ev.runs), "options": res.options}
            arrays.setdefault(f"{name}/lit", []).append(res.lit)
            for key, value in res.counter_maps().items():
                arrays.setdefault(f"{name}/{key}", []).append(value)
        if refs.has_soft:
            soft_truth[index] = refs.soft()
        frames.append(frame)
    bar.close()
    stacked = {k: np.stack(v) for k, v in arrays.items()}
    for index, truth in soft_truth.items():
        stacked.setdefault("soft_reference", np.zeros(stacked["valid"].shape))[index] = truth
    metrics = {
        "config": config.to_dict(),
        "provenance": io.provenance(),
        "scene": {"name": scene.name, "report": dataclasses.asdict(scene.report())},
        "frames": frames,
        "summary": {name: _method_summary(frames, name) for name in methods},
        "skipped": skipped,
        "timing": {"warmup": warmup, "repeats": repeats,
                   "protocol": "median of warm calls per frame; compile kept apart"},
    }
    files = []
    if write:
        out = Path(out_dir or config.output.dir)
        files += [io.write_json(out / "metrics.json", metrics),
                  io.write_npz(out / "shadows.npz", stacked)]
        if config.output.figures:
            files += _figures(stacked, methods, out / "figures")
    return RunOutput(metrics, stacked, files)


def _figures(arrays: dict, methods: list[str], folder: Path) -> list[Path]:
    from ..analysis import plots

    files = []
    valid = arrays["valid"]
    # The frame with the most reference mismatches summed over methods, else frame 0.
    for name in methods:
        lit = arrays[f"{name}/lit"]
        if lit.dtype == bool:
            errs = [(lit[i] != arrays["reference"][i])[valid[i]].sum() for i in range(len(lit))]
            f = int(np.argmax(errs)) if max(errs) > 0 else 0
            fig = plots.lit_and_error(lit[f], arrays["reference"][f], valid[f],
                                      title=f"{name} (frame {f})")
        else:
            f = 0
            fig = plots.heat_map(lit[f], valid[f], f"{name} visibility (frame {f})", "visibility")
        files.append(io.save_figure(fig, folder / f"{name}_lit.png"))
        for key in arrays:
            if key.startswith(name + "/") and key.endswith("_per_pixel"):
                counter = key.split("/", 1)[1]
                fig = plots.heat_map(arrays[key][f], valid[f], f"{name}: {counter} (frame {f})",
                                     counter)
                files.append(io.save_figure(fig, folder / f"{name}_{counter}.png"))
    return files


def format_table(metrics: dict) -> str:
    """The summary as a plain-text table."""
    head = (f"{'method':<16} {'frames':>6} {'mismatches':>10} {'unexpl.':>7} {'max mism.%':>10} "
            f"{'warm s':>9} {'compile s':>9} {'x Embree':>9} {'tests':>14}")
    lines = [head, "-" * len(head)]
    ref = np.median([f["reference_seconds"] for f in metrics["frames"]])
    lines.append(f"{'reference':<16} {len(metrics['frames']):>6} {0:>10} {0:>7} {0.0:>10.4f} "
                 f"{ref:>9.4f} {0.0:>9.3f} {1.0:>9.2f} {'-':>14}")
    for name, s in metrics["summary"].items():
        mism = s.get("mismatches", "-")
        frac = f"{100 * s['max_mismatch_fraction']:.4f}" if "max_mismatch_fraction" in s \
            else f"mae {s.get('mae', 0):.3f}"
        ratio = s["median_ratio_to_reference"]
        unexpl = s.get("unexplained", "-")
        lines.append(f"{name:<16} {s['frames']:>6} {mism:>10} {str(unexpl):>7} {frac:>10} "
                     f"{s['median_seconds']:>9.4f} {s['compile_seconds']:>9.3f} "
                     f"{ratio if ratio is None else round(ratio, 2):>9} "
                     f"{s.get('tests', '-'):>14}")
    for name, reason in metrics.get("skipped", {}).items():
        lines.append(f"{name:<16} skipped: {reason}")
    lines += format_skipped(metrics)
    timing = metrics.get("timing")
    if timing:
        lines.append(f"warm s: median of {timing['repeats']} warm call(s) per frame after "
                     f"{timing['warmup']} warm-up call(s); compile s: kept apart")
    return "\n".join(lines)


