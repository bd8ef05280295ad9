# ---
# jupyter:
#   jupytext:
#     text_representation:
#       extension: .py
#       format_name: percent
# ---

# %% [markdown]
# # Large-world stability: mismatches against the offset from the world origin
#
# The `city` scene (closed boxes on a closed slab, thin posts; with the CI config also
# needles, slivers, coincident duplicates with opposite windings and T-junctions) is
# moved to `(d, 0, d)` for each offset `d`, with its default view. For every exact
# method, in float32 and float64, and for the Embree reference, we count the valid
# pixels that disagree with an independent float64 truth (`reference.truth64`: plain
# NumPy, eye-relative primary rays, light-relative shadow segments, the documented lit
# criterion), and how many of those `reference.boundary` cannot explain (not within
# float32 spacing of a caster's edge in frame-local coordinates, nor at the `eps`
# cut). We also measure the G-buffer against the float64 primary rays: the largest
# position error and the pixels whose hit triangle differs.
# For comparison, `world_coordinates = true` repeats the float32 runs and the G-buffer
# with every frame origin at the world origin (`core.frame.world_coordinates`: float32
# work in world coordinates, as before the frame-local origin existed).
# `shadowlab figures --only stability` regenerates `figures/stability.*`.

# %%
from __future__ import annotations

import numpy as np

import shadowlab as sl
from shadowlab.core.frame import world_coordinates
from shadowlab.methods import registry
from shadowlab.reference import truth64
from shadowlab.reference.boundary import unexplained_count
from shadowlab.reference.raycast import shadow_epsilon
from shadowlab.scene import procedural

PRECISIONS = ("float32", "float64")
#: Not in the golden file: which of two coincident triangles Embree reports depends on
#: the CPU's vector width (19 against 36 ties at offset 0, CI size, on two machines);
#: ``gbuffer_hit_differs`` (another hit point) is compared.
CPU_DEPENDENT_ARRAYS = ("gbuffer_triangle_ties",)


def _methods(cfg: dict) -> list[str]:
    names = cfg.get("methods") or [n for n in registry.names() if registry.get(n).exact]
    for n in names:
        if not registry.get(n).exact:                 # MethodError for unknown names
            raise ValueError(f"stability: method {n!r} is not an exact hard-shadow method")
    return list(names)


def run(cfg: dict) -> dict:
    """Arrays: ``mismatches`` and ``unexplained`` int [P, M, K] (precision, method,
    offset), ``reference_mismatches`` / ``reference_unexplained`` [K], ``valid_pixels``
    [K], ``gbuffer_position_error`` float [K] (world units, largest over pixels whose
    hit triangle agrees), ``gbuffer_triangle_ties`` [K] (another triangle hit at the same
    point: coincident duplicates, shared edges), ``gbuffer_hit_differs`` [K] (another
    hit point), ``eps`` [K] (world units);
    with ``world_coordinates``: ``world_mismatches`` [M, K] (float32) and
    ``world_reference_mismatches`` [K]."""
    name = cfg.get("scene", "city")
    offsets = [float(d) for d in cfg["offsets"]]
    methods = _methods(cfg)
    res = tuple(cfg["resolution"])
    k = len(offsets)
    mism = np.zeros((len(PRECISIONS), len(methods), k), np.int64)
    unexp = np.zeros_like(mism)
    out = {key: np.zeros(k, np.int64) for key in ("reference_mismatches", "reference_unexplained",
                                                  "valid_pixels", "gbuffer_triangle_ties",
                                                  "gbuffer_hit_differs")}
    pos_err = np.zeros(k)
    eps = np.zeros(k)
    world = bool(cfg.get("world_coordinates", False))
    w_mism = np.zeros((len(methods), k), np.int64)
    w_ref = np.zeros(k, np.int64)
    for j, d in enumerate(offsets):
        params = dict(cfg.get("params", {}), offset=[d, 0.0, d])
        scene = procedural.make(name, **params)
        view = procedural.default_view(name, scene, **params)
        cam = view.camera.replace(resolution=res)
        gbuf = sl.render_gbuffer(scene, cam)
        prim = truth64.primary_hits(scene, cam)
        same = gbuf.valid & prim["valid"] & (gbuf.triangle == prim["triangle"])
        other = gbuf.valid & prim["valid"] & ~same
        eps[j] = shadow_epsilon(scene)
        # another triangle at the same point (within 1e-3 eps): a tie between coincident
        # duplicates or at a shared edge, which Embree breaks differently on CPUs with
        # other vector widths; anything else is a real disagreement
        delta = gbuf.position - prim["position"]
        tie = other & (np.linalg.norm(delta, axis=-1) <= 1e-3 * eps[j])
        out["gbuffer_triangle_ties"][j] = np.count_nonzero(tie)
        out["gbuffer_hit_differs"][j] = np.count_nonzero(other & ~tie)
        pos_err[j] = np.abs(delta)[same].max(initial=0.0)
        truth = truth64.gbuffer_shadows(scene, gbuf, view.light)
        out["valid_pixels"][j] = gbuf.valid.sum()
        ref = sl.reference_shadows(scene, gbuf, view.light)
        out["reference_mismatches"][j] = np.count_nonzero((ref != truth) & gbuf.valid)
        out["reference_unexplained"][j] = unexplained_count(scene, gbuf, view.light, ref, truth)
        for p, prec in enumerate(PRECISIONS):
            for m, meth in enumerate(methods):
                lit = sl.compute_shadows(scene, gbuf, view.light, method=meth,
                                         precision=prec).lit
                mism[p, m, j] = np.count_nonzero((np.asarray(lit) != truth) & gbuf.valid)
                unexp[p, m, j] = unexplained_count(scene, gbuf, view.light, lit, truth)
        if world:
            with world_coordinates():
                wbuf = sl.render_gbuffer(scene, cam)
                wtruth = truth64.gbuffer_shadows(scene, wbuf, view.light)
                ref = sl.reference_shadows(scene, wbuf, view.light)
                w_ref[j] = np.count_nonzero((ref != wtruth) & wbuf.valid)
                for m, meth in enumerate(methods):
                    lit = sl.compute_shadows(scene, wbuf, view.light, method=meth).lit
                    w_mism[m, j] = np.count_nonzero((np.asarray(lit) != wtruth) & wbuf.valid)
    arrays = {key: v for key, v in out.items()}
    if world:
        arrays.update(world_mismatches=w_mism, world_reference_mismatches=w_ref)
    arrays.update(mismatches=mism, unexplained=unexp, offsets=np.asarray(offsets),
                  methods=np.asarray(methods), precisions=np.asarray(PRECISIONS),
                  gbuffer_position_error=pos_err, eps=eps)
    return arrays


def plot(arrays: dict):
    import matplotlib.pyplot as plt

    offsets = arrays["offsets"]
    x = np.arange(len(offsets))
    labels = ["0" if d == 0 else f"1e{np.log10(d):.0f}" if np.log10(d).is_integer()
              else f"{d:g}" for d in offsets]
    world = "world_mismatches" in arrays
    panels = [(f"{prec}, frame-local: mismatching valid px + 1", arrays["mismatches"][p],
               arrays["reference_mismatches"]) for p, prec in enumerate(arrays["precisions"])]
    if world:
        panels.append(("float32, world coordinates (before): mismatching valid px + 1",
                       arrays["world_mismatches"], arrays["world_reference_mismatches"]))
    fig, axes = plt.subplots(1, len(panels) + 1, figsize=(4.7 * (len(panels) + 1), 4.2),
                             constrained_layout=True)
    top = max(int(np.max(v)) for _, v, r in panels) + max(int(np.max(r)) for _, v, r in panels)
    for ax, (title, values, ref) in zip(axes, panels):
        for m, meth in enumerate(arrays["methods"]):
            ax.plot(x, values[m] + 1, marker="o", ms=3, label=str(meth), alpha=0.8)
        ax.plot(x, ref + 1, "k--", marker="s", ms=3, label="reference (Embree)")
        ax.set_yscale("log")
        ax.set_ylim(0.7, 2 * (top + 1))
        ax.set_title(title, fontsize=9)
        ax.set_xticks(x, labels)
        ax.set_xlabel("offset from the world origin (world units)")
    axes[0].legend(fontsize=7, ncol=2)
    ax = axes[-1]
    ax.semilogy(x, np.maximum(arrays["gbuffer_position_error"], 1e-17), "o-",
                label="G-buffer position error")
    ax.semilogy(x, arrays["eps"], "k--", label="receiver offset eps")
    ax.set_xticks(x, labels)
    ax.set_xlabel("offset from the world origin (world units)")
    ties = ", ".join(str(int(v)) for v in arrays["gbuffer_triangle_ties"])
    differs = ", ".join(str(int(v)) for v in arrays["gbuffer_hit_differs"])
    ax.set_title(f"G-buffer vs float64 rays ({int(arrays['valid_pixels'][0])} valid px)\n"
                 f"other hit point: {differs}; same point, other triangle: {ties}",
                 fontsize=8)
    ax.legend(fontsize=7)
    return fig


def _within(arrays: dict, cfg: dict) -> np.ndarray:
    return arrays["offsets"] <= float(cfg.get("max_exact_offset", 1e5))


def check(arrays: dict, cfg: dict) -> None:
    """Up to ``max_exact_offset``: no unexplained mismatch for any method, precision
    or the reference, and no G-buffer hit point other than the float64 ray's (ties
    between coincident triangles aside); G-buffer positions far below the bias
    everywhere."""
    near = _within(arrays, cfg)
    assert np.all(arrays["unexplained"][..., near] == 0), arrays["unexplained"]
    assert np.all(arrays["reference_unexplained"][near] == 0), arrays["reference_unexplained"]
    assert np.all(arrays["unexplained"] <= arrays["mismatches"])
    assert np.all(arrays["gbuffer_position_error"] < 1e-3 * arrays["eps"])
    assert np.all(arrays["gbuffer_hit_differs"][near] == 0), arrays["gbuffer_hit_differs"]
    assert np.all(arrays["valid_pixels"] > 0)


def claims(arrays: dict, cfg: dict) -> list[dict]:
    near = _within(arrays, cfg)
    top = float(arrays["offsets"][near].max())
    worst = int(arrays["unexplained"][..., near].max(initial=0))
    ref = int(arrays["reference_unexplained"][near].max(initial=0))
    total = int(arrays["mismatches"][..., near].sum())
    return [{"claim": f"every exact method and the reference are exact up to offset {top:g}, "
                      "except boundary-explained pixels",
             "measured": f"{total} mismatches over all methods, precisions and offsets "
                         f"<= {top:g}; unexplained: methods {worst}, reference {ref}",
             "holds": worst == 0 and ref == 0}]


# %%
if __name__ == "__main__":
    from shadowlab.harness.figures import run_as_script

    run_as_script(__file__)
