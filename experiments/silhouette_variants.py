# ---
# jupyter:
#   jupytext:
#     text_representation:
#       extension: .py
#       format_name: percent
# ---

# %% [markdown]
# # `silhouette` variants on an architectural scene, and what the paper's shortcuts break
#
# The analogue of Pečiva 2013, Tables 5-6 (the variants on Sponza: visibility test on
# and off, sides and caps with the front cap at infinity, ZPASS and ZFAIL) on the
# procedural `atrium` (columns, open arches, an open gallery, single-sided banners; Sponza
# is not available), plus the 2-manifold fast path. Per variant: the work (silhouette
# edges, side quads, culled sides, cap triangles, stencil updates), the warm time and
# the mismatched pixels against the reference, with an error image. The paper's own
# test (`cull_sides="paper"`) with ZFAIL shows what its near/far-plane and diagonal
# choices cull. Shadow maps run when a `shadow_map` method is registered
# (`shadow_map_resolutions`).

# %%
from __future__ import annotations

import statistics
import time

import numpy as np

import shadowlab as sl
from shadowlab.analysis.metrics import error_map
from shadowlab.methods import registry
from shadowlab.reference.boundary import unexplained_count
from shadowlab.scene.procedural import default_view

#: the paper's general path (every triangle casts): the variants of its Tables 5-6 run it;
#: the method's default is the 2-manifold fast path (the "manifold" variant)
GENERAL = {"manifold": "off"}
VARIANTS = {
    "zpass": GENERAL,
    "zpass+a": {**GENERAL, "cull_sides": "exact"},
    "zfail": {**GENERAL, "stencil": "zfail"},
    "zfail+a": {**GENERAL, "stencil": "zfail", "cull_sides": "exact"},
    "zfail+c": {**GENERAL, "stencil": "zfail", "front_cap": "infinity"},
    "zfail+ac": {**GENERAL, "stencil": "zfail", "front_cap": "infinity", "cull_sides": "exact"},
    "manifold": {"manifold": "closed"},
    "paper zpass": {"preset": "paper"},
    "paper zfail": {"preset": "paper", "stencil": "zfail"},
}
#: the variant each one is compared with, pixel by pixel (an option that must not change
#: the image is measured against the run without it)
BASE = {"zpass+a": "zpass", "zfail": "zpass", "zfail+a": "zfail", "zfail+c": "zfail",
        "zfail+ac": "zfail+c", "manifold": "zpass", "paper zpass": "zpass",
        "paper zfail": "zfail"}
WORK = ("silhouette_edges", "side_quads", "culled_sides", "cap_triangles", "stencil_updates",
        "negative_stencil")


def run(cfg: dict) -> dict:
    name = cfg.get("scene", "atrium")
    params = dict(cfg.get("params", {}))
    scene = sl.load_scene(name, **params)
    view = default_view(name, scene, **params)
    gbuf = sl.render_gbuffer(scene, view.camera.replace(resolution=tuple(cfg["resolution"])))
    repeats = int(cfg.get("repeats", 1))
    truth = sl.reference_shadows(scene, gbuf, view.light)
    out = {k: [] for k in ("seconds", "mismatches", "unexplained", "changed", "error", *WORK)}
    lit = {}
    for name, opts in VARIANTS.items():
        res = sl.compute_shadows(scene, gbuf, view.light, method="silhouette", **opts)
        times = []
        for _ in range(repeats):
            t0 = time.perf_counter()
            sl.compute_shadows(scene, gbuf, view.light, method="silhouette", **opts)
            times.append(time.perf_counter() - t0)
        out["seconds"].append(statistics.median(times))
        lit[name] = res.lit
        out["mismatches"].append(int(((res.lit != truth) & gbuf.valid).sum()))
        out["unexplained"].append(unexplained_count(scene, gbuf, view.light, res.lit, truth))
        base = lit.get(BASE.get(name), res.lit)
        out["changed"].append(int(((res.lit != base) & gbuf.valid).sum()))
        out["error"].append(error_map(res.lit, truth, gbuf.valid))
        for w in WORK:
            out[w].append(int(res.counters[w]))
    arrays = {k: np.asarray(v) for k, v in out.items()}
    t0 = time.perf_counter()
    sl.reference_shadows(scene, gbuf, view.light)
    arrays["embree_seconds"] = np.asarray(time.perf_counter() - t0)
    sm = [int(r) for r in cfg.get("shadow_map_resolutions") or []]
    arrays["sm_resolutions"] = np.asarray(sm, dtype=np.int64)
    arrays["sm_mismatches"] = np.asarray([
        int(((sl.compute_shadows(scene, gbuf, view.light, method="shadow_map",
                                 resolution=r).lit != truth) & gbuf.valid).sum())
        if "shadow_map" in registry.names() else -1 for r in sm], dtype=np.int64)
    arrays["variants"] = np.asarray(list(VARIANTS))
    arrays["reference"] = truth
    arrays["valid"] = gbuf.valid
    arrays["triangles"] = np.asarray(scene.num_triangles)
    return arrays


def plot(arrays: dict):
    import matplotlib.pyplot as plt

    from shadowlab.analysis.plots import ERROR_COLORS, shade

    names = list(arrays["variants"])
    fig, axes = plt.subplots(1, 3, figsize=(13, 4), constrained_layout=True)
    axes[0].imshow(shade(arrays["reference"], arrays["valid"]), cmap="gray", vmin=0, vmax=1)
    axes[0].set_title(f"atrium reference ({int(arrays['triangles'])} triangles)", fontsize=9)
    worst = int(np.argmax(arrays["mismatches"]))
    unexplained = int(arrays["unexplained"][worst])
    axes[1].imshow(arrays["error"][worst], cmap=ERROR_COLORS, vmin=-1, vmax=1,
                   interpolation="nearest")
    rows, cols = np.nonzero(arrays["error"][worst])
    if 0 < len(rows) <= 50:        # single pixels vanish at full size: ring them
        axes[1].scatter(cols, rows, s=120, facecolors="none", edgecolors="r", linewidths=1)
    axes[1].set_title(f"{names[worst]}: {arrays['mismatches'][worst]} wrong px "
                      f"({unexplained} off a boundary), "
                      f"{arrays['culled_sides'][worst]} culled sides", fontsize=9)
    for ax in axes[:2]:
        ax.set_xticks([])
        ax.set_yticks([])
    y = np.arange(len(names))
    axes[2].barh(y, 1000 * arrays["seconds"], color="#d08c2b")
    axes[2].axvline(1000 * float(arrays["embree_seconds"]), color="k", ls=":", label="Embree")
    axes[2].set_yticks(y, [f"{n} ({q} quads, {u} upd.)" for n, q, u in
                           zip(names, arrays["side_quads"], arrays["stencil_updates"])],
                       fontsize=7)
    axes[2].set_xlabel("ms (warm, median; shared 2-core machine)")
    axes[2].legend(fontsize=7)
    return fig


def check(arrays: dict, cfg: dict) -> None:
    """Every default-bias variant is exact up to shadow-boundary pixels (no unexplained
    mismatch, no negative count); culling changes neither the image nor the updates."""
    names = list(arrays["variants"])
    for i, n in enumerate(names):
        if not n.startswith("paper"):
            assert arrays["unexplained"][i] == 0, (n, arrays["unexplained"][i])
            assert arrays["negative_stencil"][i] == 0, n
    for a, b in (("zpass", "zpass+a"), ("zfail", "zfail+a"), ("zfail+c", "zfail+ac")):
        i, j = names.index(a), names.index(b)
        assert arrays["stencil_updates"][i] == arrays["stencil_updates"][j], (a, b)
        assert arrays["changed"][j] == 0, (b, arrays["changed"][j])
        assert arrays["culled_sides"][i] == 0
    assert np.all(arrays["unexplained"] <= arrays["mismatches"])


def _wrong(arrays: dict, i: int) -> str:
    return (f"{arrays['mismatches'][i]} wrong px ({arrays['unexplained'][i]} off a shadow "
            f"boundary)")


def claims(arrays: dict, cfg: dict) -> list[dict]:
    names = list(arrays["variants"])
    at = {n: i for i, n in enumerate(names)}
    j, c, k, m, i = (at[n] for n in ("zpass+a", "zfail+c", "paper zfail", "manifold", "zpass"))
    ms = {n: 1000 * float(arrays["seconds"][at[n]]) for n in names}
    return [
        {"id": "p13.visibility_test",
         "claim": "the visibility test culls sides and saves time (Tables 5-6 'a')",
         "measured": f"{arrays['culled_sides'][j]} of {arrays['silhouette_edges'][j]} "
                     f"silhouette records culled; ZPASS {ms['zpass+a']:.0f} ms against "
                     f"{ms['zpass']:.0f} ms without, ZFAIL {ms['zfail+a']:.0f} against "
                     f"{ms['zfail']:.0f} ms (warm medians, shared machine)",
         "holds": bool(arrays["culled_sides"][j] > 0 and ms["zpass+a"] < ms["zpass"]
                       and ms["zfail+a"] < ms["zfail"])},
        {"claim": "the exact visibility test culls sides without changing the image",
         "measured": f"{arrays['changed'][j]} px changed by culling; " + _wrong(arrays, j),
         "holds": bool(arrays["culled_sides"][j] > 0 and arrays["changed"][j] == 0
                       and arrays["unexplained"][j] == 0)},
        {"id": "p13.caps_infinity",
         "claim": "sides and caps with the front cap at infinity give the same image "
                  "(Table 5 'c')",
         "measured": f"{arrays['changed'][c]} px differ from true front caps (ZFAIL); "
                     + _wrong(arrays, c),
         "holds": bool(arrays["changed"][c] == 0 and arrays["unexplained"][c] == 0)},
        {"id": "p13.visibility_exact",
         "claim": "the paper's test and choices (preset 'paper') are exact with ZFAIL",
         "measured": f"{_wrong(arrays, k)}, {arrays['culled_sides'][k]} culled sides, "
                     f"{arrays['changed'][k]} px differ from the default ZFAIL",
         "holds": bool(arrays["unexplained"][k] == 0)},
        {"id": "p13.manifold_sides",
         "claim": "the 2-manifold fast path draws fewer sides (GS2M)",
         "measured": f"{arrays['side_quads'][m]} vs {arrays['side_quads'][i]} quads "
                     f"(atrium: open geometry too)",
         "holds": bool(arrays["side_quads"][m] < arrays["side_quads"][i])},
        {"id": "p13.manifold_faster",
         "claim": "the 2-manifold fast path is faster than the general one",
         "measured": f"{ms['manifold']:.0f} ms against {ms['zpass']:.0f} ms (ZPASS; warm "
                     f"medians, shared machine)",
         "holds": bool(ms["manifold"] < ms["zpass"])},
    ]


# %%
if __name__ == "__main__":
    from shadowlab.harness.figures import run_as_script

    run_as_script(__file__)
