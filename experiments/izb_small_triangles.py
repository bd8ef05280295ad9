# ---
# jupyter:
#   jupytext:
#     text_representation:
#       extension: .py
#       format_name: percent
# ---

# %% [markdown]
# # The small-triangle limit of the conservative shadow map
#
# Tokuyoshi and Mizokuchi 2018: "the conservative shadow map is not efficient for
# triangles smaller than the texel". A terrain is tessellated ever finer at a fixed view
# and light-map resolution; for each tessellation: the median light-space area of the
# casters (texels), the CSM culling rate (culled / shadowed samples, both coverage
# tests) and the CSM stage time. A triangle smaller than 2 texels never covers a texel
# (the smallest triangle holding a unit square has area 2; the circle test needs
# 3 sqrt(3) / 2 = 2.6).
# `shadowlab figures --only izb_small_triangles` regenerates `figures/izb_small_triangles.*`.

# %%
from __future__ import annotations

import numpy as np

import shadowlab as sl
from shadowlab.core.frame import view_samples
from shadowlab.harness import References, evaluate
from shadowlab.harness.claims import outcome
from shadowlab.methods.izb import light_area
from shadowlab.methods.shadow_map import fit_camera
from shadowlab.scene.procedural import default_view
from shadowlab.structures import light_raster as lr


def median_area(scene, gbuf, light, resolution: int) -> float:
    """Median projected area (texels) of the triangles in front of the light on the
    light camera ``izb`` fits (first face)."""
    samples = view_samples(gbuf, light)
    cam = fit_camera(scene, samples, light, resolution, "auto")
    st = lr.setup_face(cam.faces[0], scene.triangles)
    area = light_area(st)[st.front & st.ok]
    return float(np.median(area)) if area.size else 0.0


def run(cfg: dict) -> dict:
    """Per tessellation size [N]: triangles, median area, rates and CSM seconds [N, 2]."""
    sizes = list(cfg["options"]["sizes"])
    light_res = int(cfg["options"].get("resolution", 1024))
    res = tuple(cfg["resolution"])
    out = {k: [] for k in ("triangles", "median_area", "rate", "csm_seconds", "false_shadows")}
    base = dict(cfg.get("params", {}))
    for size in sizes:
        params = dict(base, size=int(size))
        scene = sl.load_scene("terrain", **params)
        view = default_view("terrain", scene, **params)
        gbuf = sl.render_gbuffer(scene, view.camera.replace(resolution=res))
        refs = References(scene, gbuf, view.light)
        rates, secs, false = [], [], []
        for cov in ("corners", "circle"):
            ev = evaluate(scene, gbuf, view.light, "izb",
                          {"prepass": "csm", "coverage": cov, "resolution": light_res,
                           "front_face_culling": False},   # the poster culls no caster
                          reference=refs, repeats=int(cfg.get("repeats", 1)))
            c = ev.result.counters
            rates.append(c["csm_culled"] / max(c["shadowed"], 1))
            secs.append(ev.timings["csm"])
            false.append(c["csm_false_shadows"])
        out["triangles"].append(scene.num_triangles)
        out["median_area"].append(median_area(scene, gbuf, view.light, light_res))
        out["rate"].append(rates)
        out["csm_seconds"].append(secs)
        out["false_shadows"].append(false)
    arrays = {k: np.asarray(v) for k, v in out.items()}
    arrays["sizes"] = np.asarray(sizes)
    return arrays


def plot(arrays: dict):
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 2, figsize=(10, 3.5), constrained_layout=True)
    a = arrays["median_area"]
    for i, lab in enumerate(("corners", "circle")):
        axes[0].semilogx(a, 100 * arrays["rate"][:, i], "o-", label=lab)
        axes[1].semilogx(a, 1000 * arrays["csm_seconds"][:, i], "o-", label=lab)
    axes[0].axvline(2.0, color="#999999", ls=":")
    axes[0].set_xlabel("median caster area in the light map (texels)")
    axes[0].set_ylabel("CSM-culled / shadowed samples (%)")
    axes[1].set_xlabel("median caster area (texels)")
    axes[1].set_ylabel("CSM stage (ms, warm)")
    axes[0].legend(fontsize=8)
    return fig


def check(arrays: dict, cfg: dict) -> None:
    assert np.all(arrays["false_shadows"] == 0)
    assert np.all(arrays["rate"][:, 0] >= arrays["rate"][:, 1])


def claims(arrays: dict, cfg: dict) -> list[dict]:
    order = np.argsort(arrays["median_area"])
    r = arrays["rate"][order, 0]
    a = arrays["median_area"][order]
    false = int(arrays["false_shadows"].sum())
    culls = bool(np.any(arrays["rate"] > 0))
    return [{"claim": "the CSM is not efficient for triangles smaller than the texel: the "
                      "culling rate falls as the triangles shrink",
             "measured": ", ".join(f"{x:.2g} texels: {100 * y:.1f}%" for x, y in zip(a, r)),
             "holds": bool(r[0] < r[-1])},
            {"id": "t18.conservative",
             "claim": "the conservative shadow map never culls a lit sample",
             "measured": f"{false} lit samples culled, both coverage tests, culling "
                         f"{100 * arrays['rate'].max(initial=0.0):.1f} % of the shadowed "
                         "samples at most",
             **outcome(false == 0, tested=culls, why_untested="the CSM culled no sample")}]


# %%
if __name__ == "__main__":
    from shadowlab.harness.figures import run_as_script

    run_as_script(__file__)
