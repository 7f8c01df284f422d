"""A tiny NumPy 2D laser caster over line segments: the independent scan source of the SLAM front-end tests."""

from __future__ import annotations

import numpy as np


def box(x0: float, y0: float, x1: float, y1: float) -> np.ndarray:
    """The four sides of an axis-aligned rectangle as segments (4, 4): x0 y0 x1 y1."""
    return np.array([[x0, y0, x1, y0], [x1, y0, x1, y1], [x1, y1, x0, y1], [x0, y1, x0, y0]], float)


def cast(segments: np.ndarray, pose: np.ndarray, bearings: np.ndarray, max_range: float) -> np.ndarray:
    """Ranges from sensor pose (x, y, theta) along bearings to the nearest segment; inf beyond max_range."""
    a = pose[2] + bearings
    d = np.stack([np.cos(a), np.sin(a)], -1)[:, None, :]  # (B, 1, 2)
    p0, p1 = segments[None, :, :2], segments[None, :, 2:]
    e = p1 - p0
    w = p0 - pose[:2]
    den = d[..., 0] * e[..., 1] - d[..., 1] * e[..., 0]
    with np.errstate(divide="ignore", invalid="ignore"):
        t = (w[..., 0] * e[..., 1] - w[..., 1] * e[..., 0]) / den  # along the ray
        u = (w[..., 0] * d[..., 1] - w[..., 1] * d[..., 0]) / den  # along the segment
    hit = (np.abs(den) > 1e-12) & (t > 0) & (u >= 0) & (u <= 1)
    r = np.where(hit, t, np.inf).min(axis=1)
    return np.where(r <= max_range, r, np.inf)
