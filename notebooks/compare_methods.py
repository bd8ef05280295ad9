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
# # Comparing every method on one scene, from a sweep's results table
#
# `shadowlab sweep` writes one row per (grid point, frame, method) to
# `results.parquet`. Point `SHADOWLAB_SWEEP_RESULTS` at such a file to read it;
# otherwise this notebook runs a small sweep itself (every hard-shadow method on the
# gate scene, two scene seeds) on a local Dask cluster.
#
# `SHADOWLAB_NOTEBOOK_SIZE=ci` runs three cheap methods at a tiny size on one worker.

# %%
import os
import tempfile
from pathlib import Path

import matplotlib.pyplot as plt
import pandas as pd

SIZE = os.environ.get("SHADOWLAB_NOTEBOOK_SIZE", "full")
RESULTS = os.environ.get("SHADOWLAB_SWEEP_RESULTS")

# %%
CONFIG = {
    "ci": """
[scene]
source = "gate"
[scene.params]
trees = 2
leaves_per_tree = 20
[camera]
resolution = [24, 24]
[methods]
names = ["brute_force", "d_stackless", "zpass"]
[sweep]
"scene.params.seed" = [0, 1]
""",
    "full": """
[scene]
source = "gate"
[camera]
resolution = [256, 256]
[methods]
names = "all"
[sweep]
"scene.params.seed" = [0, 1]
""",
}[SIZE]

if RESULTS is None:
    from shadowlab.harness.sweep import load_sweep, run_sweep

    folder = Path(tempfile.mkdtemp(prefix="shadowlab-sweep-"))
    (folder / "sweep.toml").write_text(CONFIG)
    sweep = load_sweep(folder / "sweep.toml", repeats=1 if SIZE == "ci" else 3)
    run_sweep(sweep, folder / "out", workers=1 if SIZE == "ci" else 2, progress=False)
    RESULTS = folder / "out" / "results.parquet"

# %% [markdown]
# The table, in one line:

# %%
df = pd.read_parquet(RESULTS)
df.head()

# %% [markdown]
# Per method: errors summed over the grid, the median warm time and its ratio to the
# Embree shadow-ray pass, and the total shadow-volume tests where a method counts them.

# %%
summary = df.groupby("method").agg(
    kind=("kind", "first"), rows=("point", "size"), mismatches=("mismatches", "sum"),
    unexplained=("unexplained", "sum"), warm_ms=("warm_seconds", lambda s: 1e3 * s.median()),
    ratio=("ratio_to_reference", "median"), compile_s=("compile_seconds", "sum"),
).sort_values("warm_ms")
if "tests" in df:
    summary["tests"] = df.groupby("method")["tests"].sum(min_count=1)
summary

# %%
exact = df[df["kind"] == "exact"]
assert (exact["unexplained"].fillna(0) == 0).all(), "an exact method is wrong off shadow edges"
assert len(df) == df.groupby(["point", "frame"]).ngroups * df["method"].nunique()

fig, ax = plt.subplots(figsize=(7, 0.4 * len(summary) + 1.2), constrained_layout=True)
ax.barh(summary.index, summary["ratio"])
ax.axvline(1.0, color="k", lw=0.8)
ax.set_xscale("log")
ax.set_xlabel("median warm time / Embree shadow rays (same task)")
