# ---
# jupyter:
#   jupytext:
#     text_representation:
#       extension: .py
#       format_name: percent
# ---

# %% [markdown]
# # Run time against error: every registered method on one chart
#
# Per scene, every registered hard method (taken from the method registry, so a new
# method appears here without an edit) is evaluated with `harness.evaluate` (one
# warm-up call whose compile time is kept apart, then warm calls; the median is
# plotted): the exact methods at their defaults, error = mismatching valid pixels
# against the Embree shadow-ray mask and, of those, the *unexplained* ones (on no
# shadow boundary); `shadow_map` at each resolution x bias mode. The Embree shadow-ray
# pass is the reference line. On a sphere-light variant of the same scene (the point
# light becomes a sphere of `soft_radius` x the scene diagonal; a sun keeps its disk)
# every soft method, at its defaults and at each of its presets, is compared with the
# Monte Carlo truth (`truth_rays` rays per pixel) by mean absolute error, beside
# Embree's own soft reference at `embree_rays` rays per pixel.
# For each scene the Pareto front of the methods (Embree is the reference, not on it)
# states which configuration is fastest at each error level (arrays `front_*`,
# `soft_front_*`, and the JSON's `summary`).
# `shadowlab figures --only pareto` or `shadowlab bench --pareto` regenerates
# `figures/pareto.*`; `python -m shadowlab.harness.pareto_readme` quotes it in the README.

# %%
from __future__ import annotations

import statistics

import numpy as np

from shadowlab.analysis.pareto import pareto_front
from shadowlab.harness import References, checkpoints, evaluate
from shadowlab.harness.bench import _soft_curve
from shadowlab.harness.figures import ExperimentConfigError, scene_frames
from shadowlab.methods import MethodKind, get, light_problem, names
from shadowlab.scene.view import PointLight, SphereLight

#: arrays that depend on timings (which point is on a front), never compared as goldens
TIMING_ARRAYS = ("front_scene", "front_label", "front_error", "soft_front_scene",
                 "soft_front_label", "soft_front_error", "embree_ratio")
#: error floor drawn for zero error on the log axis
FLOOR = 1e-5


def hard_configs(options: dict) -> list[tuple[str, str, dict]]:
    """(label, method, options) of every registered hard method: ``shadow_map`` at each
    of ``options["sm_resolutions"]`` x ``options["biases"]``, every other one at its
    defaults (its most accurate configuration)."""
    out = []
    for name in names():
        info = get(name)
        if info.kind is MethodKind.SOFT:
            continue
        if name == "shadow_map":
            out += [(f"sm{int(r)}-{b}", name, {"resolution": int(r), "bias": b})
                    for b in options["biases"] for r in options["sm_resolutions"]]
        else:
            out.append((name, name, {}))
    return out


def soft_configs(presets: bool = True) -> list[tuple[str, str, dict]]:
    """(label, method, options) of every registered soft method at its defaults (its
    most accurate configuration) and, with ``presets``, at each of its presets
    (label ``method:preset``)."""
    out = []
    for name in names():
        info = get(name)
        if info.kind is MethodKind.SOFT:
            out.append((name, name, {}))
            if presets:
                out += [(f"{name}:{p}", name, {"preset": p}) for p in sorted(info.presets)]
    return out


def soft_light(scene, light, radius_fraction: float):
    """The area-light variant of ``light``: a sphere of ``radius_fraction`` x the scene
    diagonal at a point light, the light itself if it is already an area light.

    Raises:
        ValueError: a light with no area variant here (a directional light).
    """
    if isinstance(light, SphereLight):
        return light
    if isinstance(light, PointLight):
        return SphereLight(position=light.position, radius=radius_fraction * scene.diagonal)
    raise ValueError(f"pareto: no sphere-light variant of a {type(light).__name__}")


def _front_rows(scene_name, labels, seconds, error):
    idx = pareto_front(seconds, error)
    return [(scene_name, labels[i], float(error[i]), float(seconds[i])) for i in idx]


def _scene_point(cfg, name, res, hard, soft, rays, opts, repeats, precision) -> dict:
    """One scene's values: per hard configuration seconds, mismatches, fraction and
    unexplained [C]; embree_seconds and valid_pixels; per soft configuration
    soft_seconds, soft_mae and soft_penumbra_mae [K] and Embree's soft curve [R] (NaN
    where the scene is not in ``soft_scenes`` or a method refuses the light)."""
    _, scene, view, gbuf, refs = next(scene_frames(cfg, [name], res))
    refs.hard(repeats + 1)
    row = {k: [] for k in ("seconds", "mismatches", "fraction", "unexplained")}
    for _, method, o in hard:
        ev = evaluate(scene, gbuf, view.light, method, dict(o, precision=precision),
                      reference=refs, repeats=repeats)
        e = ev.error
        u = e.get("unexplained")
        row["seconds"].append(ev.seconds)
        row["mismatches"].append(int(e["mismatches"]))
        row["fraction"].append(float(e["mismatch_fraction"]))
        row["unexplained"].append(-1 if u is None or get(method).kind is not MethodKind.EXACT
                                  else int(u))
    row["embree_seconds"] = statistics.median(refs.hard_seconds[1:] or refs.hard_seconds)
    row["valid_pixels"] = int(gbuf.valid.sum())
    if name not in opts.get("soft_scenes", cfg["scenes"]):
        for k in ("soft_seconds", "soft_mae", "soft_penumbra_mae"):
            row[k] = [np.nan] * len(soft)
        row["embree_soft_seconds"] = [np.nan] * len(rays)
        row["embree_soft_mae"] = [np.nan] * len(rays)
        return row
    light = soft_light(scene, view.light, float(opts.get("soft_radius", 0.02)))
    srefs = References(scene, gbuf, light, soft_rays=int(cfg["truth_rays"]), seed=0)
    truth = srefs.soft()
    for k in ("soft_seconds", "soft_mae", "soft_penumbra_mae"):
        row[k] = []
    for _, method, o in soft:
        if light_problem(method, light):
            for k in ("soft_seconds", "soft_mae", "soft_penumbra_mae"):
                row[k].append(np.nan)
            continue
        ev = evaluate(scene, gbuf, light, method, dict(o, precision=precision,
                                                       **opts.get("soft_options", {})),
                      reference=srefs, repeats=repeats)
        row["soft_seconds"].append(ev.seconds)
        row["soft_mae"].append(float(ev.error["mae"]))
        row["soft_penumbra_mae"].append(float(ev.error["penumbra_mae"]))
    curve = _soft_curve(scene, gbuf, light, truth, srefs.shadow_eps, False, rays)
    row["embree_soft_seconds"] = [c["seconds"] for c in curve]
    row["embree_soft_mae"] = [float(c["mae"]) for c in curve]
    return row


def run(cfg: dict) -> dict:
    """Arrays, per scene s [S], hard configuration c [C], soft configuration k [K],
    Embree soft ray count r [R]: seconds, mismatches, fraction (of valid pixels),
    unexplained (-1: an approximate method or too many to examine) [S, C];
    embree_seconds [S]; soft_seconds, soft_mae, soft_penumbra_mae [S, K] (NaN: the
    method refuses that light, or the scene is not in ``options.soft_scenes``);
    embree_soft_seconds, embree_soft_mae [S, R] (NaN likewise); the fronts
    as flat rows front_scene/front_label/front_error/front_seconds (and soft_front_*)."""
    names_ = list(cfg["scenes"])
    res = tuple(cfg["resolution"])
    opts = dict(cfg["options"])
    repeats = int(cfg.get("repeats", 1))
    precision = cfg.get("precision", "float32")
    hard = hard_configs(opts)
    soft = soft_configs(bool(opts.get("soft_presets", True)))
    rays = [int(r) for r in cfg["embree_rays"]]
    unknown = sorted(set(opts.get("soft_scenes", names_)) - set(names_))
    if unknown:
        raise ExperimentConfigError(f"pareto: options.soft_scenes names {unknown}, not in "
                                    f"scenes ({', '.join(names_)})")
    keys = ("seconds", "mismatches", "fraction", "unexplained", "embree_seconds",
            "valid_pixels", "soft_seconds", "soft_mae", "soft_penumbra_mae",
            "embree_soft_seconds", "embree_soft_mae")
    out = {k: [] for k in keys}
    front, soft_front = [], []
    for name in names_:
        # one checkpointed point per scene (a stopped figures run resumes finished scenes)
        row = checkpoints.point(f"scene={name}", lambda: _scene_point(
            cfg, name, res, hard, soft, rays, opts, repeats, precision))
        for k in keys:
            out[k].append(row[k])
        front += _front_rows(name, [h[0] for h in hard], row["seconds"], row["fraction"])
        if name in opts.get("soft_scenes", names_):
            soft_front += _front_rows(name, [s[0] for s in soft], row["soft_seconds"],
                                      row["soft_mae"])
    arrays = {k: np.asarray(v) for k, v in out.items()}
    arrays["scenes"] = np.asarray(names_)
    arrays["labels"] = np.asarray([h[0] for h in hard])
    arrays["kinds"] = np.asarray([get(h[1]).kind.value for h in hard])
    arrays["soft_labels"] = np.asarray([s[0] for s in soft])
    arrays["embree_rays"] = np.asarray(rays)
    arrays["embree_ratio"] = arrays["seconds"] / arrays["embree_seconds"][:, None]
    for prefix, rows in (("front", front), ("soft_front", soft_front)):
        arrays[f"{prefix}_scene"] = np.asarray([r[0] for r in rows])
        arrays[f"{prefix}_label"] = np.asarray([r[1] for r in rows])
        arrays[f"{prefix}_error"] = np.asarray([r[2] for r in rows], np.float64)
        arrays[f"{prefix}_seconds"] = np.asarray([r[3] for r in rows], np.float64)
    return arrays


def _log_time_axis(ax) -> None:
    """Labels at 1, 2 and 5 x 10^k on a log time axis and no minor labels: the axes span
    one or two decades, where matplotlib's minor labels overlap."""
    from matplotlib.ticker import LogFormatterSciNotation, LogLocator, NullFormatter

    ax.xaxis.set_major_locator(LogLocator(subs=(1.0, 2.0, 5.0)))
    ax.xaxis.set_major_formatter(LogFormatterSciNotation(labelOnlyBase=False))
    ax.xaxis.set_minor_formatter(NullFormatter())


def plot(arrays: dict):
    import matplotlib.pyplot as plt

    scenes = list(arrays["scenes"])
    n = len(scenes)
    fig, axes = plt.subplots(2, n, figsize=(5.5 * n, 8), constrained_layout=True,
                             squeeze=False)
    labels, kinds = list(arrays["labels"]), list(arrays["kinds"])
    sm = [i for i, lab in enumerate(labels) if lab.startswith("sm")]
    biases = sorted({labels[i].split("-", 1)[1] for i in sm})
    for s, name in enumerate(scenes):
        ax = axes[0, s]
        for b in biases:
            idx = [i for i in sm if labels[i].endswith(f"-{b}")]
            ax.loglog(1000 * arrays["seconds"][s, idx],
                      np.maximum(arrays["fraction"][s, idx], FLOOR), "o-", ms=4,
                      label=f"shadow_map {b}")
        others = [i for i in range(len(labels)) if i not in sm]
        for j, i in enumerate(others):
            marker = ("*", "P", "X", "^")[j % 4] if kinds[i] == "exact" else "D"
            ax.loglog(1000 * arrays["seconds"][s, i], max(arrays["fraction"][s, i], FLOOR),
                      marker, ms=9, color=plt.cm.tab20((2 * j) % 20 + j // 10 % 2),
                      label=labels[i])
        ax.axvline(1000 * arrays["embree_seconds"][s], color="#777777", ls="--",
                   label="Embree shadow rays")
        f = arrays["front_scene"] == name
        ax.step(1000 * arrays["front_seconds"][f],
                np.maximum(arrays["front_error"][f], FLOOR), where="post", color="k",
                lw=0.7, alpha=0.5, label="Pareto front")
        _log_time_axis(ax)
        ax.set_xlabel("ms (warm median, this CPU)")
        ax.set_ylabel(f"mismatching pixels, fraction (0 drawn at {FLOOR:g})")
        ax.set_title(f"{name}: hard shadows vs Embree", fontsize=9)
        ax.legend(fontsize=6, ncol=2)
        ax = axes[1, s]
        if not np.isfinite(arrays["embree_soft_mae"][s]).all():
            ax.set_title(f"{name}: soft shadows not run at this size", fontsize=9)
            ax.axis("off")
            continue
        ax.loglog(1000 * arrays["embree_soft_seconds"][s], arrays["embree_soft_mae"][s],
                  "o-", color="#777777", label="Embree soft (rays/px)")
        for r, t, v in zip(arrays["embree_rays"], arrays["embree_soft_seconds"][s],
                           arrays["embree_soft_mae"][s]):
            ax.annotate(str(r), (1000 * t, v), fontsize=7, color="#555555")
        for k, lab in enumerate(arrays["soft_labels"]):
            if np.isfinite(arrays["soft_seconds"][s, k]):
                ax.loglog(1000 * arrays["soft_seconds"][s, k], arrays["soft_mae"][s, k], "s",
                          ms=7, label=str(lab))
        _log_time_axis(ax)
        ax.set_xlabel("ms (warm median, this CPU)")
        ax.set_ylabel("mean absolute error vs Monte Carlo truth")
        ax.set_title(f"{name}: soft shadows (sphere-light variant)", fontsize=9)
        ax.legend(fontsize=6)
    return fig


def check(arrays: dict, cfg: dict) -> None:
    """Exact methods have no unexplained mismatch; the fronts are fronts."""
    exact = arrays["kinds"] == "exact"
    assert np.all(arrays["unexplained"][:, exact] == 0), arrays["unexplained"]
    soft_ran = np.isfinite(arrays["embree_soft_mae"]).all(axis=1)
    for prefix in ("front", "soft_front"):
        for s, name in enumerate(arrays["scenes"]):
            f = arrays[f"{prefix}_scene"] == name
            assert f.any() == (prefix == "front" or bool(soft_ran[s]))
            assert np.all(np.diff(arrays[f"{prefix}_seconds"][f]) < 0)
            assert np.all(np.diff(arrays[f"{prefix}_error"][f]) >= 0)
    # more rays, less error
    assert np.all(np.diff(arrays["embree_soft_mae"][soft_ran], axis=1) < 0)


def front_table(arrays: dict, prefix: str = "front") -> dict[str, list[dict]]:
    """{scene: [{"error", "fastest", "seconds", "embree_seconds"}, ...]}: along
    increasing error, the fastest configuration with at most that error; hard rows
    (``front``, error = mismatch fraction) give the Embree shadow-ray pass's seconds,
    soft rows (``soft_front``, error = MAE) the Embree soft reference's seconds at equal
    MAE (interpolated on its curve; None outside it)."""
    from shadowlab.harness.bench import embree_seconds_at_error

    out = {}
    for s, name in enumerate(arrays["scenes"]):
        rows = []
        for i in np.flatnonzero(arrays[f"{prefix}_scene"] == name):
            err = float(arrays[f"{prefix}_error"][i])
            if prefix == "front":
                ref = float(arrays["embree_seconds"][s])
            else:
                curve = [{"seconds": float(t), "mae": float(e)} for t, e in
                         zip(arrays["embree_soft_seconds"][s], arrays["embree_soft_mae"][s])]
                ref = embree_seconds_at_error(curve, err, "mae")
            rows.append({"error": err, "fastest": str(arrays[f"{prefix}_label"][i]),
                         "seconds": float(arrays[f"{prefix}_seconds"][i]),
                         "embree_seconds": ref})
        out[str(name)] = rows
    return out


def summary(arrays: dict, cfg: dict) -> dict:
    """What the JSON records besides the claims: the fronts, and per scene the warm
    seconds, error and ratio to Embree of every hard configuration."""
    per_scene = {}
    for s, name in enumerate(arrays["scenes"]):
        per_scene[str(name)] = {
            "embree_seconds": float(arrays["embree_seconds"][s]),
            "valid_pixels": int(arrays["valid_pixels"][s]),
            "hard": [{"label": str(lab), "kind": str(kind),
                      "seconds": float(arrays["seconds"][s, c]),
                      "ratio_to_embree": float(arrays["embree_ratio"][s, c]),
                      "mismatches": int(arrays["mismatches"][s, c]),
                      "unexplained": int(arrays["unexplained"][s, c])}
                     for c, (lab, kind) in enumerate(zip(arrays["labels"], arrays["kinds"]))],
            "soft": [{"label": str(lab), "seconds": float(arrays["soft_seconds"][s, k]),
                      "mae": float(arrays["soft_mae"][s, k])}
                     for k, lab in enumerate(arrays["soft_labels"])
                     if np.isfinite(arrays["soft_seconds"][s, k])],
            "embree_soft": [{"rays": int(r), "seconds": float(t), "mae": float(e)}
                            for r, t, e in zip(arrays["embree_rays"],
                                               arrays["embree_soft_seconds"][s],
                                               arrays["embree_soft_mae"][s])
                            if np.isfinite(t)],
        }
    return {"scenes": per_scene, "front": front_table(arrays, "front"),
            "soft_front": front_table(arrays, "soft_front")}


def claims(arrays: dict, cfg: dict) -> list[dict]:
    exact = arrays["kinds"] == "exact"
    sm = np.array([str(lab).startswith("sm") for lab in arrays["labels"]])
    out = [{
        "claim": "every exact method has zero unexplained error (its mismatches lie on "
                 "shadow boundaries), while no shadow map is exact on every scene",
        "measured": "; ".join(
            f"{name}: exact mismatches max {int(arrays['mismatches'][s, exact].max())}, "
            f"unexplained max {int(arrays['unexplained'][s, exact].max())}; best shadow map "
            f"{int(arrays['mismatches'][s, sm].min())} mismatches"
            for s, name in enumerate(arrays["scenes"])),
        "holds": bool(np.all(arrays["unexplained"][:, exact] == 0)
                      and np.any(arrays["mismatches"][:, sm].min(axis=1) > 0))}]
    # timing targets (issue: exact methods within 3x of Embree) belong to the bench,
    # not to a claim enforced at CI size: the ratios are in the summary and the README
    return out


# %%
if __name__ == "__main__":
    from shadowlab.harness.figures import run_as_script

    run_as_script(__file__)
