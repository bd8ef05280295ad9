"""Error of a method against the exact reference."""

from __future__ import annotations

import numpy as np


def error_map(lit: np.ndarray, truth: np.ndarray, valid: np.ndarray) -> np.ndarray:
    """int8 [H, W]: 0 agree, +1 lit but should be shadowed, -1 shadowed but should be lit,
    0 on invalid pixels."""
    lit = np.asarray(lit, bool)
    truth = np.asarray(truth, bool)
    out = np.zeros(lit.shape, np.int8)
    out[valid & lit & ~truth] = 1
    out[valid & ~lit & truth] = -1
    return out


def compare_hard(lit: np.ndarray, truth: np.ndarray, valid: np.ndarray) -> dict:
    """Mismatch counts of a hard-shadow mask [H, W] on valid pixels."""
    err = error_map(lit, truth, valid)
    n_valid = int(np.count_nonzero(valid))
    mismatches = int(np.count_nonzero(err))
    return {
        "valid_pixels": n_valid,
        "mismatches": mismatches,
        "mismatch_fraction": mismatches / max(n_valid, 1),
        "false_lit": int(np.count_nonzero(err == 1)),
        "false_shadow": int(np.count_nonzero(err == -1)),
        "invalid_pixels_lit": int(np.count_nonzero(np.asarray(lit, bool) & ~valid)),
    }


#: pixels the penumbra region is dilated by (a square of side 2 d + 1 around each pixel)
PENUMBRA_DILATION = 2


def penumbra_mask(truth: np.ndarray, valid: np.ndarray,
                  dilation: int = PENUMBRA_DILATION) -> np.ndarray:
    """bool [H, W]: valid pixels within ``dilation`` pixels (Chebyshev distance) of a valid
    pixel whose true visibility is strictly between 0 and 1.

    Soft shadows differ only near penumbrae (often a few percent of the image), so errors
    averaged over every valid pixel are diluted; this region is where they are judged.
    """
    truth = np.asarray(truth, float)
    valid = np.asarray(valid, bool)
    core = valid & (truth > 0.0) & (truth < 1.0)
    out = core.copy()
    h, w = core.shape
    for dy in range(-dilation, dilation + 1):
        for dx in range(-dilation, dilation + 1):
            src = core[max(0, -dy): h - max(0, dy), max(0, -dx): w - max(0, dx)]
            out[max(0, dy): h - max(0, -dy), max(0, dx): w - max(0, -dx)] |= src
    return out & valid


def _errors(diff: np.ndarray) -> tuple[float, float, float]:
    if not diff.size:
        return 0.0, 0.0, 0.0
    a = np.abs(diff)
    return float(a.mean()), float(np.sqrt((diff ** 2).mean())), float(a.max())


def compare_soft(vis: np.ndarray, truth: np.ndarray, valid: np.ndarray,
                 dilation: int = PENUMBRA_DILATION) -> dict:
    """Errors of a visibility map [H, W] in [0, 1] against ``truth`` [H, W].

    Whole image (valid pixels): ``mae``, ``rmse``, ``max_error``, ``ssim`` (invalid pixels
    set to 0 in both; NaN below 7 x 7). Penumbra region (:func:`penumbra_mask`): the same
    as ``penumbra_mae``, ``penumbra_rmse``, ``penumbra_max_error`` and ``penumbra_ssim``
    (the mean of the SSIM map over the region; NaN when it is empty or the image is
    below 7 x 7), and ``penumbra_pixels``.
    """
    from skimage.metrics import structural_similarity

    valid = np.asarray(valid, bool)
    vis = np.asarray(vis, float)
    truth = np.asarray(truth, float)
    diff = vis - truth
    a = np.where(valid, vis, 0.0)
    b = np.where(valid, truth, 0.0)
    if min(a.shape) >= 7:
        ssim, ssim_map = structural_similarity(a, b, data_range=1.0, full=True)
    else:
        ssim, ssim_map = float("nan"), None
    pen = penumbra_mask(truth, valid, dilation)
    mae, rmse, mx = _errors(diff[valid])
    p_mae, p_rmse, p_mx = _errors(diff[pen])
    p_ssim = float(ssim_map[pen].mean()) if ssim_map is not None and pen.any() else float("nan")
    return {
        "valid_pixels": int(np.count_nonzero(valid)),
        "mae": mae, "rmse": rmse, "max_error": mx, "ssim": float(ssim),
        "penumbra_pixels": int(np.count_nonzero(pen)),
        "penumbra_mae": p_mae, "penumbra_rmse": p_rmse, "penumbra_max_error": p_mx,
        "penumbra_ssim": p_ssim,
    }


def discontinuity_mask(gbuf, ratio: float = 2.0, tile: tuple[int, int] = (4, 8)) -> np.ndarray:
    """bool [H, W]: valid pixels whose tile (``tile`` = (rows, columns); PTSV's 8 x 4
    pixels by default) holds view depths differing by more than a factor ``ratio``: the
    steep depth discontinuities of Sintorn et al. 2014, Fig. 3."""
    import warnings

    h, w = gbuf.shape
    th, tw = tile
    hp, wp = -(-h // th) * th, -(-w // tw) * tw
    d = np.full((hp, wp), np.nan)
    d[:h, :w] = np.where(gbuf.valid, gbuf.depth, np.nan)
    blocks = d.reshape(hp // th, th, wp // tw, tw)
    with warnings.catch_warnings(), np.errstate(all="ignore"):   # all-empty tiles: NaN
        warnings.simplefilter("ignore", RuntimeWarning)
        steep = np.nanmax(blocks, axis=(1, 3)) / np.nanmin(blocks, axis=(1, 3)) > ratio
    steep = np.repeat(np.repeat(np.nan_to_num(steep, nan=0).astype(bool), th, 0), tw, 1)
    return steep[:h, :w] & gbuf.valid
