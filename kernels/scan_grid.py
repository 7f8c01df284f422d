"""Smeared likelihood grids for correlative scan matching (the lookup table that scores scan points).

A `LikelihoodGrid` is a square grid of `MatchSpec.cells` cells of `MatchSpec.resolution` m,
centred on `center_xy` (world frame): the world point p falls in cell (row, col) =
floor((p - center_xy) / resolution) + cells // 2 (row along y, column along x). Each cell holds an
integer in 0..100: 100 where a reference point falls, and around it a Gaussian smear

    value(c) = round(100 * max_p exp(-|c - cell(p)|^2 resolution^2 / (2 smear_sigma^2)))

over the reference points p whose cell offset from c is at most h = `smear_half_cells` along each
axis (offsets counted in whole cells from the point's cell, as Karto's kernel does). Integers make
the score of a pose an exact integer sum, so the multi-resolution search returns the same maximum
as an exhaustive one, bit for bit.

The grid is stored zero-padded by `spec.margin` cells on every side (so that every shifted lookup
of the search stays inside the array) together with its max-pooled copy (`pooled[i, j]` = max of
the `block` x `block` cells starting at (i, j)), the bound of the coarse search level.
"""

from __future__ import annotations

import math

import equinox as eqx
import jax
import jax.numpy as jnp
from jaxtyping import Array, Bool, Float, UInt8

from jaxquad.kernels.control_flow import run_if
from jaxquad.kernels.lie import SE2

# Grid value of a cell that holds a reference point (Karto's "occupied" value).
GRID_MAX = 100


class MatchSpec(eqx.Module):
    """Static structure of a correlative scan match: sizes and step counts (shapes depend on them).

    Defaults are the paper's correlation settings (Karto/slam_toolbox): window +-0.5 m at 0.01 m,
    angles +-20 deg in 2 deg steps refined at 0.2 deg. `cells` bounds the range used: beams longer
    than `reach` = (cells / 2 - window_cells - 1) * resolution are left out of the match (1024 cells
    at 0.01 m: 4.61 m; `cells_for_range` sizes the grid for a longer-range laser).
    """

    cells: int = eqx.field(static=True, default=1024)  # grid side, cells
    resolution: float = eqx.field(static=True, default=0.01)  # m per cell = translation search step
    window_cells: int = eqx.field(static=True, default=50)  # translation search +- this many cells
    angle_window_deg: float = eqx.field(static=True, default=20.0)  # rotation search +- this, deg
    angle_step_deg: float = eqx.field(static=True, default=2.0)  # exact (stage 1) rotation step, deg
    fine_angle_step_deg: float = eqx.field(static=True, default=0.2)  # refinement step within +-angle_step
    refine_cells: int = eqx.field(static=True, default=1)  # refinement translation +- cells
    block: int = eqx.field(static=True, default=8)  # coarse-level block side, cells
    candidates: int = eqx.field(static=True, default=8)  # coarse blocks expanded per round
    max_rounds: int | None = eqx.field(static=True, default=None)  # cap on rounds (None: exact, no cap)
    smear_half_cells: int = eqx.field(static=True, default=6)  # smear kernel reach, cells (2 sigma)
    cov_points: int = eqx.field(static=True, default=10)  # covariance lattice +- this many points per axis

    @property
    def n_angles(self) -> int:
        return 2 * round(self.angle_window_deg / self.angle_step_deg) + 1

    @property
    def n_fine(self) -> int:
        """Refinement angles on each side of the stage-1 angle."""
        return round(self.angle_step_deg / self.fine_angle_step_deg)

    @property
    def n_blocks(self) -> int:
        return -(-(2 * self.window_cells + 1) // self.block)

    @property
    def cov_stride(self) -> int:
        return max(1, self.window_cells // self.cov_points)

    @property
    def margin(self) -> int:
        """Zero padding, cells: the covariance lattice reaches 2 window + refine cells from the centre,
        and the coarse level's sliding max needs block - 1 zero cells beyond the smear's reach."""
        lattice = 2 * self.window_cells + max(self.block, self.refine_cells) + 1
        return max(lattice, self.smear_half_cells + self.block - 1)

    @property
    def reach(self) -> float:
        """Longest range (m) whose end point stays inside the grid at every searched translation."""
        return (self.cells // 2 - self.window_cells - 1) * self.resolution

    @property
    def padded(self) -> int:
        return self.cells + 2 * self.margin

    @classmethod
    def loop(cls, cells: int = 320, resolution: float = 0.05, window_cells: int = 40, **kw) -> "MatchSpec":
        """Loop-closure preset: a larger window at a coarser step (+-2 m at 0.05 m, 16 m of grid)."""
        return cls(
            cells=cells,
            resolution=resolution,
            window_cells=window_cells,
            smear_half_cells=1,
            block=8,
            **kw,
        )


class MatchParams(eqx.Module):
    """Tunable numbers of a match (traced leaves: sweeps never recompile)."""

    smear_sigma: Float[Array, ""] = eqx.field(default_factory=lambda: jnp.asarray(0.03))  # m
    range_min: Float[Array, ""] = eqx.field(default_factory=lambda: jnp.asarray(0.1))  # m; shorter: invalid
    range_max: Float[Array, ""] = eqx.field(default_factory=lambda: jnp.asarray(20.0))  # m; longer: invalid
    cov_response_drop: Float[Array, ""] = eqx.field(default_factory=lambda: jnp.asarray(0.1))  # response units


class LikelihoodGrid(eqx.Module):
    values: UInt8[Array, "P P"]  # smeared grid, zero-padded by spec.margin
    pooled: UInt8[Array, "P P"]  # block x block forward max of `values`
    center_xy: Float[Array, "2"]  # world position of the centre of the unpadded grid, m


def scan_points(
    params: MatchParams,
    ranges: Float[Array, " b"],
    bearings: Float[Array, " b"],
    valid: Bool[Array, " b"],
) -> tuple[Float[Array, "b 2"], Bool[Array, " b"]]:
    """End points in the sensor frame and their validity (finite, within [range_min, range_max])."""
    ok = valid & jnp.isfinite(ranges) & (ranges >= params.range_min) & (ranges <= params.range_max)
    r = jnp.where(ok, ranges, 0.0)
    return jnp.stack([r * jnp.cos(bearings), r * jnp.sin(bearings)], -1), ok


def world_points(
    params: MatchParams,
    poses: Float[Array, "n 3"],
    ranges: Float[Array, "n b"],
    bearings: Float[Array, " b"],
    valid: Bool[Array, "n b"],
) -> tuple[Float[Array, "nb 2"], Bool[Array, " nb"]]:
    """End points of n scans taken at sensor poses (x, y, theta, world), flattened, with validity."""
    p_sensor, ok = jax.vmap(scan_points, in_axes=(None, 0, None, 0))(params, ranges, bearings, valid)
    T = jax.vmap(SE2.from_xy_theta)(poses[:, 0], poses[:, 1], poses[:, 2])
    with jax.default_matmul_precision("highest"):  # GPUs would round float32 matmuls to TF32
        p_world = jax.vmap(lambda T, p: jax.vmap(T.apply)(p))(T, p_sensor)
    return p_world.reshape(-1, 2), ok.reshape(-1)


def cell_of(spec: MatchSpec, center_xy: Float[Array, "2"], p: Float[Array, "*n 2"]) -> Array:
    """(row, col) int32 cells of world points in the unpadded grid centred on `center_xy` (may be outside)."""
    c = jnp.floor((p - center_xy) / spec.resolution).astype(jnp.int32) + spec.cells // 2
    return jnp.stack([c[..., 1], c[..., 0]], -1)


def _kernel(spec: MatchSpec, params: MatchParams) -> Array:
    """The smear kernel, (2h+1)^2 cells, uint8."""
    h = spec.smear_half_cells
    o = jnp.arange(-h, h + 1, dtype=jnp.float32) * spec.resolution
    d2 = o[:, None] ** 2 + o[None, :] ** 2
    return jnp.round(GRID_MAX * jnp.exp(-0.5 * d2 / params.smear_sigma**2)).astype(jnp.uint8)


def _forward_max_axis0(x: Array, b: int) -> Array:
    """y[i] = max of x[i : i + b] along the first axis, zero beyond the end: one fused max of b shifted
    slices over contiguous memory."""
    n = x.shape[0]
    padded = jnp.pad(x, [(0, b - 1)] + [(0, 0)] * (x.ndim - 1))
    y = padded[:n]
    for k in range(1, b):
        y = jnp.maximum(y, padded[k : k + n])
    return y


def _forward_max(x: Array, b: int) -> Array:
    """y[i, j] = max of x over the b x b cells starting at (i, j), zero beyond the end.

    Needs the first b - 1 columns of x to be zero (the grid's margin): then a shift of the flattened
    grid that runs past a row's end reads those zeros, as the shift within the row reads zeros
    beyond its end. So both axes are passes along a first axis (on CPUs a shift within rows, or a
    transpose, costs about ten times as much).
    """
    along_rows = _forward_max_axis0(x.reshape(-1), b).reshape(x.shape)
    return _forward_max_axis0(along_rows, b)


def _splat(spec: MatchSpec, rc: Array, inside: Array, kernel: Array) -> Array:
    """Padded grid of the max over points of `kernel` centred on each point's cell.

    One scatter of (2h+1)^2 windows: XLA computes one index per point, not one per cell (a third
    of the time on CPUs). Points outside are sent out of bounds, and dropped whole.
    """
    k = kernel.shape[0]
    P = spec.padded
    corner = jnp.where(inside[:, None], rc - k // 2 + spec.margin, P)
    dims = jax.lax.ScatterDimensionNumbers(
        update_window_dims=(1, 2), inserted_window_dims=(), scatter_dims_to_operand_dims=(0, 1)
    )
    windows = jnp.broadcast_to(kernel, (rc.shape[0], k, k))
    mode = jax.lax.GatherScatterMode.FILL_OR_DROP

    def scatter(dtype):
        grid = jnp.zeros((P, P), dtype)
        return lambda: jax.lax.scatter_max(grid, corner, windows.astype(dtype), dims, mode=mode).astype(jnp.uint8)

    # GPUs have no 8-bit atomic max (XLA loops a 32-bit compare-and-swap): 32-bit cells there make
    # the whole SLAM fleet about 1.3x faster; on CPUs 8-bit cells are about 1.3x faster.
    return jax.lax.platform_dependent(cuda=scatter(jnp.int32), default=scatter(jnp.uint8))


def likelihood_grid(
    spec: MatchSpec,
    params: MatchParams,
    center_xy: Float[Array, "2"],
    points_world: Float[Array, "m 2"],
    mask: Bool[Array, " m"],
) -> LikelihoodGrid:
    """The smeared grid of the reference points (masked ones and those outside the grid ignored).

    The kernels are scattered point by point (cost m (2h+1)^2), the coarse level is a dense
    sliding max (one pass per axis over the padded grid, whose zero margin it relies on).
    """
    rc = cell_of(spec, center_xy, points_world)
    finite = jnp.all(jnp.isfinite(points_world - center_xy), axis=-1)  # NaN casts to an arbitrary cell
    inside = mask & finite & jnp.all((rc >= 0) & (rc < spec.cells), axis=-1)
    values = _splat(spec, rc, inside, _kernel(spec, params))
    # A grid of no point is its own pooled copy. As a loop the copy is also computed once into memory:
    # XLA would otherwise fuse the sliding max into the search's gathers and redo it per lookup.
    pooled = run_if(jnp.any(inside), lambda v: _forward_max(v, spec.block), values)
    return LikelihoodGrid(values, pooled, jnp.asarray(center_xy, jnp.float32))


def cells_for_range(max_range: float, resolution: float, window_cells: int) -> int:
    """Grid side (cells, even) that scores every point within `max_range` m of the sensor."""
    return 2 * (math.ceil(max_range / resolution) + window_cells + 1)
