"""Streams resampled onto the log clock, gaps kept as gaps (NaN).

`linear`: at clock time t between source samples s0 <= t < s1, the straight-line (for quaternions,
slerp) blend of the two, when both lie within `tol` of t; a source sample exactly at t is taken as is.
`nearest`: the closest source sample, when it lies within `tol` of t. Elsewhere: NaN.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation


def _bracket(s: np.ndarray, t: np.ndarray, tol: float):
    """Left neighbour index, blend weight and validity of linear interpolation at each t."""
    i = np.clip(np.searchsorted(s, t, side="right") - 1, 0, s.size - 1)
    j = np.minimum(i + 1, s.size - 1)
    exact = s[i] == t
    inside = (s[i] <= t) & (t < s[j]) & (t - s[i] <= tol) & (s[j] - t <= tol)
    w = np.where(inside, (t - s[i]) / np.where(s[j] > s[i], s[j] - s[i], 1.0), 0.0)
    return i, j, w, exact | inside


def _nearest(s: np.ndarray, t: np.ndarray, tol: float):
    j = np.clip(np.searchsorted(s, t), 1, max(s.size - 1, 1)) if s.size > 1 else np.zeros(t.shape, int)
    i = np.where(np.abs(t - s[j - 1]) <= np.abs(s[j] - t), j - 1, j) if s.size > 1 else j
    return i, np.abs(s[i] - t) <= tol


def resample(s: np.ndarray, x: np.ndarray, t: np.ndarray, method: str, tol: float) -> np.ndarray:
    """(N, ...) samples `x` at increasing times `s` -> (T, ...) at times `t`, NaN where no data."""
    x = np.asarray(x, np.float64)
    if method == "nearest":
        i, ok = _nearest(s, t, tol)
        y = x[i]
    else:
        i, j, w, ok = _bracket(s, t, tol)
        w = w.reshape(w.shape + (1,) * (x.ndim - 1))
        y = x[i] * (1.0 - w) + x[j] * w
    y[~ok] = np.nan
    return y


def resample_quat(s: np.ndarray, q_wxyz: np.ndarray, t: np.ndarray, method: str, tol: float) -> np.ndarray:
    """Unit quaternions (w x y z) resampled like `resample`, blended by slerp; bad samples are skipped."""
    good = np.all(np.isfinite(q_wxyz), axis=1) & (np.linalg.norm(np.nan_to_num(q_wxyz), axis=1) > 0.5)
    out = np.full((t.size, 4), np.nan)
    if not np.any(good):
        return out
    s, q = s[good], q_wxyz[good]
    if method == "nearest":
        i, ok = _nearest(s, t, tol)
        out[ok] = q[i[ok]] / np.linalg.norm(q[i[ok]], axis=1, keepdims=True)
        return out
    i, j, w, ok = _bracket(s, t, tol)
    r0 = Rotation.from_quat(q[i[ok]][:, [1, 2, 3, 0]])
    r1 = Rotation.from_quat(q[j[ok]][:, [1, 2, 3, 0]])
    blend = r0 * Rotation.from_rotvec((r0.inv() * r1).as_rotvec() * w[ok, None])
    out[ok] = blend.as_quat()[:, [3, 0, 1, 2]]
    return out
