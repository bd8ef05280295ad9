# ---
# jupyter:
#   jupytext:
#     text_representation:
#       extension: .py
#       format_name: percent
# ---

# %% [markdown]
# # PSV queries over an animation (Mora et al. 2016, Fig. 7 and Fig. 8)
#
# A camera and light fly-through of one scene: the light starts at the scene's default
# position, swings to just behind and above the camera (the pathological case for PSV:
# every visible point is lit and in front of every caster), and back out. Per frame and
# query: mean visited nodes per sample and warm build+query time (Fig. 7; one warm-up
# call per frame and query, then the median of `repeats` calls). Over the animation: the
# averages table (Fig. 8) with % of PSV's visited nodes, the standard deviation σ of the
# per-frame times and the worst / average / best time acceleration factor over PSV. On the frame with the light nearest the camera, a per-pixel analysis: visited
# nodes of lit and shadowed samples against their distance to the light, with and
# without the depth test. Z-PASS is timed on every frame beside them (Fig. 7's duality:
# fast where PSV is pathological). Every frame of every query is checked against Embree.

# %%
from __future__ import annotations

import numpy as np

import shadowlab as sl
from shadowlab.harness.claims import measured
from shadowlab.reference.boundary import unexplained_count
from shadowlab.scene.procedural import default_view
from shadowlab.scene.view import Animation, PointLight
from shadowlab.methods.psv import UNCULLED_TREE

METHODS = ("psv", "d_psv", "d_stackless", "d_hybrid")
PAPER_RANGE = {"d_psv": (62, 72), "d_hybrid": (62, 72), "d_stackless": (84, 114)}


def animation(name: str, scene, params: dict, frames: int, res) -> list:
    """Fly-through: camera dollies in and sideways; the light passes behind the camera."""
    view = default_view(name, scene, **params)
    cam = view.camera.replace(resolution=tuple(res))
    eye, target = np.asarray(cam.eye), np.asarray(cam.target)
    back = eye - target
    side = np.cross(back, [0.0, 1.0, 0.0])
    side = side / max(np.linalg.norm(side), 1e-12) * 0.25 * np.linalg.norm(back)
    light0 = np.asarray(view.light.position)
    behind = eye + 0.15 * back + np.array([0.0, 0.05, 0.0]) * np.linalg.norm(back)
    anim = Animation(camera=cam, light=PointLight(light0), frames=frames,
                     eye_keys=[eye, eye - 0.2 * back + side, eye - 0.1 * back - side, eye],
                     target_keys=[target, target, target, target],
                     light_keys=[light0, behind, behind + side, light0])
    return anim.views()


def run(cfg: dict) -> dict:
    name = cfg["scene"]
    params = dict(cfg.get("params", {}))
    prec = cfg.get("precision", "float32")
    repeats = int(cfg.get("repeats", 1))
    bins = int(cfg.get("distance_bins", 6))
    scene = sl.load_scene(name, **params)
    views = animation(name, scene, params, int(cfg["frames"]), cfg["resolution"])
    nf, nm = len(views), len(METHODS)
    visited = np.zeros((nf, nm))
    seconds = np.zeros((nf, nm))
    mism = np.zeros((nf, nm), int)
    unex = np.zeros((nf, nm), int)
    overflow = np.zeros((nf, nm), int)
    switches = np.zeros(nf, int)
    hybrid_differs = np.zeros(nf, int)        # pixels without a switch where D-Hybrid != D-PSV
    ref_seconds = np.zeros(nf)
    zpass_seconds = np.zeros(nf)              # Z-PASS (Fig. 7, 8), warm median
    zpass_unexplained = np.zeros(nf, int)
    light_cam = np.zeros(nf)                  # light-to-camera distance / scene diagonal
    lit_fraction = np.zeros(nf)
    maps = {}
    import time
    for f, view in enumerate(views):
        gbuf = sl.render_gbuffer(scene, view.camera)
        t0 = time.perf_counter()
        truth = sl.reference_shadows(scene, gbuf, view.light)
        ref_seconds[f] = time.perf_counter() - t0
        light_cam[f] = np.linalg.norm(np.asarray(view.light.position)
                                      - np.asarray(view.camera.eye)) / scene.diagonal
        lit_fraction[f] = truth[gbuf.valid].mean() if gbuf.valid.any() else 0.0
        sl.compute_shadows(scene, gbuf, view.light, method="zpass", precision=prec)  # warm-up
        zr = [sl.compute_shadows(scene, gbuf, view.light, method="zpass", precision=prec)
              for _ in range(repeats)]
        zpass_seconds[f] = np.median([x.timings["total"] for x in zr])
        zpass_unexplained[f] = unexplained_count(scene, gbuf, view.light, zr[-1].lit, truth)
        for j, m in enumerate(METHODS):
            sl.compute_shadows(scene, gbuf, view.light, method=m, precision=prec,
                               **UNCULLED_TREE)  # warm-up
            runs = [sl.compute_shadows(scene, gbuf, view.light, method=m, precision=prec,
                                       **UNCULLED_TREE)
                    for _ in range(repeats)]
            r = runs[-1]
            maps[(f, m, "lit")] = r.lit
            ov = r.counters.get("stack_overflows_per_pixel")
            ok = gbuf.valid if ov is None else gbuf.valid & (ov == 0)
            mism[f, j] = np.count_nonzero((r.lit != truth) & ok)
            unex[f, j] = unexplained_count(scene, gbuf, view.light, r.lit, truth, ok)
            overflow[f, j] = r.counters.get("overflow_pixels", 0)
            visited[f, j] = r.counters["visited_nodes_mean"]
            seconds[f, j] = np.median([x.timings["total"] for x in runs])
            if m == "d_hybrid":
                switches[f] = r.counters["stackless_switches"]
                calm = gbuf.valid & (r.counters["stackless_switches_per_pixel"] == 0)
                hybrid_differs[f] = np.count_nonzero(calm & (
                    (r.counters["visited_nodes_per_pixel"] != maps[(f, "d_psv")])
                    | (r.lit != maps[(f, "d_psv", "lit")])))
            maps[(f, m)] = r.counters["visited_nodes_per_pixel"]
        maps[(f, "lit")] = truth
        maps[(f, "valid")] = gbuf.valid
        maps[(f, "dist")] = np.where(gbuf.valid, np.linalg.norm(
            gbuf.position - np.asarray(view.light.position), axis=-1), np.nan)
    # Per-pixel analysis on the frame with the light nearest the camera.
    fp = int(np.argmin(light_cam))
    valid, lit, dist = maps[(fp, "valid")], maps[(fp, "lit")], maps[(fp, "dist")]
    edges = np.nanquantile(dist[valid], np.linspace(0, 1, bins + 1))
    which = np.clip(np.searchsorted(edges, dist, side="right") - 1, 0, bins - 1)
    per_bin = np.full((nm, 2, bins), np.nan)          # [method, (shadow, lit), bin]
    for j, m in enumerate(METHODS):
        vm = maps[(fp, m)]
        for c, sel in enumerate((valid & ~lit, valid & lit)):
            for k in range(bins):
                cell = sel & (which == k)
                if cell.any():
                    per_bin[j, c, k] = vm[cell].mean()
    pct = 100 * visited / visited[:, :1]
    accel = seconds[:, :1] / seconds
    return {
        "scene": np.asarray(name), "methods": np.asarray(METHODS),
        "visited": visited, "seconds": seconds, "reference_seconds": ref_seconds,
        "zpass_seconds": zpass_seconds, "zpass_unexplained": zpass_unexplained,
        "mismatches": mism, "unexplained": unex, "overflow_pixels": overflow, "switches": switches,
        "hybrid_differs": hybrid_differs, "seconds_mean": seconds.mean(0),
        "seconds_std": seconds.std(0), "repeats": np.asarray(repeats),
        "light_camera_distance": light_cam, "lit_fraction": lit_fraction,
        "percent_of_psv": pct, "mean_percent_of_psv": 100 * visited.mean(0) / visited[:, 0].mean(),
        "visited_std": visited.std(0), "accel_worst": accel.min(0), "accel_mean": accel.mean(0),
        "accel_best": accel.max(0), "pixel_frame": np.asarray(fp), "distance_edges": edges,
        "per_bin_visited": per_bin,
        "pixel_maps": np.stack([maps[(fp, m)] for m in METHODS]),
        "pixel_lit": lit, "pixel_valid": valid, "pixel_distance": dist,
        "in_paper_range": np.asarray([
            PAPER_RANGE[m][0] <= 100 * visited[:, j].mean() / visited[:, 0].mean()
            <= PAPER_RANGE[m][1] if m in PAPER_RANGE else True for j, m in enumerate(METHODS)]),
    }


def plot(arrays: dict):
    import matplotlib.pyplot as plt

    ms = [str(m) for m in arrays["methods"]]
    fig, ax = plt.subplots(2, 3, figsize=(17, 9), constrained_layout=True)
    frames = np.arange(len(arrays["visited"]))
    for j, m in enumerate(ms):
        ax[0, 0].plot(frames, arrays["visited"][:, j], "o-", label=m, ms=3)
        ax[0, 1].plot(frames, 1000 * arrays["seconds"][:, j], "o-", label=m, ms=3)
    ax[0, 1].plot(frames, 1000 * arrays["reference_seconds"], "k--", label="Embree")
    ax[0, 1].plot(frames, 1000 * arrays["zpass_seconds"], "k:", label="zpass")
    ax[0, 0].set(xlabel="frame", ylabel="visited nodes / sample",
                 title=f"{arrays['scene']}: visited nodes per frame (Fig. 7)")
    ax[0, 1].set(xlabel="frame", ylabel="ms (build + query, warm)", title="time per frame")
    a2 = ax[0, 0].twinx()
    a2.plot(frames, arrays["light_camera_distance"], ":", color="gray")
    a2.set_ylabel("light-camera distance / diagonal", color="gray")
    for a in ax[0, :2]:
        a.legend(fontsize=8)
    ax[0, 2].axis("off")
    rows = [[m, f"{arrays['visited'][:, j].mean():.1f}", f"{arrays['mean_percent_of_psv'][j]:.0f}%",
             f"{1e3 * arrays['seconds_mean'][j]:.1f} ({1e3 * arrays['seconds_std'][j]:.1f})",
             f"{arrays['accel_worst'][j]:.2f}",
             f"{arrays['accel_mean'][j]:.2f}", f"{arrays['accel_best'][j]:.2f}"]
            for j, m in enumerate(ms)]
    t = ax[0, 2].table(cellText=rows, colLabels=["query", "nodes", "% PSV", "ms (σ)", "worst",
                                                 "avg", "best"], loc="center")
    t.scale(1, 1.6)
    ax[0, 2].set_title("averages over the animation (Fig. 8); acceleration = PSV time / time")
    mid = 0.5 * (arrays["distance_edges"][1:] + arrays["distance_edges"][:-1])
    for j, m in enumerate(ms):
        for c, (lab, st) in enumerate((("shadow", "--"), ("lit", "-"))):
            ax[1, 0].plot(mid, arrays["per_bin_visited"][j, c], st, color=f"C{j}",
                          label=f"{m} {lab}")
    ax[1, 0].set(xlabel="distance to the light", ylabel="mean visited nodes",
                 title=f"frame {int(arrays['pixel_frame'])}: per-pixel cost vs distance")
    ax[1, 0].legend(fontsize=7)
    valid = arrays["pixel_valid"]
    vmax = np.percentile(arrays["pixel_maps"][:, valid], 99.5) if valid.any() else 1
    for k, j in enumerate((0, 1)):
        im = ax[1, 1 + k].imshow(np.where(valid, arrays["pixel_maps"][j], np.nan),
                                 cmap="inferno", vmin=0, vmax=vmax)
        ax[1, 1 + k].set_title(f"{ms[j]} visited nodes, light behind the camera")
        ax[1, 1 + k].set_xticks([])
        ax[1, 1 + k].set_yticks([])
    fig.colorbar(im, ax=ax[1, 2], shrink=0.8)
    return fig


def check(arrays: dict, cfg: dict) -> None:
    """Exact on every frame (no unexplained mismatch); the depth test never adds visits
    and pays most for lit samples near the light; D-Hybrid equals D-PSV per pixel (visits
    and result) wherever it did not switch; no overflow with PSV's and D-PSV's stack of
    32, and none ever with D-Hybrid."""
    assert np.all(arrays["unexplained"] == 0), (arrays["mismatches"], arrays["unexplained"])
    assert np.all(arrays["zpass_unexplained"] == 0), arrays["zpass_unexplained"]
    v = arrays["visited"]
    assert np.all(v[:, 1] <= v[:, 0] + 1e-9), "D-PSV visited more than PSV"
    assert np.all(arrays["hybrid_differs"] == 0), arrays["hybrid_differs"]
    assert np.all(arrays["overflow_pixels"] == 0), arrays["overflow_pixels"]
    # The fly-through must contain the pathological frame: light near the camera, most
    # visible samples lit.
    fp = int(arrays["pixel_frame"])
    assert arrays["light_camera_distance"][fp] < 0.5 * arrays["light_camera_distance"][0]
    # Without the depth test lit samples near the light are the expensive ones: in the
    # nearest distance bin PSV visits more nodes for lit than for shadowed samples, and
    # the depth test removes a larger share of that cost near the light than far away.
    pb = arrays["per_bin_visited"]
    near, far = 0, pb.shape[-1] - 1
    assert pb[0, 1, near] > pb[0, 0, near] or np.isnan(pb[0, 0, near]), pb[0, :, near]
    assert pb[1, 1, near] / pb[0, 1, near] < pb[1, 1, far] / pb[0, 1, far], pb[:2, 1]


def claims(arrays: dict, cfg: dict) -> list[dict]:
    """Mora et al. 2016, Fig. 7 and 8 over the fly-through."""
    ms = list(arrays["methods"])
    v, pct = arrays["visited"], arrays["mean_percent_of_psv"]
    ps, dp, st, hy = (ms.index(m) for m in METHODS)
    out = []
    fewer = (v[:, dp] < v[:, ps]) & (v[:, hy] < v[:, ps])
    out.append(measured("m16.fig7.always_fewer",
                        f"D-PSV and D-Hybrid below PSV in {int(fewer.sum())} of {len(fewer)} "
                        "frames", fewer.all()))
    peak = int(np.argmax(v[:, ps]))
    fp = int(arrays["pixel_frame"])
    cut_peak = 1 - v[peak, dp] / v[peak, ps]
    cut_mean = 1 - v[:, dp].mean() / v[:, ps].mean()
    out.append(measured("m16.fig7.light_behind_peak",
                        f"PSV peaks in frame {peak} (light nearest the camera: frame {fp}); "
                        f"the depth test removes {100 * cut_peak:.0f} % there, "
                        f"{100 * cut_mean:.0f} % on average", peak == fp and cut_peak > cut_mean))
    lo, hi = PAPER_RANGE["d_psv"]
    out.append(measured("m16.fig8.dpsv_pct",
                        f"D-PSV {pct[dp]:.0f} %, D-Hybrid {pct[hy]:.0f} % (paper {lo}-{hi} %)",
                        lo <= pct[dp] <= hi and lo <= pct[hy] <= hi))
    lo, hi = PAPER_RANGE["d_stackless"]
    out.append(measured("m16.fig8.dstackless_pct", f"D-Stackless {pct[st]:.0f} % (paper "
                        f"{lo}-{hi} %)", lo <= pct[st] <= hi))
    mean, std = arrays["seconds_mean"], arrays["seconds_std"]
    out.append(measured("m16.fig8.hybrid_fastest",
                        "mean ms (σ): " + ", ".join(f"{m} {1e3 * mean[j]:.1f} ({1e3 * std[j]:.1f})"
                                                    for j, m in enumerate(ms)),
                        int(np.argmin(mean)) == hy and int(np.argmin(std)) == hy))
    acc = arrays["accel_mean"]
    out.append(measured("m16.fig8.accel",
                        "mean acceleration over PSV " + ", ".join(
                            f"{ms[j]} {acc[j]:.2f}" for j in (dp, st, hy))
                        + f"; D-Hybrid best {arrays['accel_best'][hy]:.2f}",
                        all(acc[j] > 1 for j in (dp, st, hy))))
    ratio = arrays["zpass_seconds"] / arrays["seconds"][:, ps]
    others = np.delete(ratio, fp)
    out.append(measured("m16.fig7.zpass_duality",
                        f"Z-PASS / PSV time {ratio[fp]:.2f} with the light behind the camera "
                        f"(frame {fp}), median {np.median(others):.2f} over the other frames",
                        ratio[fp] < np.median(others)))
    ov = arrays["overflow_pixels"]
    out.append(measured("m16.sec3_5.no_overflow",
                        f"overflowing pixels over all frames: PSV {ov[:, ps].sum()}, D-PSV "
                        f"{ov[:, dp].sum()} (stack 32), D-Hybrid {ov[:, hy].sum()}",
                        ov.sum() == 0))
    return out


# %%
if __name__ == "__main__":
    from shadowlab.harness.figures import run_as_script

    run_as_script(__file__)
