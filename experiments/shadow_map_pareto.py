# ---
# jupyter:
#   jupytext:
#     text_representation:
#       extension: .py
#       format_name: percent
# ---

# %% [markdown]
# # Run time against error: shadow maps against the exact methods
#
# The motivation of the irregular z-buffer, measured: `shadow_map` at resolutions
# 512-8192 with every bias mode (error: mismatching pixels against the Embree reference,
# split into false shadows, i.e. acne, and false lit pixels, i.e. peter-panning and light
# leaks), against the exact methods (`brute_force`, `izb` without and with the CSM
# prepass on a grid of the same resolution as one shadow map) and the Embree shadow-ray
# pass. Times are warm medians on this CPU (compile apart).
# `shadowlab figures --only shadow_map_pareto` regenerates `figures/shadow_map_pareto.*`.

# %%
from __future__ import annotations

import statistics

import numpy as np

from shadowlab.harness import evaluate
from shadowlab.harness.figures import scene_frames


def _configs(cfg: dict) -> list[tuple[str, dict]]:
    o = cfg["options"]
    runs = [("shadow_map", {"resolution": int(r), "bias": b})
            for b in o["biases"] for r in o["sm_resolutions"]]
    runs += [("brute_force", {}),
             ("izb", {"prepass": "none", "resolution": int(o["izb_resolution"])}),
             ("izb", {"prepass": "csm", "resolution": int(o["izb_resolution"]),
                      "verify": False})]
    return runs


def run(cfg: dict) -> dict:
    """Per scene s and configuration c [S, C]: seconds, mismatch fraction, false_lit,
    false_shadow, unexplained (exact methods; -1 otherwise); Embree seconds [S]."""
    names = list(cfg["scenes"])
    res = tuple(cfg["resolution"])
    runs = _configs(cfg)
    out = {k: [] for k in ("seconds", "fraction", "false_lit", "false_shadow", "unexplained",
                           "embree_seconds")}
    for name, scene, view, gbuf, refs in scene_frames(cfg, names, res):
        refs.hard(int(cfg.get("repeats", 2)))
        rows = {k: [] for k in out if k != "embree_seconds"}
        for method, opts in runs:
            ev = evaluate(scene, gbuf, view.light, method,
                          dict(opts, precision=cfg.get("precision", "float32")),
                          reference=refs, repeats=int(cfg.get("repeats", 2)))
            e = ev.error
            rows["seconds"].append(ev.timings["total"])
            rows["fraction"].append(e["mismatch_fraction"])
            rows["false_lit"].append(e["false_lit"])
            rows["false_shadow"].append(e["false_shadow"])
            u = e.get("unexplained")
            rows["unexplained"].append(-1 if (u is None or method == "shadow_map") else u)
        for k, v in rows.items():
            out[k].append(v)
        out["embree_seconds"].append(statistics.median(refs.hard_seconds))
    arrays = {k: np.asarray(v) for k, v in out.items()}
    arrays["scenes"] = np.asarray(names)
    arrays["labels"] = np.asarray([f"sm{o['resolution']}-{o['bias']}" if m == "shadow_map"
                                   else (f"izb-{o['prepass']}" if m == "izb" else m)
                                   for m, o in runs])
    return arrays


def plot(arrays: dict):
    import matplotlib.pyplot as plt

    n = len(arrays["scenes"])
    fig, axes = plt.subplots(1, n, figsize=(5.5 * n, 4), constrained_layout=True,
                             squeeze=False)
    labels = list(arrays["labels"])
    floor = 1e-5
    for s, ax in enumerate(axes[0]):
        biases = sorted({lab.split("-")[1] for lab in labels if lab.startswith("sm")})
        for b in biases:
            idx = [i for i, lab in enumerate(labels) if lab.startswith("sm") and lab.endswith(b)]
            ax.loglog(1000 * arrays["seconds"][s, idx],
                      np.maximum(arrays["fraction"][s, idx], floor), "o-", label=f"SM {b}")
        for i, lab in enumerate(labels):
            if not lab.startswith("sm"):
                ax.loglog(1000 * arrays["seconds"][s, i], max(arrays["fraction"][s, i], floor),
                          "*", ms=12, label=lab)
        ax.axvline(1000 * arrays["embree_seconds"][s], color="#777777", ls="--",
                   label="Embree")
        ax.set_xlabel("ms (warm median, this CPU)")
        ax.set_ylabel(f"mismatch fraction (floor {floor:g})")
        ax.set_title(str(arrays["scenes"][s]), fontsize=9)
        ax.legend(fontsize=6)
    return fig


def check(arrays: dict, cfg: dict) -> None:
    """Exact methods have no unexplained mismatch."""
    exact = [i for i, lab in enumerate(arrays["labels"]) if not lab.startswith("sm")]
    assert np.all(arrays["unexplained"][:, exact] == 0)


def claims(arrays: dict, cfg: dict) -> list[dict]:
    labels = list(arrays["labels"])
    sm = [i for i, lab in enumerate(labels) if lab.startswith("sm")]
    best = arrays["fraction"][:, sm].min(axis=1)
    res = sorted({int(labels[i].split("-")[0][2:]) for i in sm})
    by_res = [min(arrays["fraction"][:, i].mean() for i in sm
                  if labels[i].startswith(f"sm{r}-")) for r in res]
    return [
        {"claim": "the exact methods (izb included) have no unexplained error while every "
                  "shadow map has some",
         "measured": ", ".join(f"{s}: best SM {100 * b:.2f}%" for s, b in
                               zip(arrays["scenes"], best)),
         "holds": bool(np.all(best > 0))},
        {"claim": "shadow-map error falls with resolution (best bias per resolution)",
         "measured": ", ".join(f"R={r}: {100 * e:.2f}%" for r, e in zip(res, by_res)),
         "holds": bool(by_res[-1] <= by_res[0])},
    ]


# %%
if __name__ == "__main__":
    from shadowlab.harness.figures import run_as_script

    run_as_script(__file__)
