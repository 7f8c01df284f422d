"""Occupancy-map quality against a ground-truth map, with a tolerance of one cell.

Classes: a cell is occupied when its value exceeds 65 (the trinary `occupied_thresh` 0.65), free when
0 <= value < 19.6 (`free_thresh` 0.196), unknown otherwise (-1 included). "Within one cell" means
within the 3 x 3 neighbourhood (Chebyshev distance <= 1).

  precision: estimated occupied cells within one cell of a true occupied cell / estimated occupied
  recall: true *visible* occupied cells (those with a true free 4-neighbour outside `narrow_gaps`: the
          interior of a solid box can never be seen, nor a face across a gap narrower than a cell) within one
          cell of an estimated occupied cell / true visible occupied
  iou: tp / (tp + fp + fn) with tp, fp the matched and unmatched estimated occupied cells and fn the
       unmatched true visible occupied cells
  free_coverage: true free cells the estimate calls free / true free cells (`narrow_gaps` left out)
  phantom_fraction: estimated occupied cells lying in true free space farther than one cell from
          any true occupied cell / estimated occupied cells ("phantom walls")
  recall_in_view, iou_in_view: recall and iou with the true visible occupied cells restricted to those
          `in_view` (`cells_in_view`: the cells the sensor's beams first hit on the true map from the
          true path; the beams stop at `narrow_gaps` as at walls), so walls the robot never faced do not count
          as missed; NaN without `in_view`.
          Precision and its cells are the same as above: a map that draws walls it never saw is still
          charged for them, and one that draws nothing scores 0.

The estimate is compared on the truth's cells: when the two grids differ (origin, resolution or
shape), each true cell centre takes the value of the estimate's cell containing it (nearest-cell
resampling; outside the estimate: unknown). Maps with a non-zero yaw are refused.

`narrow_gaps`: a true map drawn from box footprints by their cells' centres has free cells wherever a gap
between two boxes holds a row of centres, such as behind a piece of furniture 2 cm off a wall. No range
sensor resolves such a gap at the map's resolution (the face behind it lies within a cell of the face in
front) and no robot fits in it, yet counted as free space it would make both faces visible: a quarter of a
generated house's visible wall cells, which a perfect map could never match.
"""

from __future__ import annotations

import dataclasses
import functools

import jax
import jax.numpy as jnp
import numpy as np
from scipy.ndimage import binary_dilation

from jaxquad.io.maps import FREE_THRESH, OCCUPIED_THRESH, OccupancyMap

_NEIGHBOURS = np.ones((3, 3), bool)


@dataclasses.dataclass(frozen=True)
class MapScores:
    precision: float
    recall: float
    iou: float
    free_coverage: float
    phantom_fraction: float
    n_estimated_occupied: int
    n_true_visible_occupied: int
    recall_in_view: float = float("nan")
    iou_in_view: float = float("nan")
    n_true_in_view: int = 0


def resample_map(occ: OccupancyMap, like: OccupancyMap) -> OccupancyMap:
    """`occ`'s values on the cells of `like` (nearest cell; unknown outside `occ`)."""
    for m in (occ, like):
        if m.origin[2] != 0.0:
            raise ValueError(f"map comparison needs yaw 0 origins, got yaw {m.origin[2]}")
    if occ.grid.shape == like.grid.shape and occ.resolution == like.resolution and occ.origin == like.origin:
        return occ
    rc = occ.world_to_cell(like.cell_centers())
    rows, cols = occ.grid.shape
    inside = (rc[..., 0] >= 0) & (rc[..., 0] < rows) & (rc[..., 1] >= 0) & (rc[..., 1] < cols)
    values = np.full(like.grid.shape, -1, np.int8)
    values[inside] = occ.grid[rc[inside][:, 0], rc[inside][:, 1]]
    return OccupancyMap(values, like.resolution, like.origin)


def _classes(grid: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(occupied, free) by the map format's thresholds."""
    g = np.asarray(grid).astype(np.int16)
    return g > 100 * OCCUPIED_THRESH, (g >= 0) & (g < 100 * FREE_THRESH)


def narrow_gaps(truth: OccupancyMap) -> np.ndarray:
    """(H, W) bool: `truth`'s free cells in gaps one cell wide, between occupied cells on both sides along their row
    or their column (see the module docstring)."""
    occ, free = _classes(truth.grid)
    pad = np.pad(occ, 1)
    across_row = pad[1:-1, :-2] & pad[1:-1, 2:]
    across_col = pad[:-2, 1:-1] & pad[2:, 1:-1]
    return free & (across_row | across_col)


def _ratio(num: int, den: int) -> float:
    return float(num) / den if den else float("nan")


@functools.partial(jax.jit, static_argnames=("shape", "n_steps"))
def _first_hits(occupied, origin, resolution, poses, bearings, step, shape, n_steps):
    """Flat index of the first occupied cell on each beam (P, B) marched in `n_steps` steps, -1 for none."""
    rows, cols = shape
    s = jnp.arange(n_steps, dtype=jnp.float32) * step
    a = poses[:, 2:3] + bearings[None]
    c = jnp.floor((poses[:, 0, None, None] + jnp.cos(a)[..., None] * s - origin[0]) / resolution).astype(jnp.int32)
    r = jnp.floor((poses[:, 1, None, None] + jnp.sin(a)[..., None] * s - origin[1]) / resolution).astype(jnp.int32)
    inside = (r >= 0) & (r < rows) & (c >= 0) & (c < cols)
    flat = jnp.where(inside, r * cols + c, 0)
    hit = inside & occupied[flat]
    first = jnp.take_along_axis(flat, jnp.argmax(hit, -1)[..., None], -1)[..., 0]
    return jnp.where(hit.any(-1), first, -1)


def cells_in_view(
    truth: OccupancyMap, poses: np.ndarray, bearings: np.ndarray, range_max: float, step_cells: float = 0.25
) -> np.ndarray:
    """Boolean grid of `truth`'s occupied cells that some beam of an ideal laser first hits: beams at
    `bearings` (B,) rad from each of the sensor poses (S, 3) x y yaw (world), out to `range_max` m,
    marched in steps of `step_cells` cells (a ray that only clips a cell's corner may miss it), stopped also by
    `narrow_gaps`. Poses go through a jitted march 64 at a time (non-finite poses are skipped)."""
    occ = _classes(truth.grid)[0]
    stop = occ | narrow_gaps(truth)
    poses = np.asarray(poses, np.float32)
    poses = poses[np.all(np.isfinite(poses), axis=1)]
    seen = np.zeros(occ.size, bool)
    if poses.size == 0:
        return seen.reshape(occ.shape)
    step = step_cells * truth.resolution
    n_steps = int(np.ceil(range_max / step))
    chunk = 64
    padded = np.concatenate([poses, np.repeat(poses[:1], -len(poses) % chunk, 0)])  # repeats change nothing
    args = (jnp.asarray(stop.ravel()), jnp.asarray(truth.origin[:2], jnp.float32), jnp.float32(truth.resolution))
    for k in range(0, len(padded), chunk):
        idx = np.asarray(
            _first_hits(*args, padded[k : k + chunk], jnp.asarray(bearings, jnp.float32), step, occ.shape, n_steps)
        )
        seen[idx[idx >= 0]] = True
    return seen.reshape(occ.shape) & occ


def map_scores(estimate: OccupancyMap, truth: OccupancyMap, in_view: np.ndarray | None = None) -> MapScores:
    """Scores of `estimate` against `truth` (see the module docstring); NaN where a ratio has no cells.
    `in_view`: a boolean grid on `truth`'s cells (`cells_in_view`) for the in-view recall and IoU."""
    est_occ, est_free = _classes(resample_map(estimate, truth).grid)
    true_occ, true_free = _classes(truth.grid)
    true_free = true_free & ~narrow_gaps(truth)
    cross = np.array([[0, 1, 0], [1, 1, 1], [0, 1, 0]], bool)
    visible = true_occ & binary_dilation(true_free, cross)
    near_true = binary_dilation(true_occ, _NEIGHBOURS)
    near_est = binary_dilation(est_occ, _NEIGHBOURS)
    tp = int((est_occ & near_true).sum())
    fp = int((est_occ & ~near_true).sum())
    fn = int((visible & ~near_est).sum())
    extra = {}
    if in_view is not None:
        if np.shape(in_view) != true_occ.shape:
            raise ValueError(f"in_view has shape {np.shape(in_view)}, the true map {true_occ.shape}")
        seen = visible & np.asarray(in_view, bool)
        fn_seen = int((seen & ~near_est).sum())
        extra = {
            "recall_in_view": _ratio(int((seen & near_est).sum()), int(seen.sum())),
            "iou_in_view": _ratio(tp, tp + fp + fn_seen),
            "n_true_in_view": int(seen.sum()),
        }
    return MapScores(
        precision=_ratio(tp, tp + fp),
        recall=_ratio(int((visible & near_est).sum()), int(visible.sum())),
        iou=_ratio(tp, tp + fp + fn),
        free_coverage=_ratio(int((true_free & est_free).sum()), int(true_free.sum())),
        phantom_fraction=_ratio(int((est_occ & true_free & ~near_true).sum()), int(est_occ.sum())),
        n_estimated_occupied=int(est_occ.sum()),
        n_true_visible_occupied=int(visible.sum()),
        **extra,
    )
