"""Figures drawn from arrays (never from anything the arrays do not hold)."""

from __future__ import annotations

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
from matplotlib.colors import ListedColormap  # noqa: E402

ERROR_COLORS = ListedColormap(["#2b6cb0", "#f2f2f2", "#d64545"])  # -1, 0, +1


def shade(lit: np.ndarray, valid: np.ndarray) -> np.ndarray:
    """A grey image [H, W]: lit 1.0, shadowed 0.35, invalid (sky) 0.0."""
    img = np.where(valid, np.where(lit, 1.0, 0.35), 0.0)
    return img


def lit_and_error(lit: np.ndarray, truth: np.ndarray, valid: np.ndarray, title: str = ""):
    """Three panels: reference, method, error map (red: false lit, blue: false shadow)."""
    from .metrics import error_map

    fig, axes = plt.subplots(1, 3, figsize=(11, 3.9), constrained_layout=True)
    axes[0].imshow(shade(truth, valid), cmap="gray", vmin=0, vmax=1)
    axes[0].set_title("reference (Embree)")
    axes[1].imshow(shade(lit, valid), cmap="gray", vmin=0, vmax=1)
    axes[1].set_title(title or "method")
    err = error_map(lit, truth, valid)
    axes[2].imshow(err, cmap=ERROR_COLORS, vmin=-1, vmax=1, interpolation="nearest")
    n = int(np.count_nonzero(err))
    axes[2].set_title(f"error: {n} px ({np.count_nonzero(err == 1)} false lit, "
                      f"{np.count_nonzero(err == -1)} false shadow)", fontsize=9)
    for ax in axes:
        ax.set_xticks([])
        ax.set_yticks([])
    return fig


def heat_map(values: np.ndarray, valid: np.ndarray, title: str, label: str):
    """One panel: a per-pixel counter map, invalid pixels transparent."""
    fig, ax = plt.subplots(figsize=(5, 4.4), constrained_layout=True)
    data = np.ma.masked_where(~valid, values)
    im = ax.imshow(data, cmap="inferno")
    fig.colorbar(im, ax=ax, label=label, shrink=0.85)
    ax.set_title(title)
    ax.set_xticks([])
    ax.set_yticks([])
    return fig


def _panel_off(ax) -> None:
    ax.set_xticks([])
    ax.set_yticks([])


def quick_look(lit: np.ndarray, *, reference: np.ndarray | None = None,
               valid: np.ndarray | None = None, counter_maps: dict | None = None,
               counter: str | None = None, title: str = ""):
    """One row of panels for a look at a result: lit, error against ``reference`` (if
    given), one per-pixel counter heat map (if the result has one).

    Args:
        lit: bool [H, W] lit mask (hard) or float [H, W] visibility in [0, 1] (soft).
        reference: the same kind of array to compare with, or None.
        valid: bool [H, W] pixels that see geometry (default: all); others are drawn
            black (lit) or transparent (maps) and left out of the error.
        counter_maps: {name: int array [H, W]} (``ShadowResult.counter_maps()``).
        counter: which map to draw (default: ``tests_per_pixel`` if present, else the
            first by name); a name not in ``counter_maps`` is a ValueError listing them.

    Returns:
        A matplotlib Figure.
    """
    from .metrics import error_map

    lit = np.asarray(lit)
    valid = np.ones(lit.shape, bool) if valid is None else np.asarray(valid, bool)
    maps = dict(counter_maps or {})
    if counter is not None and counter not in maps:
        raise ValueError(f"counter {counter!r} is not a per-pixel map of this result; "
                         f"maps: {', '.join(sorted(maps)) or 'none'}")
    if counter is None and maps:
        counter = "tests_per_pixel" if "tests_per_pixel" in maps else sorted(maps)[0]
    soft = lit.dtype.kind == "f"
    panels = 1 + (reference is not None) + (counter is not None)
    fig, axes = plt.subplots(1, panels, figsize=(3.6 * panels, 3.6), constrained_layout=True,
                             squeeze=False)
    axes = list(axes[0])
    ax = axes.pop(0)
    if soft:
        ax.imshow(np.where(valid, lit, 0.0), cmap="gray", vmin=0, vmax=1)
        ax.set_title(f"{title} visibility" if title else "visibility", fontsize=9)
    else:
        ax.imshow(shade(lit, valid), cmap="gray", vmin=0, vmax=1)
        ax.set_title(f"{title} lit" if title else "lit", fontsize=9)
    _panel_off(ax)
    if reference is not None:
        ax = axes.pop(0)
        reference = np.asarray(reference)
        if reference.shape != lit.shape:
            raise ValueError(f"reference shape {reference.shape} differs from the result's "
                             f"{lit.shape}")
        if soft:
            diff = np.ma.masked_where(~valid, np.abs(lit - reference))
            im = ax.imshow(diff, cmap="magma", vmin=0, vmax=max(float(diff.max() or 0), 1e-6))
            fig.colorbar(im, ax=ax, shrink=0.8)
            ax.set_title(f"|error|: MAE {float(diff.mean() or 0):.4f}", fontsize=9)
        else:
            err = error_map(lit, reference, valid)
            ax.imshow(err, cmap=ERROR_COLORS, vmin=-1, vmax=1, interpolation="nearest")
            ax.set_title(f"error: {np.count_nonzero(err)} px ({np.count_nonzero(err == 1)} "
                         f"false lit, {np.count_nonzero(err == -1)} false shadow)", fontsize=8)
        _panel_off(ax)
    if counter is not None:
        ax = axes.pop(0)
        im = ax.imshow(np.ma.masked_where(~valid, maps[counter]), cmap="inferno")
        fig.colorbar(im, ax=ax, shrink=0.8)
        ax.set_title(counter, fontsize=9)
        _panel_off(ax)
    return fig


def figure_png(fig, dpi: int = 80) -> bytes:
    """The figure as PNG bytes (the figure is closed)."""
    import io

    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=dpi)
    plt.close(fig)
    return buf.getvalue()
