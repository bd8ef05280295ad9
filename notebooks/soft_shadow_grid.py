# ---
# jupyter:
#   jupytext:
#     text_representation:
#       extension: .py
#       format_name: percent
#   kernelspec:
#     display_name: Python 3
#     language: python
#     name: python3
# ---

# %% [markdown]
# # The soft-shadow grid and its error (Kalbertodt 2023)
#
# `soft_tiled` estimates how much of an area light (the sun's disk, or a sphere's
# silhouette) each pixel sees by rasterizing every blocker triangle into a bitmask grid
# over the disk. The grid's cells are the visibility's resolution: this notebook draws
# the grids, then measures the error of each against the Monte Carlo ray-cast reference.
#
# `SHADOWLAB_NOTEBOOK_SIZE=ci` runs at a small size with two grids.

# %%
import os

import matplotlib.pyplot as plt
import numpy as np

import shadowlab as sl
from shadowlab.analysis import compare_soft
from shadowlab.structures import sun_disk

SIZE = os.environ.get("SHADOWLAB_NOTEBOOK_SIZE", "full")
RES, PARAMS, RAYS, GRIDS = {
    "ci": (32, {"size": 24}, 256, ("16x16", "31x7")),
    "full": (256, {}, 1024, ("31x3", "31x7", "16x16", "31x15", "31x31")),
}[SIZE]

# %% [markdown]
# ## The grids
#
# A cell belongs to the disk when its centre lies in the unit disk; visibility is the
# fraction of disk cells no blocker covers, so its step is 1 / (disk cells).

# %%
fig, axes = plt.subplots(1, len(GRIDS), figsize=(2.6 * len(GRIDS), 2.8), constrained_layout=True)
for ax, name in zip(np.atleast_1d(axes), GRIDS):
    g = sun_disk.grid(name)
    ax.imshow(g.disk_cells(), cmap="Greys", extent=(-1, 1, -1, 1), interpolation="nearest")
    ax.add_patch(plt.Circle((0, 0), 1, fill=False, color="tab:red"))
    ax.set_title(f"{name}: {g.disk_bits} cells, {g.words} words", fontsize=9)
    ax.set_xticks([]); ax.set_yticks([])

# %% [markdown]
# ## The error of each grid
#
# The terrain under a low sun; the reference shoots rays to uniform points of the disk.

# %%
scene = sl.load_scene("terrain", **PARAMS)
view = sl.scene.default_view("terrain", scene, **PARAMS)
gbuf = sl.render_gbuffer(scene, view.camera.replace(resolution=(RES, RES)))
truth = sl.soft_reference(scene, gbuf, view.light, rays_per_pixel=RAYS, seed=0)
rows = []
results = {}
for name in GRIDS:
    res = sl.compute_shadows(scene, gbuf, view.light, method="soft_tiled", grid=name)
    err = compare_soft(res.lit, truth, gbuf.valid)
    results[name] = res
    rows.append((name, sun_disk.grid(name).disk_bits, err["mae"], err["max_error"]))
    assert 0.0 <= res.lit.min() and res.lit.max() <= 1.0
print(f"{'grid':>6} {'cells':>6} {'MAE':>8} {'max':>8}")
for name, cells, mae, mx in rows:
    print(f"{name:>6} {cells:>6} {mae:8.4f} {mx:8.4f}")
print(f"reference noise: about {0.5 / np.sqrt(RAYS):.4f} (std. dev. of {RAYS} rays at 50 %)")

# %% [markdown]
# The grid with the smallest MAE against the reference: visibility, |error| and the
# tests per pixel.

# %%
best = min(rows, key=lambda r: r[2])[0]
results[best].plot(reference=truth, valid=gbuf.valid)
