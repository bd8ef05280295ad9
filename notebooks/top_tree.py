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
# # Anatomy of a TOP tree (Gerhards et al. 2015; Mora et al. 2016)
#
# Partitioned shadow volumes insert every caster's shadow volume (three edge planes and
# a cap) into a ternary tree: a triangle goes to the positive (outside), negative
# (inside) or intersection child of each plane it meets. A query walks the tree for one
# view sample. Here: the tree's size and depth, its intersection subtrees, and one
# query's path, replayed node by node and checked against the `psv` method.
#
# `SHADOWLAB_NOTEBOOK_SIZE=ci` runs at a small size.

# %%
import os

import matplotlib.pyplot as plt
import numpy as np

import shadowlab as sl
from shadowlab.core.frame import precision_mode, view_samples
from shadowlab.methods import psv as psvm
from shadowlab.structures import top_tree as tt

SIZE = os.environ.get("SHADOWLAB_NOTEBOOK_SIZE", "full")
NAME, PARAMS, RES = {"ci": ("sphere_grid", {"n": 2, "triangles_per_sphere": 128}, 24),
                     "full": ("sphere_grid", {"n": 4}, 256)}[SIZE]

scene = sl.load_scene(NAME, **PARAMS)
view = sl.scene.default_view(NAME, scene, **PARAMS)
gbuf = sl.render_gbuffer(scene, view.camera.replace(resolution=(RES, RES)))
light = view.light
samples = view_samples(gbuf, light)
light_h = sl.scene.view.hard_light(light).homogeneous

# %% [markdown]
# ## The tree
#
# Built exactly as `psv` builds it (the method's defaults: seeded random insertion order,
# the conservative wedge bound, closed objects' light-averted triangles culled, float32).

# %%
with precision_mode("float32") as dtype:
    tree, scale, _ = psvm.build_tree(scene, light, gbuf.camera, samples, dtype=dtype,
                                     shadow_eps=1e-5, bias="receiver", order="random",
                                     seed=0, wedge="conservative", classify_ulps=64,
                                     face_culling=sl.methods.get("psv").options["face_culling"].default)
stats = tree.stats()
for k, v in stats.items():
    print(f"{k:24} {v}")
merged = tree.status == tt.STATUS_MERGED
assert stats["merged_triangles"] + stats["dropped_triangles"] == tree.count

# %% [markdown]
# Depth: the number of nodes from the root to each shadow volume's first node. Volumes
# with an ancestor link (`anc >= 0`) sit in the intersection subtree of that node.

# %%
sizes = np.bincount(tree.anc[merged & (tree.anc >= 0)], minlength=4 * tree.capacity)
print(f"{(sizes > 0).sum()} nodes hold an intersection subtree; largest: {sizes.max()} "
      "volumes")
fig, axes = plt.subplots(1, 2, figsize=(9, 3.4), constrained_layout=True)
axes[0].hist(tree.level[merged], bins=30)
axes[0].set_xlabel("depth of the volume's first node")
axes[0].set_ylabel("shadow volumes")
axes[1].hist(sizes[sizes > 0], bins=20)
axes[1].set_xlabel("volumes in an intersection subtree")

# %% [markdown]
# ## One query's path
#
# The stack query (Gerhards et al. 2015), one node at a time: at an edge node the
# sample goes inside (next plane of the same volume) or outside (the positive child);
# an intersection child is pushed to be visited later when the wedge bound says it can
# matter. Reaching the inside of a cap means shadowed. We replay the sample where `psv`
# visits the most nodes and check the visit count and the answer.


# %%
def query_path(p, s, dist):
    """(lit, [visited nodes]) of the stack query for one sample (float32 arithmetic)."""
    path, stack, node = [], [], tree.root
    while node >= 0:
        path.append(node)
        sv, cap = node >> 2, (node & 3) == 3
        pl = tree.plane[node]
        off = float(p[0] * pl[0] + p[1] * pl[1] + p[2] * pl[2] + pl[3])
        inside = (off * s < tree.bound[sv]) if cap else off >= 0
        if tree.inter[node] >= 0 and (cap or abs(off) <= tree.wedge[node] * dist + tree.margin):
            stack.append(int(tree.inter[node]))
        if not inside:
            node = int(tree.pos[node]) if tree.pos[node] >= 0 else (stack.pop() if stack else -1)
        elif cap:
            return False, path
        else:
            node += 1
    return True, path


res = sl.compute_shadows(scene, gbuf, light, method="psv", stack_size=63)
visited = res.counters["visited_nodes_per_pixel"].reshape(-1)[samples.index]
i = int(np.argmax(visited))
p = samples.position[i].astype(np.float32)
dist = 1.0 if light_h[3] == 0 else float(np.linalg.norm(samples.position[i] - light_h[:3]))
lit, path = query_path(p, np.float32(scale[i]), dist)
print(f"sample {i}: {len(path)} nodes visited, lit = {lit}")
assert len(path) == visited[i] and lit == res.lit.reshape(-1)[samples.index[i]]
assert res.counters["stack_overflows"] == 0

kinds = np.array(path) & 3
fig, ax = plt.subplots(figsize=(9, 3), constrained_layout=True)
ax.plot(tree.level[np.array(path) >> 2] + kinds, ".-", lw=0.6)
ax.set_xlabel("step")
ax.set_ylabel("node depth")
ax.set_title(f"the path of sample {i} ({'lit' if lit else 'shadowed'})")
res
