"""Likelihood-field laser model on an occupancy grid (the beam model of AMCL's `likelihood_field`).

A map is turned once, outside jit, into a `LikelihoodField`: the Euclidean distance (m) from every
cell to the nearest occupied cell, clipped at `max_dist`, plus the centres of the free cells (where
random particles are drawn). Inside jit a beam end point is looked up in that table by its cell;
end points off the map read `max_dist`, as in AMCL.

Per particle the scan's weight is AMCL's heuristic p = 1 + sum_k pz_k^3 over the valid beams, with
pz = z_hit exp(-d^2 / (2 sigma_hit^2)) + z_rand / range_max and d the distance of beam k's end point
to the nearest obstacle. The cube (rather than a product over beams) keeps one bad beam from
zeroing a particle; it is what AMCL ships.
"""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float, Int

__all__ = ["LikelihoodField", "distance_at", "likelihood_field", "sample_free_poses", "scan_likelihood"]

# Occupancy (0..100) above which a cell is an obstacle: the map format's occupied_thresh 0.65.
_OCCUPIED = 65


class LikelihoodField(eqx.Module):
    """Distance table of one map (row 0 = bottom, +y upward; the map's yaw is 0)."""

    dist: Float[Array, "rows cols"]  # m to the nearest occupied cell, clipped at max_dist
    origin: Float[Array, "2"]  # world x y (m) of the lower-left corner of cell (0, 0)
    resolution: Float[Array, ""]  # m per cell
    max_dist: Float[Array, ""]  # m, the clip and the value off the map
    free_xy: Float[Array, "C 2"]  # world x y (m) of every free cell centre, first; padded to one row per cell
    n_free: Int[Array, ""]  # free cells (rows of free_xy in use): the shape depends on the grid's alone


def likelihood_field(
    grid: np.ndarray, resolution: float, origin_xy: tuple[float, float], max_dist: float = 2.0, surfaces: bool = False
) -> LikelihoodField:
    """Build the field of a grid (int, -1 unknown, 0..100 occupancy) with NumPy/scipy (not jittable).

    surfaces: measure distances to the occupied cells that border a non-occupied cell only. A map whose
    obstacles are filled (a ground-truth map) otherwise reads 0 all through an obstacle, so a beam that
    overshoots a surface into it scores better than one that falls as short: with noisy ranges the
    likelihood's peak moves towards the obstacles the sensor faces. A map built from scans has only
    surfaces occupied, and this changes nothing there."""
    from scipy.ndimage import distance_transform_edt

    grid = np.asarray(grid)
    if grid.ndim != 2 or grid.size == 0:
        raise ValueError(f"occupancy grid must be a non-empty 2-D array, got shape {grid.shape}")
    if not (np.isfinite(max_dist) and max_dist > 0):
        raise ValueError(f"likelihood max distance must be positive, got {max_dist}")
    occupied = grid > _OCCUPIED
    if surfaces:
        p = np.pad(occupied, 1, constant_values=False)
        occupied = occupied & ~(p[:-2, 1:-1] & p[2:, 1:-1] & p[1:-1, :-2] & p[1:-1, 2:])
    dist = distance_transform_edt(~occupied) * resolution if occupied.any() else np.full(grid.shape, max_dist)
    free = (grid >= 0) & (grid <= 100 - _OCCUPIED)  # known and clearly free (occupancy < 0.35)
    if not free.any():
        raise ValueError("occupancy grid has no free cell to place particles in")
    rows, cols = np.nonzero(free)
    free_xy = np.zeros((grid.size, 2))
    free_xy[: rows.size] = np.stack(
        [origin_xy[0] + (cols + 0.5) * resolution, origin_xy[1] + (rows + 0.5) * resolution], 1
    )
    leaves = {
        "dist": np.minimum(dist, max_dist),
        "origin": origin_xy,
        "resolution": resolution,
        "max_dist": max_dist,
        "free_xy": free_xy,
    }
    return LikelihoodField(
        **{k: jnp.asarray(v, jnp.float32) for k, v in leaves.items()}, n_free=jnp.asarray(rows.size, jnp.int32)
    )


def distance_at(field: LikelihoodField, xy: Float[Array, "*N 2"]) -> Float[Array, "*N"]:
    """Distance (m) to the nearest obstacle of the cell holding each world point; max_dist off the map."""
    rows, cols = field.dist.shape
    ij = jnp.floor((xy - field.origin) / field.resolution)
    col, row = ij[..., 0], ij[..., 1]
    inside = (col >= 0) & (col < cols) & (row >= 0) & (row < rows)
    flat = jnp.where(inside, row * cols + col, 0).astype(jnp.int32)
    return jnp.where(inside, field.dist.reshape(-1)[flat], field.max_dist)


def scan_likelihood(
    field: LikelihoodField,
    poses: Float[Array, "P 3"],
    T_base_laser: Float[Array, "3"],
    ranges: Float[Array, "B"],
    bearings: Float[Array, "B"],
    z_hit: Float[Array, ""],
    z_rand: Float[Array, ""],
    sigma_hit: Float[Array, ""],
    range_min: Float[Array, ""],
    range_max: Float[Array, ""],
) -> Float[Array, "P"]:
    """AMCL's likelihood-field weight p = 1 + sum pz^3 of one scan for every particle pose (x, y, theta).

    T_base_laser is the laser's (x, y, yaw) in the base frame. Beams outside [range_min, range_max)
    or not finite carry no information and are skipped, as AMCL skips max-range readings."""
    valid = jnp.isfinite(ranges) & (ranges >= range_min) & (ranges < range_max)
    r = jnp.where(valid, ranges, 0.0)
    a = T_base_laser[2] + bearings
    # Beam end points in the base frame (B, 2), then in the world for every particle (P, B, 2).
    end_base = T_base_laser[:2] + r[:, None] * jnp.stack([jnp.cos(a), jnp.sin(a)], -1)
    c, s = jnp.cos(poses[:, 2:3]), jnp.sin(poses[:, 2:3])
    x = poses[:, 0:1] + c * end_base[:, 0] - s * end_base[:, 1]
    y = poses[:, 1:2] + s * end_base[:, 0] + c * end_base[:, 1]
    d = distance_at(field, jnp.stack([x, y], -1))
    pz = z_hit * jnp.exp(-0.5 * (d / sigma_hit) ** 2) + z_rand / range_max
    return 1.0 + jnp.sum(jnp.where(valid, pz**3, 0.0), axis=-1)


def sample_free_poses(field: LikelihoodField, key: Array, n: int) -> Float[Array, "n 3"]:
    """n poses uniform over the free cells (uniform inside each cell) with uniform heading."""
    k_cell, k_jit, k_theta = jax.random.split(key, 3)
    idx = jax.random.randint(k_cell, (n,), 0, field.n_free)
    xy = field.free_xy[idx] + field.resolution * jax.random.uniform(k_jit, (n, 2), minval=-0.5, maxval=0.5)
    theta = jax.random.uniform(k_theta, (n,), minval=-jnp.pi, maxval=jnp.pi)
    return jnp.concatenate([xy, theta[:, None]], -1)
