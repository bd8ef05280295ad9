# ---
# jupyter:
#   jupytext:
#     text_representation:
#       extension: .py
#       format_name: percent
# ---

# %% [markdown]
# # Load balance: iterations of the 1024 largest jobs, one pass vs two (Sintorn et al. 2014, Fig. 7)
#
# On the gate view (the paper's Fig. 1), the traversal iterations (node visits,
# TRAVERSENODE calls of Algorithm 1) of the 1024 most demanding jobs: with one pass a job
# is a triangle; with two passes pass 1 ("expand") traverses each triangle down to level
# L and pushes a (triangle, node) job per node reached there, which pass 2 ("finish")
# completes. The work is the same; only its split into jobs changes.

# %%
from __future__ import annotations

import numpy as np

import shadowlab as sl
from shadowlab.methods.clustered_ptsv import run_traversal_method, top_jobs
from shadowlab.scene.procedural import default_view


def run(cfg: dict) -> dict:
    """Top-1024 iteration curves [2, 1024] (one pass, two passes), means, maxima and
    total iterations [2], mismatches [2]."""
    name = cfg.get("scene", "gate")
    params = dict(cfg.get("params", {}))
    scene = sl.load_scene(name, **params)
    view = default_view(name, scene, **params)
    gbuf = sl.render_gbuffer(scene, view.camera.replace(resolution=tuple(cfg["resolution"])))
    truth = sl.reference_shadows(scene, gbuf, view.light)
    level = int(cfg.get("expand_level", 3))
    curves, means, maxima, totals, mism, jobs = [], [], [], [], [], []
    for passes in (1, 2):
        res, det = run_traversal_method(
            scene, gbuf, view.light, kind="cluster", precision=cfg.get("precision", "float32"),
            shadow_eps=1e-5, bias="receiver", passes=passes, expand_level=level)
        it = det["iterations_pass1"] if passes == 1 else np.concatenate(
            [det["iterations_pass1"], det["iterations_pass2"]])
        curves.append(top_jobs(it))
        means.append(it.mean())
        maxima.append(it.max())
        totals.append(it.sum())
        jobs.append(len(it))
        mism.append(int(np.count_nonzero((res.lit != truth) & gbuf.valid)))
    return {"top": np.asarray(curves), "mean": np.asarray(means), "max": np.asarray(maxima),
            "total": np.asarray(totals), "jobs": np.asarray(jobs),
            "mismatches": np.asarray(mism), "expand_level": np.asarray(level),
            "valid_pixels": np.asarray(gbuf.valid.sum()),
            "labels": np.asarray(["one pass (complete)", f"two passes (L = {level})"])}


def plot(arrays: dict):
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6.5, 4), constrained_layout=True)
    for i, label in enumerate(arrays["labels"]):
        ax.plot(np.arange(1, 1025), arrays["top"][i], label=f"{label}: max "
                f"{arrays['max'][i]}, mean {arrays['mean'][i]:.1f} over {arrays['jobs'][i]} jobs",
                color="C3" if i == 0 else "C0")
        ax.axhline(arrays["mean"][i], color="C3" if i == 0 else "C0", lw=0.8, ls=":")
    ax.set_xscale("log")
    ax.set_xlabel("job rank (1024 largest)")
    ax.set_ylabel("traversal iterations")
    ax.set_title("gate: iterations of the 1024 largest jobs (Fig. 7)", fontsize=10)
    ax.legend(fontsize=8)
    return fig


def check(arrays: dict, cfg: dict) -> None:
    """Exact (up to the documented boundary tolerance); both passes do the same total
    work; the top-job lists are sorted."""
    tol = float(cfg.get("max_mismatch_fraction", 0.0005))
    assert np.all(arrays["mismatches"] <= tol * arrays["valid_pixels"]), arrays["mismatches"]
    assert arrays["total"][0] == arrays["total"][1]
    assert np.all(np.diff(arrays["top"], axis=1) <= 0)


def claims(arrays: dict, cfg: dict) -> list[dict]:
    """Sintorn 2014, Fig. 7: one pass has jobs of about 10x the average (at least
    `min_one_pass_peak`); with two passes the largest job is close to the average (at
    most `max_two_pass_peak` x), a peak reduction of at least `min_peak_reduction`."""
    peak = arrays["max"] / arrays["mean"]
    one, two = float(peak[0]), float(peak[1])
    need_one = float(cfg.get("min_one_pass_peak", 5.0))
    need_two = float(cfg.get("max_two_pass_peak", 8.0))
    need_red = float(cfg.get("min_peak_reduction", 5.0))
    return [
        {"claim": f"one pass: largest job >= {need_one:g}x the average",
         "measured": f"{one:.1f}x", "holds": one >= need_one},
        {"claim": f"two passes: largest job <= {need_two:g}x the average",
         "measured": f"{two:.1f}x", "holds": two <= need_two},
        {"claim": f"two passes reduce the peak-to-average ratio >= {need_red:g}x",
         "measured": f"{one / two:.1f}x", "holds": one / two >= need_red},
    ]


# %%
if __name__ == "__main__":
    from shadowlab.harness.figures import run_as_script

    run_as_script(__file__)
