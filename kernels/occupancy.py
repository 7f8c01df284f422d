"""Log-odds occupancy grids from 2D laser scans.

Grid conventions are those of `jaxquad.io.OccupancyMap`: row-major from the lower-left corner (row
index grows with y, column with x), square cells of `resolution` m, `origin` = world x y of the
lower-left corner of cell (0, 0), yaw 0.

One scan at one pose: each ray is traversed from the sensor's cell to its end cell with exactly the
cells of integer Bresenham (the major axis steps one cell at a time; the minor offset at step k is
ceil((2 k d_minor - d_major) / (2 d_major)), the closed form of the classic error-term loop with its
tie rule), in a fixed number of steps so that it jits and vmaps. Cells before the end cell are free;
the end cell is occupied when the ray has a return. Rays, by reading r:
  range_min <= r < range_max (finite): free up to the hit, hit cell occupied (the hit at r + hit_offset);
  r >= range_max or r = +inf (no return): free up to range_max, its end cell included, no hit;
  range_max <= r < clear_range (a far return, when clear_range > range_max): free up to
    max(range_max, r - clear_margin r^2), its end cell included, no hit;
  NaN, -inf or r < range_min (0 included: a depth camera's invalid pixel): ignored.
Per scan each ray brings its evidence to its cells (l_occ to its end cell when it has a return, l_free
to every other cell it touches), and a cell changes by the sum over the scan's rays, clipped to
[l_free, l_occ]: the rays of one scan share one pose and its error, so a scan counts as one observation
of a cell at most, and a cell that some rays end in while others cross it goes the way of their balance.
Depth noise grows with range (1 % of z^2: 4 cm at 2 m, 16 cm at 4 m), so far returns scatter a few cells
in front of a wall; a rule that let any ending ray win marked those free cells occupied in nearly every
scan and drew walls 2-3 cells thick. Log-odds are clamped to [l_min, l_max]. Cells outside the grid are
dropped.
"""

from __future__ import annotations

import math

import equinox as eqx
import jax
import jax.numpy as jnp
from jaxtyping import Array, Bool, Float, Int8


class GridSpec(eqx.Module):
    """Static grid geometry: shapes and the traversal length depend on it."""

    rows: int = eqx.field(static=True)
    cols: int = eqx.field(static=True)
    resolution: float = eqx.field(static=True)  # m per cell
    origin_x: float = eqx.field(static=True)  # m, lower-left corner of cell (0, 0)
    origin_y: float = eqx.field(static=True)
    max_range: float = eqx.field(static=True)  # m: sizes the traversal; params.range_max is clipped to it

    @property
    def max_steps(self) -> int:
        """Cells along the longest ray's major axis, end cell included (+2: start and end rounding)."""
        return math.ceil(self.max_range / self.resolution) + 2


class OccupancyParams(eqx.Module):
    """Inverse sensor model (traced leaves)."""

    l_free: Float[Array, ""] = eqx.field(default_factory=lambda: jnp.asarray(math.log(0.35 / 0.65)))
    l_occ: Float[Array, ""] = eqx.field(default_factory=lambda: jnp.asarray(math.log(0.8 / 0.2)))
    l_min: Float[Array, ""] = eqx.field(default_factory=lambda: jnp.asarray(-2.0))
    l_max: Float[Array, ""] = eqx.field(default_factory=lambda: jnp.asarray(3.5))
    range_min: Float[Array, ""] = eqx.field(default_factory=lambda: jnp.asarray(0.1))
    range_max: Float[Array, ""] = eqx.field(default_factory=lambda: jnp.asarray(20.0))
    # m: a return's end cell is taken this far beyond the reading, along the ray (at most the grid's max_range). A
    # map cell is occupied when its centre lies inside an obstacle, so the cell a face passes through is free when
    # its centre is in front of the face; half a cell puts a square-on return into the cell whose centre is behind
    # the face, and leaves the one in front to the ray's free evidence.
    hit_offset: Float[Array, ""] = eqx.field(default_factory=lambda: jnp.asarray(0.0))
    # m: readings from range_max up to this clear the ray short of the reading (module docstring); at most range_max
    # (the default 0 included): none do. The grid's max_range must reach it.
    clear_range: Float[Array, ""] = eqx.field(default_factory=lambda: jnp.asarray(0.0))
    clear_margin: Float[Array, ""] = eqx.field(default_factory=lambda: jnp.asarray(0.0))  # 1/m: margin per r^2


class OccupancyGrid(eqx.Module):
    log_odds: Float[Array, "rows cols"]
    observed: Bool[Array, "rows cols"]  # touched by at least one ray (else unknown)


def init_grid(spec: GridSpec) -> OccupancyGrid:
    return OccupancyGrid(jnp.zeros((spec.rows, spec.cols)), jnp.zeros((spec.rows, spec.cols), bool))


def _cell(spec: GridSpec, x, y):
    col = jnp.floor((x - spec.origin_x) / spec.resolution).astype(jnp.int32)
    row = jnp.floor((y - spec.origin_y) / spec.resolution).astype(jnp.int32)
    return row, col


def ray_cells(spec: GridSpec, row0, col0, row1, col1) -> tuple[Array, Array, Array]:
    """Bresenham cells of ONE ray: (row, col) of `spec.max_steps` steps and the step count n to the
    end cell (steps 0..n are the line, n the end cell; later steps are padding)."""
    d_col, d_row = col1 - col0, row1 - row0
    # |d| in float32 (exact below 2^24 cells): XLA on CUDA GPUs (jax 0.11.2) compiled the int32 maximum
    # of the two abs values, in every form tried, as if abs(d_col) were d_col, cutting short every ray
    # with d_col < 0 (`test_scan_cells_equal_numpy_bresenham` fails there without this).
    a_col, a_row = jnp.abs(d_col.astype(jnp.float32)), jnp.abs(d_row.astype(jnp.float32))
    x_major = a_col >= a_row
    major = jnp.where(x_major, a_col, a_row).astype(jnp.int32)
    minor = jnp.where(x_major, a_row, a_col).astype(jnp.int32)
    k = jnp.arange(spec.max_steps, dtype=jnp.int32)
    # offset = ceil(num / den) with num = 2 k minor - major, den = 2 major: a float estimate (integer
    # division is slow on CPUs) made exact by one integer correction each way.
    num, den = 2 * k * minor - major, 2 * jnp.maximum(major, 1)
    offset = jnp.ceil(num.astype(jnp.float32) / den.astype(jnp.float32)).astype(jnp.int32)
    offset = jnp.where((offset - 1) * den >= num, offset - 1, jnp.where(offset * den < num, offset + 1, offset))
    step_col = jnp.where(x_major, k, offset) * jnp.sign(d_col)
    step_row = jnp.where(x_major, offset, k) * jnp.sign(d_row)
    return row0 + step_row, col0 + step_col, major


def scan_evidence(
    spec: GridSpec,
    params: OccupancyParams,
    pose: Float[Array, "3"],
    ranges: Float[Array, "b"],
    bearings: Float[Array, "b"],
) -> tuple[Float[Array, "rows cols"], Bool[Array, "rows cols"]]:
    """(log-odds change, touched) per cell of one scan at `pose` (x, y, theta of the sensor, world): the
    sum of its rays' evidence clipped to [l_free, l_occ], and whether any ray touched the cell (see the
    module docstring for which rays count)."""
    range_max = jnp.minimum(params.range_max, spec.max_range)
    no_return = (ranges >= range_max) & ~jnp.isnan(ranges)  # +inf included
    valid = no_return | (jnp.isfinite(ranges) & (ranges >= params.range_min))
    far = no_return & jnp.isfinite(ranges) & (ranges < params.clear_range)
    r_far = jnp.where(far, ranges, range_max)  # finite on every ray (no inf - inf below, nor in its gradient)
    cleared = jnp.maximum(range_max, r_far - params.clear_margin * r_far**2)
    r = jnp.where(far, cleared, jnp.where(no_return | ~valid, range_max, ranges + params.hit_offset))
    r = jnp.minimum(r, spec.max_range)
    angle = pose[2] + bearings
    row0, col0 = _cell(spec, pose[0], pose[1])
    row1, col1 = _cell(spec, pose[0] + r * jnp.cos(angle), pose[1] + r * jnp.sin(angle))
    rows, cols, n = jax.vmap(ray_cells, in_axes=(None, None, None, 0, 0))(spec, row0, col0, row1, col1)
    k = jnp.arange(spec.max_steps)
    end = jnp.where(no_return, 1, 2)[:, None]  # a ray with no return clears its end cell too
    code = jnp.where(k < n[:, None], 1, jnp.where(k == n[:, None], end, 0))
    code = jnp.where(valid[:, None], code, 0)
    inside = (rows >= 0) & (rows < spec.rows) & (cols >= 0) & (cols < spec.cols) & (code > 0)
    flat = jnp.where(inside, rows * spec.cols + cols, spec.rows * spec.cols).ravel()  # out of range: dropped
    evidence = jnp.where(code == 2, params.l_occ, jnp.where(code == 1, params.l_free, 0.0)).astype(jnp.float32)
    size = spec.rows * spec.cols
    total = jnp.zeros(size, jnp.float32).at[flat].add(evidence.ravel(), mode="drop")
    touched = jnp.zeros(size, bool).at[flat].max(inside.ravel(), mode="drop")
    delta = jnp.clip(total, params.l_free, params.l_occ)
    return delta.reshape(spec.rows, spec.cols), touched.reshape(spec.rows, spec.cols)


def insert_scan(
    spec: GridSpec,
    params: OccupancyParams,
    grid: OccupancyGrid,
    pose: Float[Array, "3"],
    ranges: Float[Array, "b"],
    bearings: Float[Array, "b"],
) -> OccupancyGrid:
    """The grid after one scan at `pose` (log-odds update, clamped)."""
    delta, touched = scan_evidence(spec, params, pose, ranges, bearings)
    log_odds = jnp.clip(grid.log_odds + delta.astype(grid.log_odds.dtype), params.l_min, params.l_max)
    return OccupancyGrid(log_odds, grid.observed | touched)


def occupancy_values(grid: OccupancyGrid) -> Int8[Array, "rows cols"]:
    """The map format's cell values: -1 where no ray went, else round(100 p) with p = 1 / (1 + exp(-log_odds))."""
    p = 1.0 / (1.0 + jnp.exp(-grid.log_odds))
    return jnp.where(grid.observed, jnp.rint(100.0 * p), -1.0).astype(jnp.int8)


def map_from_scans(
    spec: GridSpec,
    params: OccupancyParams,
    poses: Float[Array, "t 3"],
    ranges: Float[Array, "t b"],
    bearings: Float[Array, "b"],
    scan_mask: Bool[Array, "t"] | None = None,
) -> OccupancyGrid:
    """A map from T scans at T poses from an empty grid (`lax.scan`); `scan_mask` skips scans."""
    mask = jnp.ones(poses.shape[0], bool) if scan_mask is None else scan_mask

    def step(grid, inputs):
        pose, r, keep = inputs
        # A skipped scan reads NaN everywhere: every ray is ignored (cheaper than selecting whole grids).
        return insert_scan(spec, params, grid, pose, jnp.where(keep, r, jnp.nan), bearings), None

    grid, _ = jax.lax.scan(step, init_grid(spec), (poses, ranges, mask))
    return grid
