"""Occupancy mapping glue: grid geometry from a map or bounds, grids to `OccupancyMap`s, fleets, a SLAM state's map."""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from jaxquad.io.maps import OccupancyMap
from jaxquad.kernels.lie import se2, xy_theta
from jaxquad.kernels.occupancy import GridSpec, OccupancyGrid, init_grid, insert_scan, map_from_scans, occupancy_values
from jaxquad.slam.state import SlamOutput, SlamParams, SlamSpec, SlamState


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


def _sensor(params: SlamParams, base: Float[Array, "*n 3"]) -> Float[Array, "*n 3"]:
    return xy_theta(se2(base) @ se2(params.T_base_laser))


def _compose(a: Float[Array, "3"], d: Float[Array, "3"]) -> Float[Array, "3"]:
    return xy_theta(se2(a) @ se2(d))


def _insert(spec: SlamSpec, params: SlamParams, grid: OccupancyGrid, base, ranges, valid, bearings) -> OccupancyGrid:
    r = jnp.where(valid, ranges, jnp.nan)  # NaN rays are ignored by the map
    return insert_scan(spec.grid, params.occupancy, grid, _sensor(params, base), r, bearings)


def refresh_map(spec: SlamSpec, params: SlamParams, state: SlamState) -> SlamState:
    """The map redrawn from every node's scan at its current pose when `map_stale` (else unchanged).

    The redraw loops over nodes with a trip count of 0 when the map is current, so under `vmap` it
    costs nothing unless some robot's map is stale."""
    count = jnp.where(state.map_stale, state.n_nodes, 0)
    g = state.graph

    def body(carry):
        k, grid = carry
        return k + 1, _insert(spec, params, grid, g.poses[k], state.ranges[k], state.valid[k], state.bearings)

    _, grid = jax.lax.while_loop(lambda c: c[0] < count, body, (jnp.asarray(0, jnp.int32), init_grid(spec.grid)))
    grid = jax.tree.map(lambda new, old: jnp.where(state.map_stale, new, old), grid, state.grid)
    return eqx.tree_at(lambda s: (s.grid, s.map_stale), state, (grid, jnp.asarray(False)))


def scan_poses(state: SlamState, out: SlamOutput) -> Float[Array, "s 3"]:
    """Every scan's base pose at the state's node poses: its node's pose composed with the scan's
    odometry offset (NaN before the first node). `out` holds the scans' outputs (leading axis S)."""
    node = jnp.maximum(out.node, 0)
    poses = jax.vmap(_compose)(state.graph.poses[node], out.T_node_scan)
    return jnp.where((out.node >= 0)[:, None], poses, jnp.nan)


def scan_map(
    spec: SlamSpec, params: SlamParams, state: SlamState, out: SlamOutput, ranges: Float[Array, "s b"]
) -> SlamState:
    """The state with its map drawn from every scan, not only the nodes', each at its `scan_poses` pose
    (scans before the first node left out; NaN rays ignored): the scans between nodes see the same walls
    from other places, evidence that a map of the node scans alone leaves out."""
    base = scan_poses(state, out)
    ok = jnp.all(jnp.isfinite(base), axis=1)
    sensor = _sensor(params, jnp.where(ok[:, None], base, 0.0))
    grid = map_from_scans(spec.grid, params.occupancy, sensor, ranges, state.bearings, ok)
    return eqx.tree_at(lambda s: s.grid, state, grid)
