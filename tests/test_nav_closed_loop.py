"""The closed navigation loop: its pieces against independent references (descent on goal stacks against
scipy's Dijkstra, the surface likelihood field against a brute-force loop, drawn missions against their
rules), and a small closed-loop CPU run in the MJX simulator: one robot reaches two short goals, another
starts with its footprint in a wall and ends collided."""

from __future__ import annotations

import json

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy.sparse import csgraph
from test_planner import _reference_graph

from jaxquad import nav, robots
from jaxquad.io.jsonfile import to_json
from jaxquad.io.maps import OccupancyMap
from jaxquad.kernels.likelihood_field import likelihood_field
from jaxquad.kernels.planner import descend
from jaxquad.nav import closed_loop as cl
from jaxquad.nav import missions
from jaxquad.sim.worlds import box_signed_distance, make_world, occupancy_map

PARAMS = nav.NavParams.default(n_samples=64, horizon=10, n_path_points=64, path_stride=2)
_descend = jax.jit(descend, static_argnames=("n_points", "stride"))


def _room() -> OccupancyMap:
    grid = np.zeros((60, 80), np.int8)
    grid[[0, -1], :] = 100
    grid[:, [0, -1]] = 100
    grid[10:50, 38:42] = 100  # a wall with gaps at both ends
    grid[25:35, 10:20] = 100  # a filled block
    return OccupancyMap(grid, 0.05, (0.0, 0.0, 0.0))


def test_goal_table_descent_is_shortest_and_equals_plan():
    occ = _room()
    grid = nav.cost_grid(PARAMS, jnp.asarray(occ.grid), jnp.asarray(occ.origin[:2]), occ.resolution)
    goals = jnp.array([[3.5, 1.5, 0.0], [0.5, 2.5, 1.0], [3.0, 2.6, -2.0]])
    table = jax.jit(nav.goal_table)(PARAMS, grid, goals)
    pose = jnp.array([0.4, 0.4, 0.0])
    weight = np.asarray(table.weight)
    graph = _reference_graph(weight)
    for k in range(goals.shape[0]):
        got = jax.jit(nav.plan_to)(PARAMS, grid, table, jnp.asarray(k), pose)
        ref = jax.jit(nav.plan)(PARAMS, grid, pose, goals[k])
        np.testing.assert_array_equal(np.asarray(got.path), np.asarray(ref.path))
        np.testing.assert_array_equal(np.asarray(got.valid), np.asarray(ref.valid))
        assert bool(got.ok) == bool(ref.ok) == True  # noqa: E712
        # The stack's layer k holds Dijkstra's distances to goal k's cell, and its descent from any cell
        # costs exactly that distance.
        g = np.asarray(table.goal_rc[k])
        dist = csgraph.dijkstra(graph, indices=g[0] * weight.shape[1] + g[1]).reshape(weight.shape)
        finite = np.isfinite(weight)
        np.testing.assert_allclose(np.asarray(table.value[k])[finite], dist[finite], rtol=1e-5)
        start = np.array([40, 5])
        cells, valid, complete = _descend(table.value, table.weight, jnp.asarray(start), 200, 1, jnp.asarray(k))
        cells = np.asarray(cells)[np.asarray(valid)]
        steps = np.diff(cells, axis=0)
        cost = sum(np.hypot(*d) * 0.5 * (weight[tuple(a)] + weight[tuple(a + d)]) for a, d in zip(cells[:-1], steps))
        assert bool(complete) and np.allclose(cost, dist[tuple(start)], rtol=1e-4)


def test_surface_field_equals_brute_force():
    grid = np.zeros((24, 30), np.int8)
    grid[5:15, 8:20] = 100  # filled block
    grid[0, :] = 100  # a wall along the map edge
    grid[20:22, 2:5] = -1
    field = likelihood_field(grid, 0.1, (0.0, 0.0), max_dist=0.8, surfaces=True)
    occ = grid > 65
    rows, cols = grid.shape
    surface = []
    for r in range(rows):
        for c in range(cols):
            nb = [(r + dr, c + dc) for dr, dc in ((1, 0), (-1, 0), (0, 1), (0, -1))]
            outside_or_free = [not (0 <= a < rows and 0 <= b < cols) or not occ[a, b] for a, b in nb]
            if occ[r, c] and any(outside_or_free):
                surface.append((r, c))
    surface = np.array(surface)
    rr, cc = np.mgrid[:rows, :cols]
    d = np.min(np.hypot(rr[..., None] - surface[:, 0], cc[..., None] - surface[:, 1]), axis=-1) * 0.1
    np.testing.assert_allclose(np.asarray(field.dist), np.minimum(d, 0.8), atol=1e-6)
    assert float(field.dist[10, 14]) > 0.3  # deep inside the block: far from its surface


def test_missions_keep_clearance_and_separation():
    world = make_world("house", 3)
    occ = occupancy_map(world)
    weight = np.where(occ.grid == 0, 1.0, np.inf)
    open_cells = missions.reachable_cells(weight)
    rng = np.random.default_rng(0)
    pool = missions.draw_poses(rng, occ, open_cells, world, 40, 0.5)
    starts = missions.draw_poses(rng, occ, open_cells, world, 6, 0.5)
    assert np.all(box_signed_distance(world, pool[:, :2]) >= 0.5 - 0.05)  # cell centre + jitter of half a cell
    rc = occ.world_to_cell(pool[:, :2])
    assert open_cells[rc[:, 0], rc[:, 1]].all()
    ids = missions.missions(rng, pool, starts, 5, 1.5)
    legs = np.concatenate([starts[:, None, :2], pool[ids][..., :2]], 1)
    assert np.all(np.linalg.norm(np.diff(legs, axis=1), axis=-1) >= 1.5)


def test_resample_map_copies_cells_by_position():
    rng = np.random.default_rng(1)
    source = OccupancyMap(rng.integers(-1, 101, (30, 40)).astype(np.int8), 0.05, (1.0, -0.5, 0.0))
    like = OccupancyMap(np.zeros((50, 30), np.int8), 0.05, (0.52, -0.13, 0.0))  # offset by 9.6 x 7.4 cells
    got = missions.resample_map(source, like)
    assert got.grid.shape == like.grid.shape and got.origin == like.origin
    for r, c in [(0, 0), (10, 12), (25, 29), (49, 5), (37, 20)]:
        x, y = 0.52 + (c + 0.5) * 0.05, -0.13 + (r + 0.5) * 0.05
        i, j = int(np.floor((y + 0.5) / 0.05)), int(np.floor((x - 1.0) / 0.05))
        expected = source.grid[i, j] if 0 <= i < 30 and 0 <= j < 40 else -1
        assert got.grid[r, c] == expected, (r, c)


def test_footprint_holds_trunk_and_feet():
    for name in ("go2", "badger"):
        robot = robots.load(name)
        center, half = missions.footprint(robot)
        from jaxquad.sim import Gait

        feet = np.asarray(Gait.for_robot(robot).p_base_foot_home)[:, :2]
        assert np.all(np.abs(feet - center) <= half)
        assert 0.2 < half[0] < 0.4 and 0.1 < half[1] < 0.25  # a quadruped's planform, legs included


@pytest.fixture(scope="module")
def run():
    """Two Go2s in the house (seed 0): robot 0 walks to two goals about a metre apart, robot 1 starts with
    its footprint across a wall."""
    from jaxquad.nav.fleet import NavConfig, navigate

    cfg = NavConfig(
        n_robots=2, n_goals=2, particles=200, samples=96, horizon=16, style="calm", chunk_ticks=50, trace_robots=2
    )
    world = make_world("house", 0)
    wall = np.argmax(world.half[:4, 0])  # the first wall along x (y = 0)
    starts = np.array([[2.0, 2.0, 0.0], [3.0, float(world.center[wall, 1]) + 0.15, 0.0]])
    goals = np.array([[3.1, 2.3, 0.6], [2.3, 2.9, 2.5]])
    return navigate(cfg, goals=goals, starts=starts, progress=None)


@pytest.mark.slow
def test_closed_loop_reaches_goals_and_flags_collisions(run, tmp_path):
    from jaxquad.nav.report import plot_paths, summarize

    assert [cl.OUTCOMES[o] for o in run.outcome[0]] == ["reached", "reached"]
    assert [cl.OUTCOMES[o] for o in run.outcome[1]] == ["collided", "skipped"]
    # Arrival is the navigation stack's own judgement; the truth must agree within the loop's errors.
    assert np.all(run.end_error[0, :, 0] < 0.5) and np.all(run.end_error[0, :, 1] < 0.4)
    assert np.all(run.elapsed[0] < 60.0) and run.elapsed[1, 0] < 0.5
    err = run.loc_error[run.active[:, 0], 0]
    assert np.median(err) < 0.2
    # The robot moved only on the navigation stack's commands: its path runs from the start to both goals.
    path = run.true_pose[run.active[:, 0], 0, :2]
    assert np.linalg.norm(path[0] - run.starts[0, :2]) < 0.05
    summary = summarize(run)
    assert summary["success_rate"] == 0.5 and summary["outcomes"]["collided"] == 1
    assert summary["outcomes"]["skipped"] == 1 and summary["goals"] == 4
    assert json.loads(to_json(summary))["localization_error_m"]["n"] > 0  # strict JSON
    plot_paths(run, tmp_path / "paths.png")
    assert (tmp_path / "paths.png").stat().st_size > 10_000


@pytest.mark.slow
def test_slam_map_lies_on_the_world():
    """A short mapping walk: the SLAM map comes on the true map's cells, and what it marks occupied lies on
    the world's boxes (map scores within one cell)."""
    from jaxquad.metrics import map_scores
    from jaxquad.nav.fleet import NavConfig

    cfg = NavConfig(map="slam", map_walk_seconds=6.0, style="calm", seed=4)
    world = make_world("house", 4000)
    occ = missions.slam_map(cfg, world)
    truth = occupancy_map(world)
    assert occ.grid.shape == truth.grid.shape and occ.origin == truth.origin
    scores = map_scores(occ, truth)
    assert scores.n_estimated_occupied > 50 and scores.precision > 0.6
