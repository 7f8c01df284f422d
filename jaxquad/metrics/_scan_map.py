"""Agreement of laser-scan end points with an occupancy map."""

from __future__ import annotations

import numpy as np


def scan_map_hits(points_world: np.ndarray, occ, tolerance: float = 0.2) -> np.ndarray:
    """Per end point (..., 2) world x y (m): True where the map cell holding it has an occupied cell
    (occupancy >= 50) whose centre is within `tolerance` m of its own centre (map yaw 0). Points off
    the map or not finite are False."""
    from scipy.ndimage import distance_transform_edt

    occupied = occ.grid >= 50
    pts = np.asarray(points_world, np.float64)
    if not occupied.any():
        return np.zeros(pts.shape[:-1], bool)
    # Distance (m) from every cell centre to the nearest occupied cell centre.
    dist = distance_transform_edt(~occupied) * occ.resolution
    finite = np.all(np.isfinite(pts), axis=-1)
    rc = occ.world_to_cell(np.where(finite[..., None], pts, 0.0))
    rows, cols = occ.grid.shape
    inside = finite & (rc[..., 0] >= 0) & (rc[..., 0] < rows) & (rc[..., 1] >= 0) & (rc[..., 1] < cols)
    rc = np.where(inside[..., None], rc, 0)
    return inside & (dist[rc[..., 0], rc[..., 1]] <= tolerance + 1e-9)
