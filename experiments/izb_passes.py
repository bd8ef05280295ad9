# ---
# jupyter:
#   jupytext:
#     text_representation:
#       extension: .py
#       format_name: percent
# ---

# %% [markdown]
# # IZB passes without and with node culling (Tokuyoshi and Mizokuchi 2018, Figs. 1 and 3)
#
# One scene, `izb` with `prepass="none"` (Wyman et al.'s IZB) and `"csm"` (the two-pass
# visibility test): the visibility masks (samples culled by the CSM, Fig. 1a; the tests
# per pixel of the rest, Fig. 1b; the final lit mask, Fig. 1c), the list length of each
# sample's texel (Fig. 3's heat map, drawn in screen space on one colour scale for both),
# and the per-pass warm times (CSM, IZB creation = list build, frustum tracing, total).
# `shadowlab figures --only izb_passes` regenerates `figures/izb_passes.*`.

# %%
from __future__ import annotations

import numpy as np

from shadowlab.harness import References, evaluate
from shadowlab.harness.figures import scene_view

PASSES = ("csm", "build", "trace", "verify", "total")
KEYS = ("tests", "list_nodes", "list_length_max", "traced_fragments",
        "depth_culled_fragments", "csm_culled", "csm_false_shadows", "samples", "shadowed")


def run(cfg: dict) -> dict:
    """Maps [2, H, W] (none, csm), pass seconds [2, 4], counters [2, K], reference."""
    scene, view, gbuf = scene_view(cfg, "sphere_grid")
    refs = References(scene, gbuf, view.light)
    opts = dict(cfg.get("options", {}))
    out = {k: [] for k in ("lit", "culled", "tests_map", "lengths", "seconds", "counters",
                           "mismatches", "unexplained")}
    for prepass in ("none", "csm"):
        ev = evaluate(scene, gbuf, view.light, "izb",
                      dict(opts, prepass=prepass, precision=cfg.get("precision", "float32")),
                      reference=refs, repeats=int(cfg.get("repeats", 2)))
        c = ev.result.counters
        out["lit"].append(ev.result.lit)
        out["culled"].append(c["csm_culled_per_pixel"])
        out["tests_map"].append(c["tests_per_pixel"])
        out["lengths"].append(c["list_length_per_pixel"])
        out["seconds"].append([ev.timings.get(p, 0.0) for p in PASSES])
        out["counters"].append([c[k] for k in KEYS])
        out["mismatches"].append(ev.error["mismatches"])
        out["unexplained"].append(-1 if ev.error["unexplained"] is None
                                  else ev.error["unexplained"])
    arrays = {k: np.asarray(v) for k, v in out.items()}
    arrays["valid"] = gbuf.valid
    arrays["reference"] = refs.hard()
    arrays["triangles"] = np.asarray(scene.num_triangles)
    return arrays


def plot(arrays: dict):
    import matplotlib.pyplot as plt

    from shadowlab.analysis.plots import shade

    fig, axes = plt.subplots(2, 4, figsize=(13, 6.4), constrained_layout=True)
    top = max(1, int(arrays["lengths"].max()))
    for i, label in enumerate(("IZB w/o node culling", "IZB with node culling")):
        axes[i, 0].imshow(arrays["culled"][i], cmap="Reds", vmin=0, vmax=1)
        axes[i, 0].set_title(f"{label}: CSM-culled (1a)", fontsize=8)
        axes[i, 1].imshow(np.log1p(arrays["tests_map"][i]), cmap="magma")
        axes[i, 1].set_title("log(1 + tests per pixel) (1b)", fontsize=8)
        im = axes[i, 2].imshow(arrays["lengths"][i], cmap="viridis", vmin=0, vmax=top)
        axes[i, 2].set_title("list length of the pixel's texel (Fig. 3)", fontsize=8)
        fig.colorbar(im, ax=axes[i, 2], shrink=0.7)
        axes[i, 3].barh(PASSES, 1000 * arrays["seconds"][i], color="#4a7ab0")
        axes[i, 3].set_xlabel("ms (warm median)")
        for ax in axes[i, :3]:
            ax.set_xticks([])
            ax.set_yticks([])
    return fig


def check(arrays: dict, cfg: dict) -> None:
    """Both exact and equal; the prepass conservative; node culling never adds work."""
    assert np.array_equal(arrays["lit"][0], arrays["lit"][1])
    assert np.all(arrays["unexplained"] == 0)
    c = dict(zip(KEYS, arrays["counters"].T))
    assert c["csm_false_shadows"][1] == 0
    assert c["tests"][1] <= c["tests"][0]
    assert c["list_nodes"][1] == c["samples"][1] - c["csm_culled"][1]
    assert c["list_length_max"][1] <= c["list_length_max"][0]


def claims(arrays: dict, cfg: dict) -> list[dict]:
    c = dict(zip(KEYS, arrays["counters"].T))
    sec = arrays["seconds"]
    passes = sec[:, :3].sum(axis=1)          # CSM + IZB creation + tracing (no verify)
    speed = passes[0] / max(passes[1], 1e-12)
    tests_ratio = c["tests"][1] / max(c["tests"][0], 1)
    nodes_ratio = c["list_nodes"][1] / max(c["list_nodes"][0], 1)
    trace_ratio = sec[1, 2] / max(sec[0, 2], 1e-12)
    culled = int(c["csm_culled"][1])
    rate = culled / max(int(c["samples"][1]), 1)
    # where the CSM culls (almost) nothing, the prepass can only add its raster
    no_cull = (f"the CSM culled {culled} of {int(c['samples'][1])} samples ({100 * rate:.2f} %), "
               "so the prepass only adds its raster: a sample is culled only in a texel that "
               "a caster covers whole (izb_small_triangles: the culling rate against the "
               "caster size in texels)" if rate < 0.01 else "")
    return [
        {"id": "t18.fig1.speedup",
         "claim": "the two-pass visibility test improves hard-shadow time by more than 2x",
         "measured": f"CSM + creation + tracing {1000 * passes[0]:.1f} -> "
                     f"{1000 * passes[1]:.1f} ms ({speed:.2f}x; this CPU, under load)",
         "holds": bool(speed > 2), **({"note": no_cull} if no_cull and speed <= 2 else {})},
        {"id": "t18.fig3.stages",
         "claim": "tracing work falls faster than the node count (Fig. 3: creation 3.1x, "
                  "tracing 15.7x)",
         "measured": f"tests x{tests_ratio:.3f}, nodes x{nodes_ratio:.3f}, trace time "
                     f"x{trace_ratio:.2f}",
         "holds": bool(tests_ratio < nodes_ratio),
         **({"note": no_cull} if no_cull and tests_ratio >= nodes_ratio else {})},
        {"claim": "node culling leaves more fragments to the depth test (fewer traced)",
         "measured": f"traced {c['traced_fragments'][0]} -> {c['traced_fragments'][1]}",
         "holds": bool(c["traced_fragments"][1] <= c["traced_fragments"][0])},
    ]


# %%
if __name__ == "__main__":
    from shadowlab.harness.figures import run_as_script

    run_as_script(__file__)
