# ---
# jupyter:
#   jupytext:
#     text_representation:
#       extension: .py
#       format_name: percent
# ---

# %% [markdown]
# # The cluster hierarchy against PTSV on a city (Sintorn et al. 2014, Fig. 6, Sec. 2.1)
#
# A finding from a scene outside the paper: on a city (closed boxes on a ground slab, a
# wall of thin posts between the camera and the buildings, a point light high above),
# `clustered_ptsv` needed more test-and-sets than `ptsv`, where the paper claims as many
# or fewer. This experiment measures that claim on the `city` scene at several
# resolutions, with the four candidate causes apart:
#
# - **the leaf test**: a cluster leaf tests every sample of its 8 x 8 tile (the paper's
#   choice, the default) or only the cluster's own samples (`leaf_samples="cluster"`);
#   tests per leaf visit and clusters per occupied tile show how often one tile's samples
#   are tested once per cluster;
# - **the baseline's sample set**: our `ptsv` builds over the light-facing samples,
#   PTSV 2011 over the whole depth buffer (`tree_samples="all"`);
# - **where the work is**: tests at pixels of 8 x 4 tiles spanning a steep depth
#   discontinuity (max / min depth > 2) against the rest;
# - **tree quality**: leaf visits and node tests of each tree.

# %%
from __future__ import annotations

import numpy as np

import shadowlab as sl
from shadowlab.analysis.metrics import discontinuity_mask
from shadowlab.harness import checkpoints
from shadowlab.harness.claims import measured
from shadowlab.reference.boundary import unexplained_count
from shadowlab.scene.procedural import default_view

VARIANTS = (("ptsv", "ptsv", {}),
            ("ptsv (2011 build)", "ptsv", {"tree_samples": "all"}),
            ("clustered", "clustered_ptsv", {}),
            ("clustered, cluster-only leaves", "clustered_ptsv", {"leaf_samples": "cluster"}),
            ("clustered (implicit)", "clustered_ptsv", {"bounds": "implicit"}))
COUNTERS = ("tests", "leaf_visits", "node_tests", "tests_at_discontinuities",
            "tests_elsewhere")


def _resolution_point(cfg, scene, view, res) -> dict:
    """One resolution's counters [V, 5], mismatches and unexplained [V], valid and
    steep pixels, and clusters per occupied 8 x 8 tile."""
    gbuf = sl.render_gbuffer(scene, view.camera.replace(resolution=res))
    truth = sl.reference_shadows(scene, gbuf, view.light)
    steep = discontinuity_mask(gbuf)
    ty, tx = np.nonzero(gbuf.valid)
    occupied = len(np.unique((ty // 8) * (-(-res[0] // 8)) + tx // 8))
    out = {"counters": [], "mismatches": [], "unexplained": [], "clusters_per_tile": None}
    for j, (_, method, opts) in enumerate(VARIANTS):
        r = sl.compute_shadows(scene, gbuf, view.light, method=method,
                               precision=cfg.get("precision", "float32"), **opts)
        c = r.counters
        tp = np.asarray(c["tests_per_pixel"])
        out["counters"].append([int(c["tests"]), int(c["leaf_visits"]), int(c["node_tests"]),
                                int(tp[steep].sum()), int(tp[gbuf.valid & ~steep].sum())])
        out["mismatches"].append(int(np.count_nonzero((r.lit != truth) & gbuf.valid)))
        out["unexplained"].append(int(unexplained_count(scene, gbuf, view.light, r.lit, truth)))
        if j == 2:
            out["clusters_per_tile"] = float(c["clusters"] / max(occupied, 1))
    out["valid"] = int(gbuf.valid.sum())
    out["steep_pixels"] = int(steep.sum())
    return out


def run(cfg: dict) -> dict:
    """Per resolution R ([R, 2] width, height) and variant V: counters [R, V, 5] (COUNTERS), mismatches and
    unexplained mismatches [R, V]; per resolution: valid pixels, pixels at
    discontinuities and clusters per occupied 8 x 8 tile [R]."""
    name = cfg.get("scene", "city")
    params = dict(cfg.get("params", {}))
    scene = sl.load_scene(name, **params)
    view = default_view(name, scene, **params)
    resolutions = [tuple(int(x) for x in r) for r in cfg["resolutions"]]
    # one checkpointed point per resolution (a stopped figures run resumes finished ones)
    points = [checkpoints.point(f"resolution={res[0]}x{res[1]}",
                                lambda: _resolution_point(cfg, scene, view, res))
              for res in resolutions]
    counters = np.asarray([p["counters"] for p in points], np.int64).reshape(
        len(resolutions), len(VARIANTS), len(COUNTERS))
    mism = np.asarray([p["mismatches"] for p in points], np.int64)
    unex = np.asarray([p["unexplained"] for p in points], np.int64)
    valid = [p["valid"] for p in points]
    steep_px = [p["steep_pixels"] for p in points]
    per_tile = [p["clusters_per_tile"] for p in points]
    return {"resolutions": np.asarray(resolutions), "counters": counters,
            "counter_names": np.asarray(COUNTERS),
            "labels": np.asarray([v[0] for v in VARIANTS]),
            "mismatches": mism, "unexplained": unex, "valid": np.asarray(valid),
            "steep_pixels": np.asarray(steep_px), "clusters_per_tile": np.asarray(per_tile),
            "triangles": np.asarray(scene.num_triangles)}


def _col(arrays, name):
    return arrays["counters"][..., list(arrays["counter_names"]).index(name)]


def plot(arrays: dict):
    import matplotlib.pyplot as plt

    res = arrays["resolutions"][:, 0]
    tests = _col(arrays, "tests").astype(np.float64)
    per_leaf = tests / np.maximum(_col(arrays, "leaf_visits"), 1)
    fig, (a1, a2) = plt.subplots(1, 2, figsize=(10, 4), constrained_layout=True)
    for j, label in enumerate(arrays["labels"]):
        if j == 0:
            continue
        a1.plot(res, tests[:, j] / tests[:, 0], "o-", label=label)
    a1.axhline(1.0, color="gray", lw=0.8, ls=":")
    a1.set_xscale("log", base=2)
    a1.set_xlabel("image width (pixels)")
    a1.set_ylabel("test-and-sets / ptsv's")
    a1.set_title(f"city ({int(arrays['triangles'])} tris): work against our ptsv", fontsize=10)
    a1.legend(fontsize=8)
    for j, label in enumerate(arrays["labels"]):
        a2.plot(res, per_leaf[:, j], "o-", label=label)
    a2.set_xscale("log", base=2)
    a2.set_xlabel("image width (pixels)")
    a2.set_ylabel("tests per leaf visit")
    a2.set_title("the leaf test: 8x8 tiles (clustered) vs 8x4 (PTSV)", fontsize=10)
    a2.legend(fontsize=8)
    return fig


def check(arrays: dict, cfg: dict) -> None:
    """No unexplained mismatch (docs/exactness.md); the per-pixel tests split into
    discontinuities and the rest add up to the totals; cluster-only leaves never test
    more than whole-tile leaves (same tree, a subset of each leaf's samples)."""
    assert np.all(arrays["unexplained"] == 0), (arrays["mismatches"], arrays["unexplained"])
    assert np.array_equal(_col(arrays, "tests_at_discontinuities")
                          + _col(arrays, "tests_elsewhere"), _col(arrays, "tests"))
    labels = list(arrays["labels"])
    tile, own = labels.index("clustered"), labels.index("clustered, cluster-only leaves")
    assert np.all(_col(arrays, "tests")[:, own] <= _col(arrays, "tests")[:, tile])
    assert np.all(arrays["steep_pixels"] > 0)


def claims(arrays: dict, cfg: dict) -> list[dict]:
    """Sintorn 2014, Fig. 6 / Sec. 2.1 on a city: the hierarchy (explicit bounds, the
    paper's whole-tile leaf test) needs as many test-and-sets as PTSV or fewer, at every
    resolution; against our light-facing `ptsv` and against the 2011 build. When it
    fails, the note gives the measured leaf-test numbers."""
    labels = list(arrays["labels"])
    k = {name: labels.index(name) for name in labels}
    tests = _col(arrays, "tests").astype(np.float64)
    visits = np.maximum(_col(arrays, "leaf_visits"), 1)
    res = [f"{w}x{h}" for w, h in arrays["resolutions"]]
    cl, own = k["clustered"], k["clustered, cluster-only leaves"]
    out = []
    for base, label in (("ptsv", "vs our ptsv (light-facing build)"),
                        ("ptsv (2011 build)", "vs PTSV 2011 (whole depth buffer)")):
        b = k[base]
        ratio = tests[:, cl] / tests[:, b]
        ratio_own = tests[:, own] / tests[:, b]
        text = ", ".join(f"{r}: {x:.2f} (cluster-only leaves {y:.2f})"
                         for r, x, y in zip(res, ratio, ratio_own))
        holds = bool(np.all(ratio <= 1.0))
        note = ""
        if not holds:
            i = int(np.argmax(ratio))
            away = _col(arrays, "tests_elsewhere")[i] / np.maximum(_col(arrays, "tests")[i], 1)
            note = (f"at {res[i]} a cluster leaf tests {tests[i, cl] / visits[i, cl]:.1f} "
                    f"samples per visit against PTSV's {tests[i, b] / visits[i, b]:.1f}: the "
                    f"paper's leaf tests its whole 8 x 8 tile, and the occupied tiles hold "
                    f"{arrays['clusters_per_tile'][i]:.2f} clusters each (a tile whose samples "
                    f"span a range of depths covers several depth slices), so a volume reaching several "
                    f"clusters of a tile tests its samples once per cluster; testing only "
                    f"the cluster's samples gives {ratio_own[i]:.2f}x; "
                    f"{100 * away[cl]:.0f} % of the hierarchy's tests are away from depth "
                    f"discontinuities, where the paper expects no advantage; the explicit "
                    f"tree visits {visits[i, b] / visits[i, cl]:.1f}x fewer leaves than "
                    f"PTSV's")
        out.append(measured("s14.city.le_ptsv", f"clustered / PTSV test-and-sets: {text}",
                            holds, label=label, note=note))
    return out


# %%
if __name__ == "__main__":
    from shadowlab.harness.figures import run_as_script

    run_as_script(__file__)
