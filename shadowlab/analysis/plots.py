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
