"""Occupancy mapping glue: grid geometry from a map or bounds, grids to `OccupancyMap`s, fleets."""

from __future__ import annotations

import jax
import numpy as np

from jaxquad.io.maps import OccupancyMap
from jaxquad.kernels.occupancy import GridSpec, OccupancyGrid, map_from_scans, occupancy_values


def grid_spec(bounds: tuple[float, float, float, float], resolution: float, max_range: float) -> GridSpec:
    """The grid covering `bounds` (xmin, ymin, xmax, ymax; m) with square cells of `resolution` m."""
    xmin, ymin, xmax, ymax = bounds
    if not (xmax > xmin and ymax > ymin and resolution > 0 and max_range > 0):
        raise ValueError(
            f"grid needs xmax > xmin, ymax > ymin and positive sizes, got bounds {bounds}, "
            f"resolution {resolution}, max_range {max_range}"
        )
    cols, rows = int(np.ceil((xmax - xmin) / resolution)), int(np.ceil((ymax - ymin) / resolution))
    return GridSpec(rows, cols, float(resolution), float(xmin), float(ymin), float(max_range))


def grid_spec_like(occ: OccupancyMap, max_range: float) -> GridSpec:
    """The grid of an existing map (same cells), e.g. the simulator's ground truth."""
    if occ.origin[2] != 0.0:
        raise ValueError(f"occupancy grids need a map yaw of 0, got {occ.origin[2]}")
    rows, cols = occ.grid.shape
    return GridSpec(rows, cols, float(occ.resolution), float(occ.origin[0]), float(occ.origin[1]), float(max_range))


def to_occupancy_map(spec: GridSpec, grid: OccupancyGrid) -> OccupancyMap:
    """-1 where no ray went, else round(100 p) with p = 1 / (1 + exp(-log_odds)); saves with `save_map`."""
    shape = np.shape(grid.log_odds)
    if shape != (spec.rows, spec.cols):
        raise ValueError(
            f"grid shape {shape} is not the spec's ({spec.rows}, {spec.cols}); convert one robot's grid at a time"
        )
    values = np.asarray(occupancy_values(grid))
    return OccupancyMap(values, spec.resolution, (spec.origin_x, spec.origin_y, 0.0))


def fleet_maps(spec: GridSpec, params, poses, ranges, bearings, scan_mask=None) -> OccupancyGrid:
    """Maps of R robots at once: poses (R, T, 3), ranges (R, T, B), bearings (B,), scan_mask (R, T)."""
    fn = jax.vmap(map_from_scans, in_axes=(None, None, 0, 0, None, None if scan_mask is None else 0))
    return jax.jit(fn)(spec, params, poses, ranges, bearings, scan_mask)
