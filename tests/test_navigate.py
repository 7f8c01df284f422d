"""Navigation orchestration: plans on an occupancy map, and the kinematic closed loop with replanning."""

import json
import math

import jax
import jax.numpy as jnp
import numpy as np

from jaxquad import nav
from jaxquad.io.maps import OccupancyMap
from jaxquad.kernels.costmap import INSCRIBED

PARAMS = nav.NavParams.default(n_samples=256, horizon=30, n_path_points=64, path_stride=3, replan_ticks=10)


def _room():
    """5 x 5 m room, origin (-1, -1); an L-shaped wall between start and goal."""
    grid = np.zeros((100, 100), np.int8)
    grid[[0, -1], :] = 100
    grid[:, [0, -1]] = 100
    grid[20:80, 48:52] = 100
    grid[76:80, 20:52] = 100
    return OccupancyMap(grid, 0.05, (-1.0, -1.0, 0.0))


def _grid(occ):
    return nav.cost_grid(PARAMS, jnp.asarray(occ.grid), jnp.asarray(occ.origin[:2]), occ.resolution)


_plan = jax.jit(nav.plan)
_simulate = jax.jit(nav.simulate_kinematic, static_argnums=5)


def test_plan_avoids_obstacles_and_snaps_blocked_goal():
    occ = _room()
    grid = _grid(occ)
    pose = jnp.array([0.0, 2.0, 0.0])
    p = _plan(PARAMS, grid, pose, jnp.array([3.0, 2.0, 0.0]))
    path = np.asarray(p.path)[np.asarray(p.valid)]
    assert bool(p.ok)
    assert np.linalg.norm(path[0] - [0.0, 2.0]) < 0.05 and np.linalg.norm(path[-1] - [3.0, 2.0]) < 0.05
    assert np.all(np.asarray(grid.cost_at(jnp.asarray(path))) < INSCRIBED)
    assert path[:, 1].min() < 0.0  # around the bottom end of the wall (y from 0 to 3 m)
    # A goal on the wall moves to the nearest open cell (within the 0.5 m planner tolerance).
    p = _plan(PARAMS, grid, pose, jnp.array([1.5, 1.5, 0.0]))
    assert bool(p.ok)
    end = np.asarray(p.path)[np.asarray(p.valid)][-1]
    assert 0.2 < np.linalg.norm(end - [1.5, 1.5]) <= 0.5
    # A goal inside a closed box is not reachable.
    occ.grid[5:30, 70:95] = 100
    occ.grid[8:27, 73:92] = 0
    p = _plan(PARAMS, _grid(occ), pose, jnp.array([3.2, 0.3, 0.0]))
    assert not bool(p.ok) and not np.any(np.asarray(p.valid))


def test_closed_loop_reaches_goal_behind_wall():
    grid = _grid(_room())
    start, goal = jnp.array([0.0, 2.0, 0.0]), jnp.array([3.0, 2.5, -math.pi / 2])
    trace = _simulate(PARAMS, grid, start, goal, jax.random.key(0), 40)
    arrived = np.asarray(trace.arrived)
    assert arrived.any()
    pose = np.asarray(trace.pose)
    assert np.all(np.asarray(grid.cost_at(jnp.asarray(pose[:, :2]))) < INSCRIBED)
    assert np.linalg.norm(pose[-1, :2] - np.asarray(goal[:2])) < 0.25
    assert np.all(np.asarray(trace.plan_ok))


def test_bench_section_json(capsys):
    from jaxquad.cli import main

    argv = [
        "bench",
        "--cpu",
        "--json",
        "--nav",
        "--batch",
        "2",
        "--repeats",
        "1",
        "--nav-samples",
        "8",
        "--nav-horizon",
        "4",
        "--nav-grid",
        "100",
        "--nav-plan-batch",
        "2",
    ]
    assert main(argv) == 0
    rows = json.loads(capsys.readouterr().out)["sections"]["nav"]["rows"]
    assert [r["kernel"] for r in rows] == ["mppi_step", "costmap", "plan", "frontier_clusters", "frontier_choice"]
    assert all(r["run_ms"] > 0 and r["batch"] == 2 for r in rows)
    assert rows[2]["ok"] == 2


def test_footprint_of_a_robot_sets_disks_and_inscribed_radius():
    """NavParams from a built-in robot's planform (NumPy, from its MuJoCo model): 3 disks on the long axis and
    the costmap's inscribed radius sqrt(half_width^2 + (half_length / 3)^2)."""
    from jaxquad.nav.missions import footprint
    from jaxquad.robots import load

    center, half = footprint(load("go2"))
    p = nav.NavParams.default(n_samples=8, horizon=4, footprint=(center, half))
    disks = np.asarray(p.controller.footprint_disks)
    np.testing.assert_allclose(disks[:, 0], center[0] + np.array([-2, 0, 2]) * half[0] / 3, atol=1e-6)
    np.testing.assert_allclose(disks[:, 1], center[1], atol=1e-7)
    np.testing.assert_allclose(float(p.costmap.inscribed_radius), math.hypot(half[1], half[0] / 3), rtol=1e-6)
    padded = nav.NavParams.default(n_samples=8, horizon=4, footprint=(center, half), footprint_padding=0.1)
    padded_radius = float(padded.costmap.inscribed_radius)
    np.testing.assert_allclose(padded_radius, math.hypot(half[1], half[0] / 3) + 0.1, rtol=1e-6)
    np.testing.assert_array_equal(padded.controller.footprint_disks, disks)  # the disks' centres do not move
    np.testing.assert_array_equal(padded.controller.footprint_outline, p.controller.footprint_outline)
    # the outline's padding moves its corners out on both axes and its long sides' middles across
    out = nav.NavParams.default(n_samples=8, horizon=4, footprint=(center, half), outline_padding=0.1)
    hx, hy = half[0] + 0.1, half[1] + 0.1
    want = np.array([[hx, hy], [hx, -hy], [-hx, hy], [-hx, -hy], [0.0, hy], [0.0, -hy]]) + center
    np.testing.assert_allclose(np.asarray(out.controller.footprint_outline), want, atol=1e-6)
    assert float(out.costmap.inscribed_radius) == float(p.costmap.inscribed_radius)
