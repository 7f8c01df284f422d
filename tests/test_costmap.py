"""Costmap: exact distance transform against scipy, inflation against Nav2's formula written out per cell."""

import math

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy import ndimage

from jaxquad.kernels.costmap import (
    INSCRIBED,
    LETHAL,
    UNKNOWN,
    CostGrid,
    CostmapParams,
    costmap_from_occupancy,
    costmap_layers,
    distance_transform,
)

_edt = jax.jit(distance_transform)
_costmap = jax.jit(costmap_from_occupancy)


@pytest.mark.parametrize(
    "seed, shape, density",
    [(0, (40, 40), 0.02), (1, (57, 83), 0.1), (2, (100, 64), 0.005)],
)
def test_distance_transform_matches_scipy(seed, shape, density):
    rng = np.random.default_rng(seed)
    obstacle = rng.random(shape) < density
    obstacle[rng.integers(shape[0]), rng.integers(shape[1])] = True
    expected = ndimage.distance_transform_edt(~obstacle)
    np.testing.assert_allclose(np.asarray(_edt(jnp.asarray(obstacle))), expected, rtol=1e-6, atol=1e-5)


def test_distance_transform_without_obstacles_is_large():
    assert np.all(np.asarray(_edt(jnp.zeros((20, 30), bool))) >= 1e5)


def _nav2_cost(d, p):
    """Nav2 costmap_2d's computeCost, one cell at a time."""
    if d == 0.0:
        return LETHAL
    if d <= p["inscribed"]:
        return INSCRIBED
    if d > p["inflation"]:
        return 0.0
    return (INSCRIBED - 1) * math.exp(-p["scale"] * (d - p["inscribed"]))


def test_costmap_matches_loop_reference():
    rng = np.random.default_rng(3)
    res = 0.05
    grid = np.zeros((48, 60), np.int8)
    grid[rng.random(grid.shape) < 0.01] = 100
    grid[10:14, 5:40] = 80
    grid[30:, 45:] = -1
    grid[rng.random(grid.shape) < 0.02] = 30  # below the occupied threshold: free
    p = {"inscribed": 0.2, "inflation": 0.7, "scale": 3.0}
    params = CostmapParams.default()
    cost = np.asarray(_costmap(jnp.asarray(grid), res, params))
    d = ndimage.distance_transform_edt(grid < 65) * res
    for (r, c), v in np.ndenumerate(grid):
        want = _nav2_cost(d[r, c], p)
        if v < 0 and want < INSCRIBED:
            want = UNKNOWN
        assert cost[r, c] == pytest.approx(want, rel=1e-5, abs=1e-4), (r, c)


def test_depth_layer_grades_the_inscribed_zone():
    """The depth layer against scipy's distance transform: 1 - d / inscribed radius inside the radius (1 on an
    obstacle), 0 beyond it and on unknown cells no inflation reaches; the cost layer is costmap_from_occupancy's.
    A grid with the layer reads 1 off it; a grid without the layer reads 0 everywhere."""
    rng = np.random.default_rng(5)
    res, radius = 0.05, 0.3
    grid = np.zeros((40, 52), np.int8)
    grid[rng.random(grid.shape) < 0.01] = 100
    grid[20:23, 4:30] = 90
    grid[:8, 40:] = -1
    params = CostmapParams.default(inscribed_radius=radius)
    cost, depth = (np.asarray(a) for a in jax.jit(costmap_layers)(jnp.asarray(grid), res, params))
    np.testing.assert_array_equal(cost, np.asarray(_costmap(jnp.asarray(grid), res, params)))
    d = ndimage.distance_transform_edt(grid < 65) * res
    np.testing.assert_allclose(depth, np.clip(1.0 - d / radius, 0.0, 1.0), atol=1e-6)
    assert (depth == 1.0).sum() == (grid >= 65).sum() and ((depth > 0) & (depth < 1)).sum() > 100
    np.testing.assert_array_equal(depth > 0, (cost >= INSCRIBED) & (cost != UNKNOWN) & (d < radius))
    graded = CostGrid(jnp.asarray(cost), jnp.array([-1.0, 2.0]), jnp.float32(res), jnp.asarray(depth))
    flat = CostGrid(jnp.asarray(cost), jnp.array([-1.0, 2.0]), jnp.float32(res))
    xy = np.c_[rng.uniform(-1.5, 2.0, 200), rng.uniform(1.5, 4.5, 200)].astype(np.float32)
    rc = np.floor((xy[:, ::-1] - [2.0, -1.0]) / res).astype(int)
    inside = (rc >= 0).all(1) & (rc < grid.shape).all(1)
    want = np.where(inside, depth[np.clip(rc[:, 0], 0, 39), np.clip(rc[:, 1], 0, 51)], 1.0)
    assert inside.sum() > 50 and (~inside).sum() > 50
    np.testing.assert_array_equal(np.asarray(graded.depth_at(jnp.asarray(xy))), want)
    np.testing.assert_array_equal(np.asarray(flat.depth_at(jnp.asarray(xy))), 0.0)


def test_costmap_vmaps_over_robots_with_traced_params():
    grid = np.zeros((40, 40), np.int8)
    grid[20, 20] = 100
    params = jax.tree.map(lambda x: jnp.stack([x, x]), CostmapParams.default())
    params = eqx.tree_at(lambda p: p.inflation_radius, params, jnp.array([0.3, 0.7]))
    cost = jax.jit(jax.vmap(costmap_from_occupancy, in_axes=(None, None, 0)))(jnp.asarray(grid), 0.05, params)
    # 0.5 m from the obstacle: beyond 0.3 m inflation, inside 0.7 m.
    assert float(cost[0, 20, 30]) == 0.0
    assert float(cost[1, 20, 30]) == pytest.approx(252 * math.exp(-3.0 * 0.3), rel=1e-5)
