# ---
# jupyter:
#   jupytext:
#     text_representation:
#       extension: .py
#       format_name: percent
# ---

# %% [markdown]
# # Per-pixel test-and-set heat maps: PTSV vs the cluster hierarchy (Sintorn et al. 2014, Fig. 3)
#
# On the gate scene (the paper's Fig. 1 view: a near gate, trees, a distant house), the
# number of times each pixel is tested against a shadow volume by `ptsv` (2D tiles with
# depth ranges) and by `clustered_ptsv` (implicit and explicit bounds). Pixels are split
# into those whose 8 x 4 PTSV tile spans a steep depth discontinuity (max / min depth
# > 2) and the rest; the paper's claim is that PTSV's work piles up at such
# discontinuities while the cluster hierarchy's does not.

# %%
from __future__ import annotations

import warnings

import numpy as np

import shadowlab as sl
from shadowlab.harness.claims import measured
from shadowlab.reference.boundary import unexplained_count
from shadowlab.scene.procedural import default_view

VARIANTS = (("ptsv", "ptsv", {}),
            ("clustered (implicit)", "clustered_ptsv", {"bounds": "implicit"}),
            ("clustered (explicit)", "clustered_ptsv", {"bounds": "explicit"}))


def discontinuity_mask(gbuf, ratio: float = 2.0) -> np.ndarray:
    """bool [H, W]: valid pixels whose 8 x 4 tile holds depths differing by > ratio."""
    h, w = gbuf.shape
    th, tw = 4, 8
    hp, wp = -(-h // th) * th, -(-w // tw) * tw
    d = np.full((hp, wp), np.nan)
    d[:h, :w] = np.where(gbuf.valid, gbuf.depth, np.nan)
    blocks = d.reshape(hp // th, th, wp // tw, tw)
    with warnings.catch_warnings(), np.errstate(all="ignore"):   # all-empty tiles: NaN
        warnings.simplefilter("ignore", RuntimeWarning)
        steep = np.nanmax(blocks, axis=(1, 3)) / np.nanmin(blocks, axis=(1, 3)) > ratio
    steep = np.repeat(np.repeat(np.nan_to_num(steep, nan=0).astype(bool), th, 0), tw, 1)
    return steep[:h, :w] & gbuf.valid


def run(cfg: dict) -> dict:
    """Heat maps [V, H, W] (tests per pixel), totals [V], mean tests per valid pixel at
    and away from discontinuities [V, 2], mismatches [V]."""
    name = cfg.get("scene", "gate")
    params = dict(cfg.get("params", {}))
    scene = sl.load_scene(name, **params)
    view = default_view(name, scene, **params)
    gbuf = sl.render_gbuffer(scene, view.camera.replace(resolution=tuple(cfg["resolution"])))
    truth = sl.reference_shadows(scene, gbuf, view.light)
    steep = discontinuity_mask(gbuf)
    flat = gbuf.valid & ~steep
    maps, totals, means, mism, unex = [], [], [], [], []
    for _, method, opts in VARIANTS:
        r = sl.compute_shadows(scene, gbuf, view.light, method=method,
                               precision=cfg.get("precision", "float32"), **opts)
        m = r.counters["tests_per_pixel"]
        maps.append(m)
        totals.append(r.counters["tests"])
        means.append([m[steep].mean() if steep.any() else 0.0, m[flat].mean()])
        mism.append(int(np.count_nonzero((r.lit != truth) & gbuf.valid)))
        unex.append(unexplained_count(scene, gbuf, view.light, r.lit, truth))
    return {"maps": np.asarray(maps), "totals": np.asarray(totals),
            "means": np.asarray(means), "mismatches": np.asarray(mism),
            "unexplained": np.asarray(unex),
            "valid": gbuf.valid, "steep": steep, "reference": truth,
            "labels": np.asarray([v[0] for v in VARIANTS]),
            "triangles": np.asarray(scene.num_triangles)}


def plot(arrays: dict):
    import matplotlib.pyplot as plt

    n = len(arrays["labels"])
    fig, axes = plt.subplots(1, n + 1, figsize=(4.2 * (n + 1), 4.2), constrained_layout=True)
    valid = arrays["valid"]
    axes[0].imshow(np.where(arrays["steep"], 1.0, np.where(valid, 0.4, 0.0)), cmap="gray")
    axes[0].set_title(f"gate ({int(arrays['triangles'])} tris): tiles with depth ratio > 2",
                      fontsize=9)
    vmax = np.percentile(arrays["maps"][:, valid], 99.5)
    for i, label in enumerate(arrays["labels"]):
        im = axes[i + 1].imshow(np.where(valid, arrays["maps"][i], np.nan), cmap="inferno",
                                vmin=0, vmax=vmax)
        at, away = arrays["means"][i]
        axes[i + 1].set_title(f"{label}: {arrays['totals'][i] / 1e3:.0f} k tests\n"
                              f"mean {at:.0f} at discontinuities, {away:.0f} elsewhere",
                              fontsize=9)
    fig.colorbar(im, ax=axes[-1], shrink=0.8, label="test-and-sets per pixel")
    for ax in axes:
        ax.set_xticks([])
        ax.set_yticks([])
    return fig


def check(arrays: dict, cfg: dict) -> None:
    """No unexplained mismatch (docs/exactness.md); the maps sum to the totals; the view
    has tiles spanning steep depth discontinuities."""
    assert np.all(arrays["unexplained"] == 0), (arrays["mismatches"], arrays["unexplained"])
    assert np.array_equal(arrays["maps"].sum(axis=(1, 2)), arrays["totals"])
    assert arrays["steep"].any()


def claims(arrays: dict, cfg: dict) -> list[dict]:
    """Sintorn 2014, Fig. 3: at steep depth discontinuities PTSV tests each pixel more
    often than elsewhere, and the cluster hierarchy with explicit bounds tests those
    pixels at least `min_gain` times less often than PTSV."""
    labels = list(arrays["labels"])
    pt, ex = labels.index("ptsv"), labels.index("clustered (explicit)")
    means = arrays["means"]
    gain = means[pt, 0] / max(means[ex, 0], 1e-9)
    need = float(cfg.get("min_gain", 2.0))
    return [
        measured("s14.fig3.ptsv_discontinuities",
                 f"PTSV {means[pt, 0]:.1f} tests per pixel at discontinuities vs "
                 f"{means[pt, 1]:.1f} elsewhere", means[pt, 0] > means[pt, 1]),
        measured("s14.fig3.cluster_discontinuities",
                 f"explicit {means[ex, 0]:.1f} vs PTSV {means[pt, 0]:.1f} tests per pixel "
                 f"there ({gain:.1f}x, need {need:g}x)", gain >= need),
    ]


# %%
if __name__ == "__main__":
    from shadowlab.harness.figures import run_as_script

    run_as_script(__file__)
