"""Timestamp association with evo's nearest-time rule (NumPy: it changes lengths, so it runs before JAX)."""

from __future__ import annotations

import numpy as np


def _check_stamps(t: np.ndarray, name: str) -> np.ndarray:
    t = np.asarray(t, dtype=np.float64)
    if t.ndim != 1 or t.size == 0:
        raise ValueError(f"{name} timestamps must be a non-empty 1-D array, got shape {t.shape}")
    if not np.all(np.isfinite(t)):
        raise ValueError(f"{name} timestamps contain NaN or infinite values")
    if np.any(np.diff(t) <= 0):
        raise ValueError(f"{name} timestamps must increase strictly")
    return t


def _nearest(t_short: np.ndarray, t_long: np.ndarray, max_diff: float) -> tuple[np.ndarray, np.ndarray]:
    """For every stamp of `t_short`, the nearest stamp of `t_long` (the earlier one on ties), kept if
    within `max_diff` seconds. Same comparisons, in the same floating-point arithmetic, as evo's
    binary search, so borderline stamps are kept or dropped exactly as evo does."""
    n = t_long.size
    in_range = ~((t_short < t_long[0] - max_diff) | (t_short > t_long[-1] + max_diff))
    upper = np.minimum(np.searchsorted(t_long, t_short, side="right"), n - 1)
    diff_ub = t_long[upper] - t_short
    diff_lb = np.where(upper > 0, t_short - t_long[np.maximum(upper - 1, 0)], np.inf)
    take_ub = (diff_ub <= max_diff) & (diff_ub < diff_lb)
    take_lb = ~take_ub & (diff_lb <= max_diff) & (diff_lb <= diff_ub)
    keep = in_range & (take_ub | take_lb)
    idx_long = np.where(take_ub, upper, upper - 1)
    return np.flatnonzero(keep), idx_long[keep]


def associate(t_ref_s: np.ndarray, t_est_s: np.ndarray, max_diff_s: float = 0.01) -> tuple[np.ndarray, np.ndarray]:
    """Indices (idx_ref, idx_est) of associated poses, as evo associates a reference and an estimate.

    Every stamp of the trajectory with fewer poses (the estimate when both have as many) is matched to
    the nearest stamp of the other and kept if |dt| <= max_diff_s; matches are not one-to-one.
    ValueError when no stamp matches.
    """
    t_ref = _check_stamps(t_ref_s, "reference")
    t_est = _check_stamps(t_est_s, "estimate")
    if not max_diff_s >= 0:
        raise ValueError(f"max_diff must be >= 0 seconds, got {max_diff_s}")
    est_longer = t_est.size > t_ref.size
    if est_longer:
        idx_ref, idx_est = _nearest(t_ref, t_est, max_diff_s)
    else:
        idx_est, idx_ref = _nearest(t_est, t_ref, max_diff_s)
    if idx_ref.size == 0:
        raise ValueError(
            f"no matching timestamps between reference [{t_ref[0]}, {t_ref[-1]}] s and estimate "
            f"[{t_est[0]}, {t_est[-1]}] s within max_diff {max_diff_s} s"
        )
    return idx_ref, idx_est
