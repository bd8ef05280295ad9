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
# # Anatomy of the cluster hierarchy (Sintorn et al. 2014)
#
# `clustered_ptsv` groups the view samples into clusters: 8 x 8 pixel tiles split by
# exponential depth slices, keyed by a Morton-interleaved integer. A 32-ary tree over
# the keys is what each triangle's shadow volume is tested against, top down. Here: the
# key layout, the levels and their nodes, the clusters in the image, and where the
# tests go.
#
# `SHADOWLAB_NOTEBOOK_SIZE=ci` runs at a small size.

# %%
import os

import matplotlib.pyplot as plt
import numpy as np

import shadowlab as sl
from shadowlab.core.frame import view_samples
from shadowlab.structures import cluster_hierarchy as ch

SIZE = os.environ.get("SHADOWLAB_NOTEBOOK_SIZE", "full")
RES = {"ci": 48, "full": 512}[SIZE]
PARAMS = {"ci": {"trees": 3, "leaves_per_tree": 40}, "full": {}}[SIZE]

scene = sl.load_scene("gate", **PARAMS)
view = sl.scene.default_view("gate", scene, **PARAMS)
gbuf = sl.render_gbuffer(scene, view.camera.replace(resolution=(RES, RES)))
light = view.light

# %% [markdown]
# ## The key layout
#
# x and y tile bits from the resolution, two more depth bits than the larger of them
# (the paper's choice), interleaved round robin from the least significant bit. Each
# level of the tree consumes 5 key bits (32 children).

# %%
tree = ch.cluster_layout(gbuf.camera)
axis = "xyz"
print(f"key bits (x, y, z) = {tree.bits}, {tree.key_bits} bits, D = {tree.levels} mask levels")
print("layout, least significant bit first:", "".join(axis[a] for a in tree.layout))
print(f"depth slice ratio r = {np.exp(tree.log_ratio):.4f}; near {tree.near:.3g}, "
      f"far {tree.far:.3g}; eq. (1) needs more slices than the key holds: {tree.saturates}")
for level in range(tree.levels + 1):
    ext = [1 << tree.extent_bits(level, a) for a in range(3)]
    print(f"level {level}: {tree.nodes(level):>8} possible nodes, a node spans "
          f"{ext[0]} x {ext[1]} tiles x {ext[2]} slices")

# %% [markdown]
# ## The clusters of this view
#
# The key of every light-facing sample (a plain NumPy loop), the nodes that exist at
# each level, and the clusters drawn in the image (one colour per key).

# %%
samples = view_samples(gbuf, light)
py, px = np.unravel_index(samples.index, gbuf.valid.shape)
depth = gbuf.depth.reshape(-1)[samples.index]
keys = ch.sample_keys_numpy(tree, px, py, depth)
masks = ch.masks_numpy(tree, keys)
existing = [1] + [int(sum(bin(int(w)).count("1") for w in m)) for m in masks]
for level, n in enumerate(existing):
    print(f"level {level}: {n} existing nodes")
leaves = np.unique(keys)
assert existing[-1] == len(leaves)

image = np.full(gbuf.valid.shape, np.nan)
image.reshape(-1)[samples.index] = np.searchsorted(leaves, keys) * 0.618 % 1.0
slices = np.full(gbuf.valid.shape, np.nan)
slices.reshape(-1)[samples.index] = [int(k) for k in keys]
fig, axes = plt.subplots(1, 2, figsize=(9, 4), constrained_layout=True)
axes[0].imshow(image, cmap="hsv", interpolation="nearest")
axes[0].set_title(f"{len(leaves)} clusters (one colour each)")
z = np.full(gbuf.valid.shape, np.nan)
zb = np.floor(np.log(depth / tree.near) / tree.log_ratio).clip(0, tree.slices - 1)
z.reshape(-1)[samples.index] = zb
im = axes[1].imshow(z, cmap="viridis", interpolation="nearest")
fig.colorbar(im, ax=axes[1], label="depth slice")
axes[1].set_title("depth slice of each sample")
for ax in axes:
    ax.set_xticks([]); ax.set_yticks([])

# %% [markdown]
# ## Where the tests go
#
# The method's own counters: the hierarchy it built (which must have the clusters
# counted above), node tests, trivial accepts and rejects, and the per-pixel count of
# sample-level test-and-sets.

# %%
res = sl.compute_shadows(scene, gbuf, light, method="clustered_ptsv")
c = res.counters
print({k: c[k] for k in ("clusters", "hierarchy_nodes", "node_tests", "trivial_accepts",
                         "trivial_rejects", "leaf_visits", "tests")})
assert c["clusters"] == len(leaves)
assert c["hierarchy_nodes"] == sum(existing[1:])
truth = sl.reference_shadows(scene, gbuf, light)
assert ((res.lit != truth) & gbuf.valid).sum() == 0
fig = res.plot(reference=truth, valid=gbuf.valid)
