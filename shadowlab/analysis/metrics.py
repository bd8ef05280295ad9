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


def compare_soft(vis: np.ndarray, truth: np.ndarray, valid: np.ndarray) -> dict:
    """Mean absolute, RMS and maximum error and SSIM of a visibility map [H, W] in [0, 1]."""
    from skimage.metrics import structural_similarity

    diff = (np.asarray(vis, float) - np.asarray(truth, float))[valid]
    a = np.where(valid, vis, 0).astype(float)
    b = np.where(valid, truth, 0).astype(float)
    ssim = structural_similarity(a, b, data_range=1.0) if min(a.shape) >= 7 else float("nan")
    return {
        "valid_pixels": int(np.count_nonzero(valid)),
        "mae": float(np.abs(diff).mean()) if diff.size else 0.0,
        "rmse": float(np.sqrt((diff ** 2).mean())) if diff.size else 0.0,
        "max_error": float(np.abs(diff).max()) if diff.size else 0.0,
        "ssim": float(ssim),
    }
