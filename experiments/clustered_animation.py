# ---
# jupyter:
#   jupytext:
#     text_representation:
#       extension: .py
#       format_name: percent
# ---

# %% [markdown]
# # Clustered PTSV over a fly-through (Sintorn et al. 2014, Fig. 6 and Fig. 8)
#
# Per scene, an animated fly-through. Per frame and variant: test-and-set operations
# (Fig. 6) and the warm traversal time (Fig. 8). The paper's Fig. 6 enables front-face
# culling; here face culling is off by default (config `front_face_culling`). The papers'
# side (`cull_side="facing"`) loses shadows where a shadow ray starts inside a closed
# object (the gate's parts touch and interpenetrate: 3 and 7 pixels of 16k in two gate
# frames at 128²); `cull_side="averted"` (the method's default) is exact. Variants:
#
# - `baseline`: implicit bounds, no extra culling planes;
# - `+culling planes`: implicit bounds and the three per-vertex culling planes;
# - `+explicit bounds`: explicit (min / max) node boxes and the culling planes;
# - `+two passes` (Fig. 8 only): the same, traversed in two passes;
# - `ptsv`: the 2011 baseline (2D tile tree with depth ranges, silhouette planes).
#
# Per frame, the share of PTSV's 8 x 4 tiles whose samples' depths differ by more than
# 2x measures its depth discontinuities (grey in the plot); the check compares the
# methods in each scene's frame with the largest share.

# %%
from __future__ import annotations

import statistics
import warnings

import numpy as np

import shadowlab as sl
from shadowlab.scene.procedural import default_view
from shadowlab.scene.view import Animation

VARIANTS = {
    "baseline": ("clustered_ptsv", dict(bounds="implicit", culling_planes=False)),
    "+culling planes": ("clustered_ptsv", dict(bounds="implicit", culling_planes=True)),
    "+explicit bounds": ("clustered_ptsv", dict(bounds="explicit", culling_planes=True)),
    "+two passes": ("clustered_ptsv", dict(bounds="explicit", culling_planes=True, passes=2,
                                           expand_level=3)),
    "ptsv": ("ptsv", dict()),
}
FIG6 = ("baseline", "+culling planes", "+explicit bounds", "ptsv")


def fly_through(name: str, scene, frames: int, resolution) -> list:
    """The frames of a fly-through of ``scene`` (procedural ``name``)."""
    view = default_view(name, scene)
    cam = view.camera.replace(resolution=tuple(resolution))
    eye, target = np.asarray(cam.eye), np.asarray(cam.target)
    if name == "gate":            # walk up to the gate, then look along it at the trees
        eyes = [eye, eye + [0.0, -0.3, -4.0], eye + [-2.5, 0.2, -5.5]]
        targets = [target, target + [0.0, 0.0, 0.0], target + [-12.0, 0.0, 0.0]]
    else:                         # sweep sideways and down towards the ground
        d = target - eye
        side = np.cross(d, [0.0, 1.0, 0.0])
        side *= 0.35 * np.linalg.norm(d) / np.linalg.norm(side)
        eyes = [eye - side, eye + 0.3 * d, eye + side + 0.15 * d]
        targets = [target, target, target]
    anim = Animation(cam, view.light, frames=frames, eye_keys=eyes, target_keys=targets)
    return anim.views()


def _discontinuity_share(gbuf) -> float:
    """Share of 8 x 4 tiles with valid samples whose max / min depth exceeds 2."""
    h, w = gbuf.shape
    d = np.where(gbuf.valid, gbuf.depth, np.nan)
    d = d[: h // 4 * 4, : w // 8 * 8].reshape(h // 4, 4, w // 8, 8)
    with warnings.catch_warnings():                     # all-empty tiles give NaN
        warnings.simplefilter("ignore", RuntimeWarning)
        hi = np.nanmax(d, axis=(1, 3))
        lo = np.nanmin(d, axis=(1, 3))
    ok = np.isfinite(hi)
    return float(np.mean(hi[ok] / lo[ok] > 2)) if ok.any() else 0.0


def run(cfg: dict) -> dict:
    """Per scene s, variant v, frame f: tests [S, V, F], traverse seconds [S, V, F],
    node tests and mismatches [S, V, F], discontinuity share [S, F]."""
    names = list(cfg["scenes"])
    frames = int(cfg["frames"])
    repeats = int(cfg.get("repeats", 1))
    prec = cfg.get("precision", "float32")
    variants = list(VARIANTS)
    shape = (len(names), len(variants), frames)
    out = {k: np.zeros(shape, np.int64) for k in ("tests", "node_tests", "mismatches")}
    out["traverse_seconds"] = np.zeros(shape)
    out["discontinuity"] = np.zeros((len(names), frames))
    out["valid_pixels"] = np.zeros((len(names), frames), np.int64)
    out["triangles"] = np.zeros(len(names), np.int64)
    for i, name in enumerate(names):
        params = dict(cfg.get("params", {}).get(name, {}))
        scene = sl.load_scene(name, **params)
        out["triangles"][i] = scene.num_triangles
        for f, view in enumerate(fly_through(name, scene, frames, cfg["resolution"])):
            gbuf = sl.render_gbuffer(scene, view.camera)
            truth = sl.reference_shadows(scene, gbuf, view.light)
            out["discontinuity"][i, f] = _discontinuity_share(gbuf)
            out["valid_pixels"][i, f] = gbuf.valid.sum()
            for v, key in enumerate(variants):
                method, opts = VARIANTS[key]
                opts = dict(opts, front_face_culling=bool(cfg.get("front_face_culling", False)),
                            precision=prec)
                runs = [sl.compute_shadows(scene, gbuf, view.light, method=method, **opts)
                        for _ in range(repeats + 1)]           # the first one compiles
                r = runs[-1]
                out["tests"][i, v, f] = r.counters["tests"]
                out["node_tests"][i, v, f] = r.counters["node_tests"]
                out["mismatches"][i, v, f] = int(np.count_nonzero((r.lit != truth) & gbuf.valid))
                out["traverse_seconds"][i, v, f] = statistics.median(
                    x.timings["traverse"] for x in runs[1:])
    out["scenes"] = np.asarray(names)
    out["variants"] = np.asarray(variants)
    out["frames"] = np.arange(frames)
    return out


def plot(arrays: dict):
    import matplotlib.pyplot as plt

    names = arrays["scenes"]
    variants = list(arrays["variants"])
    fig, axes = plt.subplots(2, len(names), figsize=(6 * len(names), 7),
                             constrained_layout=True, squeeze=False)
    for i, name in enumerate(names):
        ax = axes[0, i]
        for key in FIG6:
            v = variants.index(key)
            ax.plot(arrays["frames"], arrays["tests"][i, v] / 1e3, label=key,
                    ls="--" if key == "ptsv" else "-")
        ax.set_title(f"{name} ({arrays['triangles'][i]} tris): test-and-set (Fig. 6)",
                     fontsize=9)
        ax.set_xlabel("frame")
        ax.set_ylabel("thousand test-and-sets")
        ax.legend(fontsize=8)
        ax2 = ax.twinx()
        ax2.fill_between(arrays["frames"], arrays["discontinuity"][i], color="0.85")
        ax.set_zorder(ax2.get_zorder() + 1)           # lines above the grey area
        ax.patch.set_visible(False)
        ax2.set_ylim(0, 1)
        ax2.set_ylabel("share of 8x4 tiles with depth ratio > 2", color="0.5", fontsize=8)
        ax = axes[1, i]
        for key in variants:
            if key == "ptsv":
                continue
            v = variants.index(key)
            ax.plot(arrays["frames"], 1000 * arrays["traverse_seconds"][i, v], label=key)
        ax.set_title(f"{name}: traversal time per option set (Fig. 8)", fontsize=9)
        ax.set_xlabel("frame")
        ax.set_ylabel("ms (warm, median)")
        ax.legend(fontsize=8)
    return fig


def check(arrays: dict, cfg: dict) -> None:
    """Exact everywhere (up to the documented boundary tolerance); culling planes never
    add node tests or test-and-sets; two passes do the same work as one."""
    tol = float(cfg.get("max_mismatch_fraction", 0.0005))
    assert np.all(arrays["mismatches"] <= tol * arrays["valid_pixels"][:, None]), \
        arrays["mismatches"]
    variants = list(arrays["variants"])
    base, cull = variants.index("baseline"), variants.index("+culling planes")
    ex, two = variants.index("+explicit bounds"), variants.index("+two passes")
    tests = arrays["tests"]
    assert np.all(tests[:, cull] <= tests[:, base])
    assert np.all(arrays["node_tests"][:, cull] <= arrays["node_tests"][:, base])
    assert np.array_equal(tests[:, two], tests[:, ex])        # same work, other jobs


def claims(arrays: dict, cfg: dict) -> list[dict]:
    """Sintorn 2014, Fig. 6: explicit bounds need no more test-and-sets than PTSV in
    nearly every frame (share of frames >= `min_share_le_ptsv`, per scene), and at
    least `min_gain_at_discontinuities` x fewer in the frame with the most depth
    discontinuities (scenes in `gain_scenes`)."""
    variants = list(arrays["variants"])
    ex, pt = variants.index("+explicit bounds"), variants.index("ptsv")
    tests = arrays["tests"]
    need_share = float(cfg.get("min_share_le_ptsv", 0.9))
    need_gain = float(cfg.get("min_gain_at_discontinuities", 2.0))
    out = []
    for i, name in enumerate(arrays["scenes"]):
        le = tests[i, ex] <= tests[i, pt]
        ratio = tests[i, ex] / np.maximum(tests[i, pt], 1)
        out.append({"claim": f"{name}: explicit bounds <= PTSV test-and-sets in >= "
                             f"{need_share:.0%} of frames",
                    "measured": f"{int(le.sum())} of {le.size} frames; explicit / PTSV "
                                f"{ratio.min():.2f}-{ratio.max():.2f}",
                    "holds": bool(le.mean() >= need_share)})
    for name in cfg.get("gain_scenes", []):
        i = list(arrays["scenes"]).index(name)
        f = int(np.argmax(arrays["discontinuity"][i]))
        gain = tests[i, pt, f] / max(tests[i, ex, f], 1)
        out.append({"claim": f"{name}: >= {need_gain:g}x fewer test-and-sets than PTSV "
                             "in the frame with the most depth discontinuities",
                    "measured": f"frame {f}: {gain:.2f}x",
                    "holds": bool(gain >= need_gain)})
    return out


# %%
if __name__ == "__main__":
    from shadowlab.harness.figures import run_as_script

    run_as_script(__file__)
