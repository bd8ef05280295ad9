# ---
# jupyter:
#   jupytext:
#     text_representation:
#       extension: .py
#       format_name: percent
# ---

# %% [markdown]
# # `soft_tiled`: error against the exact reference vs run time, per grid, with and without rotation
#
# Terrain under a low sun. The truth is `soft_reference` with `truth_rays` stratified
# rays per pixel; a second truth with another seed measures the truth's own error.
# For each grid (16x16, 31x3 .. 31x31), with and without the per-pixel grid rotation,
# `soft_tiled` with the paper's preset (warm, median of repeats; compile time kept
# apart) gives a (run time, error) point, and every grid again in the exact variant
# (the method's defaults: homogeneous projection, two-sided lists); the naive
# `soft_overlap_sum` is an extra point, and Embree's own soft reference at fewer rays per pixel gives the
# run-time-vs-error curve to beat. Banding: under a wider sun (`banding_sun_deg`, wide
# penumbrae), a crop of the most penumbra without and with rotation, and the lag-1
# autocorrelation of the error over penumbra pixels (bands: correlated error, close to
# 1; rotation turns it into noise).

# %%
from __future__ import annotations

import statistics
import time

import numpy as np

import shadowlab as sl
from shadowlab.harness.figures import scene_view
from shadowlab.analysis.metrics import compare_soft


def _variants(cfg):
    out = []
    for grid in cfg["grids"]:
        for rot in (False, True):
            out.append((f"{grid}{' rot' if rot else ''}", "soft_tiled",
                        {"grid": grid, "rotate": rot}))
    # every grid also in the exact variant: the method's defaults (preset "accurate":
    # homogeneous projection, two-sided lists, whole lists), with rotation
    for grid in cfg["grids"]:
        out.append((f"{grid} rot exact", "soft_tiled",
                    {"grid": grid, "rotate": True, "preset": "accurate"}))
    out.append(("overlap sum", "soft_overlap_sum", {}))
    return out


def _autocorr(err: np.ndarray, mask: np.ndarray) -> float:
    """Lag-1 (horizontal and vertical) autocorrelation of err over mask pairs."""
    num, den = 0.0, 0.0
    e = np.where(mask, err - err[mask].mean(), 0.0)
    for a, b, m in [(e[:, 1:], e[:, :-1], mask[:, 1:] & mask[:, :-1]),
                    (e[1:], e[:-1], mask[1:] & mask[:-1])]:
        num += float((a * b)[m].sum())
        den += float(0.5 * (a * a + b * b)[m].sum())
    return num / den if den > 0 else 0.0


def _crop(truth: np.ndarray, size: int) -> tuple[int, int]:
    """Top-left corner of the size x size window with the most penumbra pixels."""
    pen = ((truth > 0.05) & (truth < 0.95)).astype(float)
    c = pen.cumsum(0).cumsum(1)
    c = np.pad(c, ((1, 0), (1, 0)))
    s = c[size:, size:] - c[:-size, size:] - c[size:, :-size] + c[:-size, :-size]
    y, x = np.unravel_index(np.argmax(s), s.shape)
    return int(y), int(x)


def run(cfg: dict) -> dict:
    scene, view, gbuf = scene_view(cfg)
    light = view.light
    valid = gbuf.valid
    rays = int(cfg["truth_rays"])
    t0 = time.perf_counter()
    truth = sl.soft_reference(scene, gbuf, light, rays_per_pixel=rays, seed=0)
    truth_seconds = time.perf_counter() - t0
    truth2 = sl.soft_reference(scene, gbuf, light, rays_per_pixel=rays, seed=1)
    self_err = compare_soft(truth2, truth, valid)
    out = {k: [] for k in ("labels", "seconds", "compile_seconds", "mae", "rmse", "max_error",
                           "ssim", "autocorr", "overflow_tiles", "rasterized_mean")}
    images = {}
    pen = valid & (truth > 0.02) & (truth < 0.98)
    repeats = int(cfg.get("repeats", 2))
    opts = dict(cfg.get("options", {}))
    for label, method, extra in _variants(cfg):
        o = dict(opts, **extra)
        cold = sl.compute_shadows(scene, gbuf, light, method=method, **o)
        runs = [sl.compute_shadows(scene, gbuf, light, method=method, **o)
                for _ in range(repeats)]
        vis = runs[-1].lit
        err = compare_soft(vis, truth, valid)
        out["labels"].append(label)
        out["seconds"].append(statistics.median(r.timings["total"] for r in runs))
        out["compile_seconds"].append(sum(v for k, v in cold.timings.items()
                                          if k.endswith("_compile")))
        for k in ("mae", "rmse", "max_error", "ssim"):
            out[k].append(err[k])
        out["autocorr"].append(_autocorr(vis - truth, pen))
        out["overflow_tiles"].append(runs[-1].counters["overflow_tiles"])
        out["rasterized_mean"].append(runs[-1].counters["rasterized_triangles"]
                                      / max(runs[-1].counters["samples"], 1))
        images[label] = vis
    emb = {k: [] for k in ("embree_rays", "embree_seconds", "embree_mae", "embree_rmse",
                           "embree_max_error", "embree_ssim")}
    for r in cfg["embree_rays"]:
        t0 = time.perf_counter()
        est = sl.soft_reference(scene, gbuf, light, rays_per_pixel=int(r), seed=2)
        emb["embree_seconds"].append(time.perf_counter() - t0)
        e = compare_soft(est, truth, valid)
        emb["embree_rays"].append(int(r))
        for k in ("mae", "rmse", "max_error", "ssim"):
            emb[f"embree_{k}"].append(e[k])
    # banding: a wider sun (wide penumbrae), coarse grids without and with rotation
    wide = sl.SphereLight(direction=light.direction,
                          angular_radius_deg=float(cfg.get("banding_sun_deg", 2.0)))
    truth_w = sl.soft_reference(scene, gbuf, wide, rays_per_pixel=rays, seed=0)
    pen_w = valid & (truth_w > 0.02) & (truth_w < 0.98)
    shown = ["16x16", "16x16 rot", "31x3", "31x3 rot"]
    band = {"band_mae": [], "band_autocorr": [], "band_penumbra_mae": []}
    shown_imgs = []
    for label in shown:
        grid_name, rot = label.split()[0], label.endswith("rot")
        vis = sl.compute_shadows(scene, gbuf, wide, method="soft_tiled", **dict(
            opts, grid=grid_name, rotate=rot)).lit
        shown_imgs.append(vis)
        band["band_mae"].append(compare_soft(vis, truth_w, valid)["mae"])
        band["band_penumbra_mae"].append(float(np.abs(vis - truth_w)[pen_w].mean()))
        band["band_autocorr"].append(_autocorr(vis - truth_w, pen_w))
    size = int(cfg.get("crop", 32))
    y, x = _crop(np.where(valid, truth_w, 0), size)
    arrays = {k: np.asarray(v) for k, v in {**out, **emb, **band}.items()}
    arrays.update({
        "truth": truth, "valid": valid, "truth_rays": np.asarray(rays),
        "truth_seconds": np.asarray(truth_seconds),
        "truth_self_mae": np.asarray(self_err["mae"]),
        "truth_self_max": np.asarray(self_err["max_error"]),
        "banding_truth": truth_w, "banding_sun_deg": np.asarray(wide.angular_radius_deg),
        "crop_corner": np.asarray([y, x]), "crop_size": np.asarray(size),
        "shown_labels": np.asarray(shown),
        "shown": np.stack(shown_imgs),
        "penumbra_pixels": np.asarray(int(pen.sum())),
    })
    return arrays


def plot(arrays: dict):
    import matplotlib.pyplot as plt

    fig = plt.figure(figsize=(14, 8.5), constrained_layout=True)
    grid = fig.add_gridspec(2, 4)
    labels = list(arrays["labels"])
    for col, (key, name) in enumerate([("mae", "mean absolute error"), ("ssim", "SSIM")]):
        ax = fig.add_subplot(grid[0, 2 * col: 2 * col + 2])
        ax.plot(1000 * arrays["embree_seconds"], arrays[f"embree_{key}"], "o-", color="#777777",
                label="Embree soft reference (rays/px)")
        for r, t, v in zip(arrays["embree_rays"], arrays["embree_seconds"], arrays[f"embree_{key}"]):
            ax.annotate(str(r), (1000 * t, v), fontsize=7, color="#555555")
        for i, lab in enumerate(labels):
            marker = "s" if "rot" in lab else "o"
            color = "#c0392b" if "overlap" in lab else ("#2c7fb8" if "rot" in lab else "#d08c2b")
            ax.plot(1000 * arrays["seconds"][i], arrays[key][i], marker, color=color)
            ax.annotate(lab, (1000 * arrays["seconds"][i], arrays[key][i]), fontsize=7)
        ax.set_xscale("log")
        if key == "mae":
            ax.set_yscale("log")
            ax.axhline(float(arrays["truth_self_mae"]), color="k", lw=0.6, ls=":",
                       label=f"truth vs 2nd seed ({int(arrays['truth_rays'])} rays)")
        ax.set_xlabel("run time, ms (warm, median; compile excluded)")
        ax.set_ylabel(name)
        ax.legend(fontsize=7)
        ax.set_title(f"{name} vs run time", fontsize=9)
    y, x = arrays["crop_corner"]
    s = int(arrays["crop_size"])
    ax = fig.add_subplot(grid[1, 0])
    ax.imshow(np.where(arrays["valid"], 0.3 + 0.7 * arrays["banding_truth"], 0.0), cmap="gray",
              vmin=0, vmax=1)
    ax.add_patch(plt.Rectangle((x, y), s, s, fill=False, color="r"))
    ax.set_title(f"banding: sun radius {float(arrays['banding_sun_deg']):.1f} deg, truth; "
                 "crop in red", fontsize=9)
    crops = [arrays["banding_truth"][y:y + s, x:x + s]] + [v[y:y + s, x:x + s]
                                                           for v in arrays["shown"]]
    names = ["truth"] + list(arrays["shown_labels"])
    sub = grid[1, 1:].subgridspec(1, len(crops))
    for i, (img, nm) in enumerate(zip(crops, names)):
        ax = fig.add_subplot(sub[0, i])
        ax.imshow(img, cmap="gray", vmin=0, vmax=1, interpolation="nearest")
        if nm != "truth":
            k = list(arrays["shown_labels"]).index(nm)
            nm = (f"{nm}\npenumbra MAE {arrays['band_penumbra_mae'][k]:.3f}\n"
                  f"error autocorr {arrays['band_autocorr'][k]:.2f}")
        ax.set_title(nm, fontsize=8)
        ax.set_xticks([])
        ax.set_yticks([])
    return fig


def check(arrays: dict, cfg: dict) -> None:
    labels = list(arrays["labels"])
    tiled = np.array(["overlap" not in lab for lab in labels])
    paper = np.array(["overlap" not in lab and "exact" not in lab for lab in labels])
    assert np.all(arrays["mae"][tiled] <= float(cfg["max_mae"])), dict(zip(labels, arrays["mae"]))
    # the truth is much better than what it measures (the exact variant comes close to
    # the truth's own noise: it is only checked to beat the paper's variants)
    assert float(arrays["truth_self_mae"]) < 0.5 * float(np.min(arrays["mae"][paper]))
    assert arrays["mae"][labels.index("16x16 rot exact")] <= np.min(arrays["mae"][paper])
    # the naive overlap sum double-counts: worse than the finest grid
    fine = labels.index(f"{cfg['grids'][-1]}")
    assert arrays["mae"][labels.index("overlap sum")] > arrays["mae"][fine]
    # rotation trades bands for noise: less correlated error on the coarse grids (only
    # measurable when neighbouring pixels see nearly the same disk: full size)
    shown = list(arrays["shown_labels"])
    assert np.all(np.isfinite(arrays["band_autocorr"]))
    if cfg.get("check_banding", False):
        for g in ("16x16", "31x3"):
            assert arrays["band_autocorr"][shown.index(g + " rot")] < \
                arrays["band_autocorr"][shown.index(g)]
    assert np.all(np.diff(arrays["embree_mae"]) < 0)       # more rays, less error


# %%
if __name__ == "__main__":
    from shadowlab.harness.figures import run_as_script

    run_as_script(__file__)
