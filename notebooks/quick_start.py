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
# # Quick start
#
# Load a scene, render its G-buffer, compute the exact reference with Embree, run two
# methods, compare them with the reference and look at their counters.
#
# `SHADOWLAB_NOTEBOOK_SIZE=ci` (what CI sets) runs everything at a small size.

# %%
import os

import shadowlab as sl

SIZE = os.environ.get("SHADOWLAB_NOTEBOOK_SIZE", "full")
RES = {"ci": 32, "full": 256}[SIZE]
PARAMS = {"ci": {"trees": 3, "leaves_per_tree": 40}, "full": {}}[SIZE]

# %% [markdown]
# A procedural scene (a mesh file works the same: `sl.load_scene("model.obj")`) and its
# default view: a camera and a light.

# %%
scene = sl.load_scene("gate", **PARAMS)
view = sl.scene.default_view("gate", scene, **PARAMS)
camera = view.camera.replace(resolution=(RES, RES))
light = view.light
print(scene.name, scene.num_triangles, "triangles;", light)

# %% [markdown]
# The G-buffer (position, normal, depth, triangle id and a valid mask per pixel) and the
# exact reference: an Embree shadow ray per pixel, `True` = lit.

# %%
gbuf = sl.render_gbuffer(scene, camera)
truth = sl.reference_shadows(scene, gbuf, light)
print(f"{gbuf.valid.sum()} valid pixels, {truth.sum()} lit")

# %% [markdown]
# A method returns a `ShadowResult`: the lit mask, counters and timings (compile time
# kept apart). In Jupyter it shows itself: lit, error against the reference, and a
# counter heat map.

# %%
res = sl.compute_shadows(scene, gbuf, light, method="clustered_ptsv")
mismatches = int(((res.lit != truth) & gbuf.valid).sum())
print("mismatches against the reference:", mismatches)
assert mismatches == 0                     # an exact method
res.with_reference(truth, gbuf.valid)

# %% [markdown]
# `sl.evaluate` is the harness's single entry point: the method under the timing protocol
# (a warm-up call, then the median of warm calls), its reference and its metric; the
# result comes with the reference attached.

# %%
ev = sl.evaluate(scene, gbuf, light, "brute_force", repeats=1)
print(ev.error)
print({k: round(v, 5) for k, v in ev.timings.items()})
assert ev.error["mismatches"] == 0

# %% [markdown]
# Counters: the scalar ones, and per-pixel maps (`*_per_pixel`). Every counter is
# documented in docs/counters.md.

# %%
for name, value in res.scalar_counters().items():
    print(f"{name:24} {value}")
tests = res.counter_maps()["tests_per_pixel"]
assert tests.sum() == res.counters["tests"]
fig = res.plot(counter="tests_per_pixel")
