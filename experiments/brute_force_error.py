# ---
# jupyter:
#   jupytext:
#     text_representation:
#       extension: .py
#       format_name: percent
# ---

# %% [markdown]
# # `brute_force` against the exact Embree reference
#
# For each scene: the reference lit mask, the error map of `brute_force` (red: lit
# but should be shadowed, blue: shadowed but should be lit) and the run time of both,
# warm, median of repeats; the compile time of `brute_force` is kept apart
# (`shadowlab.harness.evaluate`: the reference, metric and timing protocol of `run`).
# `shadowlab figures --only brute_force_error` regenerates `figures/brute_force_error.*`.

# %%
from __future__ import annotations

import statistics

import numpy as np

from shadowlab.analysis.metrics import error_map
from shadowlab.harness import evaluate
from shadowlab.harness.figures import scene_frames
from shadowlab.reference.boundary import unexplained_count


def run(cfg: dict) -> dict:
    """Arrays per scene s: reference and error maps [S, H, W], times [S] (seconds)."""
    names = list(cfg["scenes"])
    res = tuple(cfg["resolution"])
    repeats = int(cfg.get("repeats", 3))
    out = {k: [] for k in ("reference", "valid", "error", "mismatches", "unexplained",
                           "valid_pixels",
                           "triangles", "reference_seconds", "method_seconds",
                           "compile_seconds", "tests")}
    for name, scene, view, gbuf, refs in scene_frames(cfg, names, res):
        truth = refs.hard(repeats)
        ev = evaluate(scene, gbuf, view.light, "brute_force",
                      {"precision": cfg.get("precision", "float32")}, reference=refs,
                      repeats=repeats)
        lit = ev.result.lit
        stats = ev.error
        out["reference"].append(truth)
        out["valid"].append(gbuf.valid)
        out["error"].append(error_map(lit, truth, gbuf.valid))
        out["mismatches"].append(stats["mismatches"])
        out["unexplained"].append(unexplained_count(scene, gbuf, view.light, lit, truth))
        out["valid_pixels"].append(stats["valid_pixels"])
        out["triangles"].append(scene.num_triangles)
        out["reference_seconds"].append(statistics.median(refs.hard_seconds))
        out["method_seconds"].append(ev.seconds)
        out["compile_seconds"].append(ev.compile_seconds)
        out["tests"].append(ev.result.counters["tests"])
    arrays = {k: np.asarray(v) for k, v in out.items()}
    arrays["scenes"] = np.asarray(names)
    return arrays


def plot(arrays: dict):
    import matplotlib.pyplot as plt

    from shadowlab.analysis.plots import ERROR_COLORS, shade

    n = len(arrays["scenes"])
    fig, axes = plt.subplots(n, 3, figsize=(10, 3.2 * n), constrained_layout=True,
                             squeeze=False)
    for i, name in enumerate(arrays["scenes"]):
        valid = arrays["valid"][i]
        axes[i, 0].imshow(shade(arrays["reference"][i], valid), cmap="gray", vmin=0, vmax=1)
        axes[i, 0].set_title(f"{name}: reference ({arrays['triangles'][i]} tris)", fontsize=9)
        axes[i, 1].imshow(arrays["error"][i], cmap=ERROR_COLORS, vmin=-1, vmax=1,
                          interpolation="nearest")
        axes[i, 1].set_title(f"brute_force error: {arrays['mismatches'][i]} of "
                             f"{arrays['valid_pixels'][i]} px", fontsize=9)
        for ax in axes[i, :2]:
            ax.set_xticks([])
            ax.set_yticks([])
        times = [arrays["reference_seconds"][i], arrays["method_seconds"][i]]
        axes[i, 2].barh(["Embree", "brute_force"], [1000 * t for t in times],
                        color=["#777777", "#d08c2b"])
        axes[i, 2].set_xlabel("ms (warm, median)")
        axes[i, 2].set_title(f"{arrays['tests'][i] / 1e6:.0f} M tests, compile "
                             f"{arrays['compile_seconds'][i]:.2f} s", fontsize=9)
    return fig


def check(arrays: dict, cfg: dict) -> None:
    """The oracle equals the reference but on shadow-boundary pixels (no unexplained
    mismatch: ``reference.boundary``, docs/exactness.md)."""
    assert np.all(arrays["unexplained"] == 0), dict(zip(arrays["scenes"],
                                                        arrays["unexplained"]))
    assert np.all(arrays["unexplained"] <= arrays["mismatches"])
    assert np.array_equal((arrays["error"] != 0).sum(axis=(1, 2)), arrays["mismatches"])
    assert np.all(arrays["valid_pixels"] > 0)


def claims(arrays: dict, cfg: dict) -> list[dict]:
    """The oracle's own claim (no paper's): exact but for boundary pixels."""
    return [{"claim": "brute_force equals the Embree reference on every pixel off a shadow "
                      "boundary",
             "measured": ", ".join(f"{n}: {m} wrong ({u} off a boundary)" for n, m, u in
                                   zip(arrays["scenes"], arrays["mismatches"],
                                       arrays["unexplained"])),
             "holds": bool(np.all(arrays["unexplained"] == 0))}]


# %%
if __name__ == "__main__":
    from shadowlab.harness.figures import run_as_script

    run_as_script(__file__)
