"""Costmaps from occupancy grids: lethal obstacles, the robot's inscribed radius, exponential inflation.

Cost values follow Nav2's costmap_2d: 254 lethal (an obstacle cell), 253 inscribed (the robot's centre here,
or with a footprint one of its covering disks' centres, would touch an obstacle), 252 *
exp(-cost_scaling_factor * (d - inscribed_radius)) out to `inflation_radius`, 0 beyond, and 255 for unknown
cells that no inflation reaches at 253 or more. d is the Euclidean distance (m) between cell centres, computed
by an exact distance transform. A second layer, `depth`, grades the inscribed zone that the cost leaves flat:
1 - d / inscribed_radius inside the inscribed radius (1 on an obstacle cell, towards 0 at the radius), 0 beyond,
so a controller can tell a pose barely inside a safety padding from one against the obstacle.

Occupancy grids are int8: -1 unknown, 0..100 occupancy (`jaxquad.io.OccupancyMap.grid`); a cell is an
obstacle at `occupied_thresh` and above (65, the map_server's 0.65).
"""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
from jaxtyping import Array, Bool, Float, Int

FREE, INSCRIBED, LETHAL, UNKNOWN = 0, 253, 254, 255
# Distance reported where a grid has no obstacle at all (cells); larger than any grid side.
_NO_OBSTACLE = 1e6


class CostmapParams(eqx.Module):
    """Inflation numbers (traced leaves, m unless named otherwise)."""

    inscribed_radius: Float[Array, ""]  # half the robot's width, or its covering disks' radius: closer cells are 253
    inflation_radius: Float[Array, ""]  # cost falls to 0 beyond this distance from an obstacle
    cost_scaling_factor: Float[Array, ""]  # 1/m, exponential decay rate of the inflation
    occupied_thresh: Float[Array, ""]  # occupancy (0..100) at and above which a cell is an obstacle

    @classmethod
    def default(cls, **overrides: float) -> CostmapParams:
        # 0.7 m inflation (the paper); the authors' public configuration inflates 0.3 m.
        values = {
            "inscribed_radius": 0.2,
            "inflation_radius": 0.7,
            "cost_scaling_factor": 3.0,
            "occupied_thresh": 65.0,
        }
        values.update(overrides)
        return cls(**{k: jnp.asarray(v, jnp.float32) for k, v in values.items()})


def _distance_along_axis0(obstacle: Bool[Array, "H W"]) -> Float[Array, "H W"]:
    """Distance (cells) to the nearest obstacle in the same column, by a forward and a backward cummax."""
    h = obstacle.shape[0]
    i = jnp.arange(h, dtype=jnp.float32)[:, None]
    last = jax.lax.cummax(jnp.where(obstacle, i, -_NO_OBSTACLE), axis=0)
    nxt = -jax.lax.cummax(jnp.where(obstacle, -i, -_NO_OBSTACLE)[::-1], axis=0)[::-1]
    return jnp.minimum(i - last, nxt - i)


def distance_transform(obstacle: Bool[Array, "H W"]) -> Float[Array, "H W"]:
    """Exact Euclidean distance (cells) from every cell centre to the nearest obstacle cell centre.

    Separable (Saito-Toriwaki): the per-column distance g, then d^2(i, j) = min_k g(i, k)^2 + (j - k)^2
    by a brute-force minimum over each row (O(H W^2), fully parallel; one row at a time in memory).
    Cells of a grid without obstacles get 1e6.
    """
    g2 = jnp.minimum(_distance_along_axis0(obstacle), _NO_OBSTACLE) ** 2
    w = obstacle.shape[1]
    k = jnp.arange(w, dtype=jnp.float32)
    dk2 = (k[:, None] - k[None, :]) ** 2  # (j, k)

    def row(g2_row):
        return jnp.min(g2_row[None, :] + dk2, axis=1)

    d2 = jax.lax.map(row, g2, batch_size=min(64, obstacle.shape[0]))
    return jnp.minimum(jnp.sqrt(d2), _NO_OBSTACLE)


def inflation_cost(distance: Float[Array, "*S"], params: CostmapParams) -> Float[Array, "*S"]:
    """Nav2's inflation formula for a distance (m) from the nearest obstacle (0 at the obstacle)."""
    decay = (INSCRIBED - 1) * jnp.exp(-params.cost_scaling_factor * (distance - params.inscribed_radius))
    cost = jnp.where(distance <= params.inflation_radius, decay, 0.0)
    cost = jnp.where(distance <= params.inscribed_radius, float(INSCRIBED), cost)
    return jnp.where(distance <= 0.0, float(LETHAL), cost)


def inscribed_depth(distance: Float[Array, "*S"], params: CostmapParams) -> Float[Array, "*S"]:
    """How far inside the inscribed radius a distance (m) from the nearest obstacle lies, as a fraction of the
    radius: 1 - distance / inscribed_radius, clipped to 0..1."""
    return jnp.clip(1.0 - distance / jnp.maximum(params.inscribed_radius, 1e-6), 0.0, 1.0)  # radius 0: obstacles 1


def costmap_layers(
    grid: Int[Array, "H W"], resolution: float | Float[Array, ""], params: CostmapParams
) -> tuple[Float[Array, "H W"], Float[Array, "H W"]]:
    """(cost, depth) of an occupancy grid (-1 unknown, 0..100): the cost grid (0..255 as float32) and each
    cell's depth inside the inscribed radius (0..1), both from one distance transform (see module doc)."""
    grid = jnp.asarray(grid, jnp.int32)
    obstacle = grid.astype(jnp.float32) >= params.occupied_thresh
    distance = distance_transform(obstacle) * resolution
    cost = inflation_cost(distance, params)
    # As Nav2 without inflate_unknown: unknown stays unknown unless inflation makes it (at least) inscribed.
    return jnp.where((grid < 0) & (cost < INSCRIBED), float(UNKNOWN), cost), inscribed_depth(distance, params)


def costmap_from_occupancy(
    grid: Int[Array, "H W"], resolution: float | Float[Array, ""], params: CostmapParams
) -> Float[Array, "H W"]:
    """Cost grid (0..255 as float32, see module doc) from an occupancy grid (-1 unknown, 0..100)."""
    return costmap_layers(grid, resolution, params)[0]


class CostGrid(eqx.Module):
    """A cost grid placed in the world: row-major from the lower-left cell (row = y, column = x), yaw 0."""

    cost: Float[Array, "H W"]  # 0..255, see the module doc
    origin: Float[Array, " 2"]  # world x, y (m) of the lower-left corner of cell (0, 0)
    resolution: Float[Array, ""]  # m per cell
    depth: Float[Array, "H W"] | None = None  # 0..1 inside the inscribed radius (module doc); None: not graded

    def cell_of(self, xy: Float[Array, "*S 2"]) -> Int[Array, "*S 2"]:
        """(row, col) of the cell holding each world point (may lie outside the grid)."""
        return jnp.floor((xy[..., ::-1] - self.origin[::-1]) / self.resolution).astype(jnp.int32)

    def center_of(self, rc: Int[Array, "*S 2"]) -> Float[Array, "*S 2"]:
        """World x, y (m) of cell centres."""
        return self.origin + (rc[..., ::-1].astype(jnp.float32) + 0.5) * self.resolution

    def lookup(
        self, layer: Float[Array, "H W"], xy: Float[Array, "*S 2"], outside: float | Float[Array, ""]
    ) -> Float[Array, "*S"]:
        """`layer` (on this grid's cells) at the cell under each world point; `outside` off the grid."""
        rc = self.cell_of(xy)
        h, w = layer.shape
        inside = (rc[..., 0] >= 0) & (rc[..., 0] < h) & (rc[..., 1] >= 0) & (rc[..., 1] < w)
        value = layer[jnp.clip(rc[..., 0], 0, h - 1), jnp.clip(rc[..., 1], 0, w - 1)]
        return jnp.where(inside, value, outside)

    def cost_at(self, xy: Float[Array, "*S 2"]) -> Float[Array, "*S"]:
        """Cost of the cell under each world point; lethal outside the grid."""
        return self.lookup(self.cost, xy, float(LETHAL))

    def depth_at(self, xy: Float[Array, "*S 2"]) -> Float[Array, "*S"]:
        """Depth inside the inscribed radius of the cell under each world point: 1 outside the grid (as on an
        obstacle), 0 everywhere on a grid without a depth layer."""
        if self.depth is None:
            return jnp.zeros(xy.shape[:-1], jnp.float32)
        return self.lookup(self.depth, xy, 1.0)
