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
# run-time-vs-error curve to beat; errors over all valid pixels and over the penumbra
# region. Rasterization cost against grid size on its own (the JAX rasterizer on random
# triangles) beside the paper's GPU numbers. Banding: a straight occluder edge under a
# wide sun (`edge_sun_deg`) straight overhead, parallel to the grid rows in every disk,
# with a closed-form truth, without and with rotation; the band amplitude (RMS step of
# the error averaged along the edge) measures bands, the noise amplitude (RMS of the
# error about that average) measures noise.

# %%
from __future__ import annotations

import statistics
import time

import numpy as np

import shadowlab as sl
from shadowlab.harness.figures import scene_view
from shadowlab.analysis.metrics import compare_soft


METRICS = ("mae", "rmse", "max_error", "ssim", "penumbra_mae", "penumbra_rmse",
           "penumbra_max_error", "penumbra_ssim")
#: the paper's rasterization-only times on its GPU (ms; one scene, "very rough")
PAPER_RASTER_MS = {"16x16": 5.0, "31x3": 2.1, "31x5": 2.5, "31x7": 3.1}


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


BAND_SHOWN = ["16x16", "16x16 rot", "31x3", "31x3 rot"]


def _edge_scene(height: float, half: float = 50.0):
    """The ground y = 0 and a half-plane occluder {y = height, x < 0} (two quads)."""
    from shadowlab.scene.mesh import Scene

    h, y = half, height
    quad = np.array([[0, 2, 1], [0, 3, 2]])
    ground = Scene(np.array([[-h, 0, -h], [h, 0, -h], [h, 0, h], [-h, 0, h]], float), quad,
                   np.zeros(2, np.int32), ("ground",), "ground")
    blocker = Scene(np.array([[-h, y, -h], [0, y, -h], [0, y, h], [-h, y, h]], float), quad,
                    np.zeros(2, np.int32), ("blocker",), "blocker")
    return Scene.concatenate([ground, blocker], name="straight_edge")


def _banding(cfg):
    """A straight occluder edge under a wide sun straight overhead, seen from below the
    occluder looking down: the edge is parallel to the grid rows in every pixel's disk
    (the worst case for banding), visibility depends on x only and has a closed form,
    1 - segment(u) with u = x / (h tan r). Image columns are x, rows are z.

    Per shown variant, on the penumbra columns: penumbra MAE; the *band amplitude*: the
    RMS step of the error averaged along the edge (z) from one column to the next,
    divided by sqrt(2) (averaging along z keeps error that depends on x alone, bands and
    smooth bias; the step keeps the bands and drops the bias); the *noise amplitude*:
    the RMS of the error minus its column average (what varies along the edge)."""
    height = 1.0
    sun_deg = float(cfg.get("edge_sun_deg", 8.0))
    res = int(cfg.get("edge_resolution", 96))
    scene = _edge_scene(height)
    cam = sl.Camera(eye=(0.0, 0.5, 0.0), target=(0.0, 0.0, 0.0), up=(0.0, 0.0, -1.0),
                    fov_y_deg=60.0, near=0.05, far=10.0, resolution=(res, res))
    gbuf = sl.render_gbuffer(scene, cam)
    assert gbuf.valid.all()
    sun = sl.SphereLight(direction=(0.0, -1.0, 0.0), angular_radius_deg=sun_deg)
    u = np.clip(gbuf.position[..., 0] / (height * np.tan(np.radians(sun_deg))), -1, 1)
    truth = (np.arccos(-u) + u * np.sqrt(1 - u * u)) / np.pi
    cols = ((truth > 0.02) & (truth < 0.98)).all(0)          # penumbra columns
    band = {"band_penumbra_mae": [], "band_amplitude": [], "noise_amplitude": [],
            "band_autocorr": []}
    imgs = []
    for label in BAND_SHOWN:
        grid_name, rot = label.split()[0], label.endswith("rot")
        vis = sl.compute_shadows(scene, gbuf, sun, method="soft_tiled", grid=grid_name,
                                 rotate=rot).lit
        imgs.append(vis)
        err = (vis - truth)[:, cols]
        band["band_penumbra_mae"].append(float(np.abs(err).mean()))
        colmean = err.mean(0)
        band["band_amplitude"].append(float(np.sqrt((np.diff(colmean) ** 2).mean() / 2)))
        band["noise_amplitude"].append(float(np.sqrt(((err - colmean) ** 2).mean())))
        band["band_autocorr"].append(_autocorr(vis - truth, np.broadcast_to(cols, truth.shape)))
    return band, imgs, {"truth": truth, "sun_deg": sun_deg}


def _raster_cost(cfg):
    """The rasterization alone (the JAX rasterizer the method uses, homogeneous
    projection, horizon on): warm median seconds for F fragments x T triangles per grid,
    on random triangles overlapping the disk."""
    from shadowlab.kernels.sun_disk import jax_visibility

    rng = np.random.default_rng(0)
    f_count, t_count = int(cfg.get("raster_fragments", 2048)), int(cfg.get("raster_triangles", 8))
    s = 0.05
    z = rng.uniform(1.0, 2.0, (f_count, t_count, 3))
    xy = rng.uniform(-1.5, 1.5, (f_count, t_count, 3, 2)) * (s * z)[..., None]
    d = np.concatenate([xy, z[..., None]], -1).astype(np.float32)
    n = np.tile([0.0, 0.0, 1.0], (f_count, 1))
    grids = list(cfg.get("raster_grids", cfg["grids"]))
    out = {"raster_grids": grids, "raster_seconds": [], "raster_ns_per_pair": []}
    for g in grids:
        jax_visibility(d, s, n, grid=g, projection="homogeneous", horizon=True)   # compile
        times = []
        for _ in range(int(cfg.get("raster_repeats", 3))):
            t0 = time.perf_counter()
            jax_visibility(d, s, n, grid=g, projection="homogeneous", horizon=True)
            times.append(time.perf_counter() - t0)
        sec = statistics.median(times)
        out["raster_seconds"].append(sec)
        out["raster_ns_per_pair"].append(1e9 * sec / (f_count * t_count))
    out["raster_paper_ms"] = [PAPER_RASTER_MS.get(g, float("nan")) for g in grids]
    return out


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
    out = {k: [] for k in ("labels", "seconds", "compile_seconds", *METRICS, "autocorr",
                           "overflow_tiles", "rasterized_mean")}
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
        for k in METRICS:
            out[k].append(err[k])
        out["autocorr"].append(_autocorr(vis - truth, pen))
        out["overflow_tiles"].append(runs[-1].counters["overflow_tiles"])
        out["rasterized_mean"].append(runs[-1].counters["rasterized_triangles"]
                                      / max(runs[-1].counters["samples"], 1))
        images[label] = vis
    emb = {k: [] for k in ("embree_rays", "embree_seconds", *(f"embree_{m}" for m in METRICS))}
    for r in cfg["embree_rays"]:
        t0 = time.perf_counter()
        est = sl.soft_reference(scene, gbuf, light, rays_per_pixel=int(r), seed=2)
        emb["embree_seconds"].append(time.perf_counter() - t0)
        e = compare_soft(est, truth, valid)
        emb["embree_rays"].append(int(r))
        for k in METRICS:
            emb[f"embree_{k}"].append(e[k])
    band, shown_imgs, edge = _banding(cfg)
    raster = _raster_cost(cfg)
    arrays = {k: np.asarray(v) for k, v in {**out, **emb, **band, **raster}.items()}
    arrays.update({
        "truth": truth, "valid": valid, "truth_rays": np.asarray(rays),
        "truth_seconds": np.asarray(truth_seconds),
        "truth_self_mae": np.asarray(self_err["mae"]),
        "truth_self_max": np.asarray(self_err["max_error"]),
        "edge_truth": edge["truth"], "edge_sun_deg": np.asarray(edge["sun_deg"]),
        "shown_labels": np.asarray(BAND_SHOWN),
        "shown": np.stack(shown_imgs),
        "penumbra_pixels": np.asarray(int(pen.sum())),
    })
    return arrays


def plot(arrays: dict):
    import matplotlib.pyplot as plt

    fig = plt.figure(figsize=(14, 8.5), constrained_layout=True)
    grid = fig.add_gridspec(2, 4)
    labels = list(arrays["labels"])
    for col, (key, name) in enumerate([("mae", "mean absolute error"),
                                        ("penumbra_mae", "penumbra mean absolute error")]):
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
        ax.set_yscale("log")
        if key == "mae":
            ax.axhline(float(arrays["truth_self_mae"]), color="k", lw=0.6, ls=":",
                       label=f"truth vs 2nd seed ({int(arrays['truth_rays'])} rays)")
        ax.set_xlabel("run time, ms (warm, median; compile excluded)")
        ax.set_ylabel(name)
        ax.legend(fontsize=7)
        ax.set_title(f"{name} vs run time", fontsize=9)
    ax = fig.add_subplot(grid[1, 0])
    g = list(arrays["raster_grids"])
    ns = np.asarray(arrays["raster_ns_per_pair"])
    ax.bar(np.arange(len(g)) - 0.2, ns / ns[g.index("16x16")] if "16x16" in g else ns,
           width=0.4, label="here (JAX, CPU)")
    paper = np.asarray(arrays["raster_paper_ms"], float)
    if "16x16" in g:
        ax.bar(np.arange(len(g)) + 0.2, paper / PAPER_RASTER_MS["16x16"], width=0.4,
               label="paper (GPU, rough)")
    ax.set_xticks(np.arange(len(g)), g)
    ax.set_ylabel("rasterization time / 16x16's")
    ax.legend(fontsize=7)
    ax.set_title("rasterization cost vs grid", fontsize=9)
    imgs = [arrays["edge_truth"]] + list(arrays["shown"])
    names = ["truth (closed form)"] + list(arrays["shown_labels"])
    sub = grid[1, 1:].subgridspec(1, len(imgs))
    for i, (img, nm) in enumerate(zip(imgs, names)):
        ax = fig.add_subplot(sub[0, i])
        ax.imshow(img, cmap="gray", vmin=0, vmax=1, interpolation="nearest")
        if i:
            k = i - 1
            nm = (f"{nm}\npenumbra MAE {arrays['band_penumbra_mae'][k]:.3f}\n"
                  f"bands {arrays['band_amplitude'][k]:.4f}, "
                  f"noise {arrays['noise_amplitude'][k]:.4f}")
        ax.set_title(nm, fontsize=8)
        ax.set_xticks([])
        ax.set_yticks([])
    fig.suptitle(f"bottom: a straight edge under a {float(arrays['edge_sun_deg']):.0f} degree "
                 "sun, parallel to the grid rows (bands: RMS step of the error averaged "
                 "along the edge; noise: RMS of the error about that average)", fontsize=9)
    return fig


def check(arrays: dict, cfg: dict) -> None:
    labels = list(arrays["labels"])
    tiled = np.array(["overlap" not in lab for lab in labels])
    paper = np.array(["overlap" not in lab and "exact" not in lab for lab in labels])
    exact = np.array(["exact" in lab for lab in labels])
    assert np.all(arrays["mae"][tiled] <= float(cfg["max_mae"])), dict(zip(labels, arrays["mae"]))
    # the truth is much better than what it measures
    assert float(arrays["truth_self_mae"]) < 0.5 * float(np.min(arrays["mae"][paper]))
    # every grid's exact variant beats every paper variant on the penumbra
    assert np.max(arrays["penumbra_mae"][exact]) <= np.min(arrays["penumbra_mae"][paper])
    # the naive overlap sum double-counts: worse than the finest grid
    fine = labels.index(f"{cfg['grids'][-1]}")
    assert arrays["mae"][labels.index("overlap sum")] > arrays["mae"][fine]
    # rotation trades bands for noise on the straight edge (not a coin flip: the
    # unrotated error is a function of x alone, the rotated one averages out along z)
    shown = list(arrays["shown_labels"])
    band, noise = arrays["band_amplitude"], arrays["noise_amplitude"]
    for g in ("16x16", "31x3"):
        i, j = shown.index(g), shown.index(g + " rot")
        assert band[j] < 0.25 * band[i] and noise[j] > noise[i] + 1e-3
    assert np.all(np.diff(arrays["embree_mae"]) < 0)       # more rays, less error
    assert np.all(np.asarray(arrays["raster_seconds"]) > 0)


def claims(arrays: dict, cfg: dict) -> list[dict]:
    """The paper's claims on the grid, banding and union-of-occluders, measured."""
    labels = list(arrays["labels"])
    shown = list(arrays["shown_labels"])
    bf = dict(zip(shown, arrays["band_amplitude"]))
    nf = dict(zip(shown, arrays["noise_amplitude"]))
    pm = dict(zip(shown, arrays["band_penumbra_mae"]))
    out = []
    for g in ("16x16", "31x3"):
        out.append({
            "id": "k23.rotation",
            "claim": f"randomly rotating the {g} grid trades banding for noise",
            "measured": f"band amplitude {bf[g]:.4f} -> {bf[g + ' rot']:.4f}, noise "
                        f"{nf[g]:.4f} -> {nf[g + ' rot']:.4f}, penumbra MAE "
                        f"{pm[g]:.4f} -> {pm[g + ' rot']:.4f} (straight edge, "
                        f"{float(arrays['edge_sun_deg']):.0f} degree sun)",
            "holds": bool(bf[g + " rot"] < 0.25 * bf[g] and nf[g + " rot"] > nf[g])})
    out.append({
        "claim": "fewer grid lines band more (31x3 vs 16x16, unrotated)",
        "measured": f"band amplitude {bf['31x3']:.4f} vs {bf['16x16']:.4f}, penumbra MAE "
                    f"{pm['31x3']:.4f} vs {pm['16x16']:.4f}",
        "holds": bool(bf["31x3"] > bf["16x16"])})
    i_fine = labels.index(f"{cfg['grids'][-1]}")
    i_sum = labels.index("overlap sum")
    out.append({
        "id": "k23.overlap_sum",
        "claim": "summing overlap areas double-counts; the bitmask union does not",
        "measured": f"MAE overlap sum {arrays['mae'][i_sum]:.5f} vs {labels[i_fine]} "
                    f"{arrays['mae'][i_fine]:.5f}",
        "holds": bool(arrays["mae"][i_sum] > arrays["mae"][i_fine])})
    g = list(arrays["raster_grids"])
    ns = dict(zip(g, arrays["raster_ns_per_pair"]))
    if "16x16" in ns and "31x3" in ns:
        out.append({
            "id": "k23.grid_31xn",
            "claim": "rasterizing into 31x3 is cheaper than into 16x16 (paper: 2.1 vs 5 ms)",
            "measured": f"{ns['31x3']:.1f} vs {ns['16x16']:.1f} ns per pair (JAX on CPU, "
                        "shared machine)",
            "holds": bool(ns["31x3"] < ns["16x16"])})
    if "31x7" in ns and "31x3" in ns:
        out.append({
            "id": "k23.grid_31xn",
            "claim": "the cost grows with the number of lines (31x3 < 31x7; paper 2.1 vs 3.1 ms)",
            "measured": f"{ns['31x3']:.1f} vs {ns['31x7']:.1f} ns per pair",
            "holds": bool(ns["31x3"] < ns["31x7"])})
    return out


# %%
if __name__ == "__main__":
    from shadowlab.harness.figures import run_as_script

    run_as_script(__file__)
