"""Exploration in the closed loop: its pieces against independent references (the plan read off the robot's
own cost-to-go against scipy's Dijkstra, map values against the log-odds formula, coverage against a count,
coverage sampling against a loop), and a small CPU exploration in the MJX simulator whose coverage grows."""

from __future__ import annotations

import dataclasses
import json
import math
from types import SimpleNamespace

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy.sparse import csgraph
from test_nav_closed_loop import _room
from test_planner import _reference_graph

from jaxquad import nav
from jaxquad.explore.loop import MODES, OUTCOMES, coverage
from jaxquad.explore.report import coverage_samples
from jaxquad.io.jsonfile import to_json
from jaxquad.kernels.occupancy import OccupancyGrid, occupancy_values
from jaxquad.metrics import narrow_gaps

PARAMS = nav.NavParams.default(n_samples=32, horizon=8, n_path_points=200, path_stride=1)
EXPLORE = nav.ExploreParams.default()
_robot_value = jax.jit(nav.explore.robot_value)
_plan_from_start = jax.jit(nav.navigate.plan_from_start)


@pytest.fixture(scope="module")
def room():
    occ = _room()
    grid = nav.cost_grid(PARAMS, jnp.asarray(occ.grid), jnp.asarray(occ.origin[:2]), occ.resolution)
    pose = jnp.array([0.4, 0.4, 0.3])
    weight, value = _robot_value(EXPLORE, grid, pose)
    return grid, pose, np.asarray(weight), value


def test_plan_from_start_runs_the_shortest_path_from_robot_to_goal(room):
    grid, pose, weight, value = room
    start = np.asarray(grid.cell_of(pose[:2]))
    graph = _reference_graph(weight)
    dist = csgraph.dijkstra(graph, indices=start[0] * weight.shape[1] + start[1]).reshape(weight.shape)
    finite = np.isfinite(weight)
    np.testing.assert_allclose(np.asarray(value)[finite], dist[finite], rtol=1e-5)
    for goal in ([50, 70], [20, 60], [45, 10]):  # behind the wall, beside the block, above it
        plan = _plan_from_start(PARAMS, grid, jnp.asarray(weight), value, jnp.asarray(goal, jnp.int32), pose)
        assert bool(plan.ok)
        path = np.asarray(plan.path)[np.asarray(plan.valid)]
        cells = np.floor((path - np.asarray(grid.origin)) / float(grid.resolution)).astype(int)[:, ::-1]
        np.testing.assert_array_equal(cells[0], start)  # from the robot ...
        np.testing.assert_array_equal(cells[-1], goal)  # ... to the goal
        steps = np.diff(cells, axis=0)
        assert np.all(np.abs(steps).max(axis=1) == 1)  # 8-connected, one cell per point
        cost = sum(np.hypot(*d) * 0.5 * (weight[tuple(a)] + weight[tuple(a + d)]) for a, d in zip(cells[:-1], steps))
        np.testing.assert_allclose(cost, dist[tuple(goal)], rtol=1e-4)


def test_plan_from_start_to_a_blocked_goal_is_not_ok(room):
    grid, pose, weight, value = room
    plan = _plan_from_start(PARAMS, grid, jnp.asarray(weight), value, jnp.asarray([30, 15], jnp.int32), pose)
    assert not bool(plan.ok) and not np.asarray(plan.valid).any()  # inside the filled block


def test_occupancy_values_follow_the_log_odds_formula():
    rng = np.random.default_rng(0)
    log_odds = rng.uniform(-3.0, 4.0, (40, 50)).astype(np.float32)
    observed = rng.random((40, 50)) < 0.7
    got = np.asarray(jax.jit(occupancy_values)(OccupancyGrid(jnp.asarray(log_odds), jnp.asarray(observed))))
    p = 100.0 / (1.0 + np.exp(-log_odds.astype(np.float64)))
    expected = np.where(observed, np.rint(p), -1)
    clear = np.abs(p - np.floor(p) - 0.5) > 1e-3  # float32 may round the other way at a tie
    assert got.dtype == np.int8 and np.array_equal(got[clear], expected[clear])
    assert np.abs(got.astype(int) - expected).max() <= 1


def test_coverage_counts_known_free_reachable_cells():
    rng = np.random.default_rng(1)
    values = rng.integers(-1, 101, (30, 40)).astype(np.int8)
    reachable = rng.random((30, 40)) < 0.6
    expected = sum(1 for v, r in zip(values.ravel(), reachable.ravel()) if r and 0 <= v < 20) / reachable.sum()
    got = float(jax.jit(coverage)(jnp.asarray(values), jnp.asarray(reachable)))
    assert got == pytest.approx(expected, rel=1e-6)


def test_uncovered_cells_by_what_the_map_calls_them():
    from jaxquad.explore.report import uncovered

    maps = np.array([[[-1, 10, 19, 20], [65, 66, 100, -1]], [[0, 0, 0, 0], [0, 0, 0, 0]]], np.int8)
    reachable = np.array([[True, True, True, True], [True, True, True, False]])
    clear = np.array([[False, True, True, False], [True, True, True, True]])
    got = uncovered(maps, reachable, clear)
    # Robot 0, 7 reachable cells: unknown (0,0); free 10 and 19; uncertain 20 and 65; occupied 66 and 100; the
    # unreachable unknown (1,3) is not counted; (0,0) and (0,3) lie on box faces.
    np.testing.assert_allclose(got["unknown"], [1 / 7, 0])
    np.testing.assert_allclose(got["uncertain"], [2 / 7, 0])
    np.testing.assert_allclose(got["occupied"], [2 / 7, 0])
    np.testing.assert_allclose(got["on_box_faces"], [2 / 7, 0])
    np.testing.assert_allclose(1 - got["unknown"] - got["uncertain"] - got["occupied"], [
        float(coverage(jnp.asarray(m), jnp.asarray(reachable))) for m in maps
    ], rtol=1e-6)  # fmt: skip


def test_coverage_samples_hold_the_last_tick_at_or_before_each_time():
    t = np.arange(1, 101) * 0.096  # ticks end 0.096 s apart; the run stopped at 9.6 s of 12 s
    cov = np.stack([np.sqrt(t / 10), t / 10], 1)
    result = SimpleNamespace(config=SimpleNamespace(seconds=12.0), t=t, coverage=cov)
    times, got = coverage_samples(result, every=2.5)
    np.testing.assert_allclose(times, [0.0, 2.5, 5.0, 7.5, 10.0])
    for s, ts in enumerate(times):
        k = max([i for i in range(len(t)) if t[i] <= ts + 1e-9], default=0)
        np.testing.assert_array_equal(got[s], cov[k])


def test_without_a_goal_the_robot_turns_or_holds_where_its_wait_began():
    """Clear turn: the look-around turn. Blocked: a wait, holding the pose of its first tick by body-frame
    velocity hold_gain x error (scaled as a whole into the limits) and yaw rate hold_gain x yaw error."""
    from jaxquad.explore.loop import idle_command
    from jaxquad.kernels.mppi import MppiParams

    params = (MppiParams.default(hold_gain=2.0), jnp.float32(0.6))
    pose, start = jnp.array([1.0, 2.0, 0.5]), jnp.array([0.95, 2.1, 0.4])
    cmd, held = idle_command(*params, pose, jnp.array(True), jnp.array(True), start)
    np.testing.assert_allclose(cmd, [0.0, 0.0, 0.6])  # a clear turn wins over a wait going on
    np.testing.assert_allclose(held, start)
    cmd, held = idle_command(*params, pose, jnp.array(False), jnp.array(False), start)  # the wait's first tick
    np.testing.assert_allclose(held, pose)
    np.testing.assert_allclose(cmd, 0.0, atol=1e-7)
    jumped = jnp.array([1.3, 2.0, 0.5])  # the SLAM pose 0.3 m off: a new hold point there, no walk back
    cmd, held = idle_command(*params, jumped, jnp.array(False), jnp.array(True), pose)
    np.testing.assert_allclose(held, jumped)
    np.testing.assert_allclose(cmd, 0.0, atol=1e-7)
    cmd, _ = idle_command(*params, jnp.array([jnp.nan, 2.0, 0.5]), jnp.array(False), jnp.array(True), pose)
    np.testing.assert_array_equal(cmd, 0.0)
    for drifted in ([1.02, 1.99, 0.52], [1.0, 1.86, 0.5]):  # a small drift, and one beyond the speed limits
        cmd, held = idle_command(*params, jnp.array(drifted), jnp.array(False), jnp.array(True), pose)
        np.testing.assert_allclose(held, pose)
        c, s = math.cos(drifted[2]), math.sin(drifted[2])
        err = np.array(pose[:2]) - drifted[:2]
        v = 2.0 * np.array([c * err[0] + s * err[1], -s * err[0] + c * err[1]])
        v *= min(1.0, *(np.where(v >= 0, [0.26, 0.15], [0.15, 0.15]) / np.abs(v)))
        np.testing.assert_allclose(cmd, [*v, np.clip(2.0 * (0.5 - drifted[2]), -0.8, 0.8)], atol=1e-6)


def test_a_run_ends_in_the_mode_of_its_last_command():
    """The mode of the tick before the last active one (its command moved the robot on the last tick)."""
    from jaxquad.explore.report import _last_modes

    active = np.array([[1, 1, 0], [1, 1, 0], [1, 0, 0], [1, 0, 0]], bool)  # ended after 4, 2 and 0 ticks
    mode = np.array([[0, 4, 6], [1, 3, 6], [2, 6, 6], [5, 6, 6]], np.int8)
    result = SimpleNamespace(active=np.c_[active, active[:, :1]], mode=mode)  # a fourth robot, not traced
    np.testing.assert_array_equal(_last_modes(result), [2, 4, -1])


@pytest.fixture(scope="module")
def run():
    """One Go2 explores the house (seed 0) for 48 s from its drawn start."""
    from jaxquad.explore import ExploreConfig, explore

    cfg = ExploreConfig(n_robots=1, seconds=48.0, samples=64, horizon=20, chunk_ticks=50, trace_robots=1)
    return explore(cfg)


@pytest.mark.slow
def test_small_exploration_grows_its_map(run, tmp_path):
    from jaxquad.explore.report import plot_coverage, plot_maps, summarize

    assert OUTCOMES[run.outcome[0]] == "running" and np.isnan(run.end_t[0])  # no collision, fall or loss
    times, cov = coverage_samples(run, 6.0)
    assert cov[0, 0] < 0.1 and cov[-1, 0] > 0.35  # the map grew from nothing to over a third of the house
    assert np.all(np.diff(cov[1:, 0]) > -0.02)  # and, after the first scans settled, kept growing
    assert run.distance[0] > 2.0
    gaps = narrow_gaps(run.truth)  # the house's gaps behind furniture: not counted as reachable
    assert gaps.any() and run.reachable.any() and not (run.reachable & gaps).any()
    err = run.error[run.active[:, 0], 0]
    assert np.median(err) < 0.15
    summary = summarize(run, every=6.0)
    assert json.loads(to_json(summary))["coverage"]["per_robot"][0] > 0.35  # the final map (after `finish`)
    assert summary["per_robot"][0]["map_scores"]["precision"] > 0.3
    assert summary["coverage_over_time"]["t_s"] == times.tolist()
    left = summary["per_robot"][0]["uncovered"]  # the reachable cells not free: a partition of 1 - coverage
    assert left["unknown"] + left["uncertain"] + left["occupied"] == pytest.approx(1 - summary["coverage"]["mean"])
    assert left["unknown"] > 0.3 and 0 < left["on_box_faces"] < 1 - summary["coverage"]["mean"]
    control = summary["per_robot"][0]["control_s"]  # every active tick in one mode
    assert sum(control.values()) == pytest.approx(run.active[:, 0].sum() * 0.096, rel=1e-4)
    assert control["mppi"] > 10.0 and summary["per_robot"][0]["mode_at_end"] in MODES
    chunks = summary["timing"]["chunk_s"]  # 48 s in chunks of 4.8 s, each timed
    assert len(chunks) == 10 and min(chunks) > 0
    plot_maps(run, tmp_path / "maps.png")
    plot_coverage(run, tmp_path / "coverage.png", 6.0)
    assert (tmp_path / "maps.png").stat().st_size > 10_000 and (tmp_path / "coverage.png").stat().st_size > 5_000


@pytest.mark.slow
def test_a_paused_run_goes_on_to_the_same_result(run, tmp_path):
    """The fixture's run again, paused after its first chunk and after its second (each in a fresh `explore`
    call, as a new process would), then finished: every output equals the run without pauses."""
    from jaxquad.explore import explore
    from jaxquad.explore.checkpoint import Paused

    cfg, path = run.config, tmp_path / "run.npz"
    for done_s in (4.8, 9.6):
        with pytest.raises(Paused) as e:
            explore(cfg, checkpoint=path, wall_budget_s=1e-9)  # at least one chunk a sitting
        assert e.value.sim_s == done_s and path.exists()
    with pytest.raises(ValueError, match="other settings"):  # another run's file, refused before any work
        explore(dataclasses.replace(cfg, samples=32), checkpoint=path)
    seen = []
    again = explore(cfg, checkpoint=path, progress=lambda done, total: seen.append(done))
    assert seen[0] == 9.6 and seen[-1] == 48.0
    names = ("t", "coverage", "error", "active", "true_pose", "pose", "goal", "mode", "outcome", "end_t", "distance")
    for name in (*names, "maps"):
        np.testing.assert_array_equal(getattr(again, name), getattr(run, name), err_msg=name)
    assert again.nodes[0] == run.nodes[0] and again.loops[0] == run.loops[0]
    assert len(again.chunk_s) == 10  # the chunks of every sitting


@pytest.mark.slow
def test_cli_pauses_with_status_75_and_goes_on(run, tmp_path, capsys):
    """`jaxquad explore` with the fixture's settings: paused after a chunk (status 75, nothing written but the
    checkpoint), then finished from it with the unpaused run's coverage; the checkpoint is removed once the
    outputs are written."""
    from jaxquad.cli import main
    from jaxquad.explore.report import summarize

    ckpt, out = tmp_path / "run.npz", tmp_path / "out"
    args = ["explore", "--robots", "1", "--seconds", "48", "--samples", "64", "--horizon", "20", "--plot-robots", "1"]
    args += ["--out", str(out), "--checkpoint", str(ckpt)]
    assert main([*args, "--wall-budget", "1e-9"]) == 75
    assert ckpt.exists() and not out.exists() and "paused at 4.8 of 48.0" in capsys.readouterr().err
    assert main(args) == 0
    assert not ckpt.exists() and (out / "maps.png").exists()
    got = json.loads((out / "summary.json").read_text())["coverage"]["per_robot"]
    assert got == json.loads(to_json(summarize(run, 5.0)))["coverage"]["per_robot"]


@pytest.mark.slow
def test_experiment_keeps_a_cell_that_finishes_in_one_sitting(run, tmp_path, monkeypatch, capsys):
    """experiments/exploration.py with `--checkpoint` naming a folder that does not exist yet, its exploration the
    fixture's run (explore replaced, no second simulation): the cell finishes in its first sitting and its row is
    kept in the folder (made before any work); run again, the script reads the kept row and explores nothing."""
    import sys

    from _experiments import load

    import jaxquad.explore

    script = load("exploration")
    calls = []
    monkeypatch.setattr(jaxquad.explore, "explore", lambda cfg, **kw: calls.append(cfg) or run)
    cells = tmp_path / "new" / "cells"
    argv = ["exploration.py", "--runs", "1", "--robots", "go2", "--worlds", "house", "--variants", "full"]
    argv += ["--seconds", "48", "--samples", "64", "--horizon", "20", "--every", "6", "--checkpoint", str(cells)]
    monkeypatch.setattr(sys, "argv", [*argv, "--wall-budget", "1e6"])
    assert script.main() == 0
    row = json.loads(capsys.readouterr().out)[0]
    assert len(calls) == 1 and calls[0].seconds == 48.0 and calls[0].n_robots == 1
    assert json.loads((cells / "go2_house_full.json").read_text())["row"] == row
    monkeypatch.setattr(sys, "argv", argv)
    assert script.main() == 0
    out = capsys.readouterr()
    assert len(calls) == 1 and "finished earlier" in out.err and json.loads(out.out)[0] == row


def test_near_obstacle_limit_where_an_obstacle_or_the_unknown_is_within_the_inflation_radius():
    """The forward limit drops to the near-obstacle speed exactly where the robot's cell centre lies within the
    costmap's inflation radius of an obstacle cell's centre (a brute-force NumPy distance) or is unknown; the other
    limits stay."""
    from jaxquad.explore.loop import near_obstacle_limit

    occ = _room()
    occupancy = occ.grid.copy()
    occupancy[50:, 60:] = -1  # an unknown corner
    grid = nav.cost_grid(PARAMS, jnp.asarray(occupancy), jnp.asarray(occ.origin[:2]), occ.resolution)
    limit = jax.jit(jax.vmap(near_obstacle_limit, in_axes=(None, None, None, 0)))
    rng = np.random.default_rng(0)
    xy = rng.uniform([0.0, 0.0], [80 * 0.05, 60 * 0.05], size=(400, 2))
    poses = jnp.asarray(np.c_[xy, rng.uniform(-3, 3, 400)], jnp.float32)
    got = limit(PARAMS.controller, jnp.float32(0.2), grid, poses).v_max
    rc = np.floor(xy[:, ::-1] / 0.05).astype(int)
    centre = (rc[:, ::-1] + 0.5) * 0.05
    obstacle = np.argwhere(occupancy >= 65)[:, ::-1]  # (col, row)
    d = np.min(np.linalg.norm(centre[:, None] - (obstacle[None] + 0.5) * 0.05, axis=-1), axis=1)
    radius = float(PARAMS.costmap.inflation_radius)
    near = (d < radius) | (occupancy[rc[:, 0], rc[:, 1]] < 0)
    clear = np.abs(d - radius) > 0.03  # cells on the radius itself are left out
    fast = float(PARAMS.controller.v_max[0])
    np.testing.assert_allclose(np.asarray(got[clear, 0]), np.where(near[clear], 0.2, fast))
    np.testing.assert_allclose(np.asarray(got[:, 1:]), np.broadcast_to(PARAMS.controller.v_max[1:], (400, 2)))
    assert near[clear].any() and (~near[clear]).any()


def test_speed_limit_and_frontier_gain_reach_the_loop():
    """`max_speed` is MPPI's forward limit (the others kept: the paper's DWB limits), `frontier_gain` the frontier
    cost's weight of a cluster's size and `outline_padding` the controller's outline, in the closed loop's
    parameters."""
    from jaxquad.explore import ExploreConfig
    from jaxquad.explore.fleet import _params
    from jaxquad.sim import FleetConfig, build_fleet
    from jaxquad.sim.worlds import occupancy_map

    fleet = build_fleet(FleetConfig(robot="go2", world="house", n_robots=1), compile_chunk=False)
    truth = occupancy_map(fleet.worlds[0])
    for cfg, v_max, gain in (
        (ExploreConfig(n_robots=1), [0.26, 0.15, 0.8], 0.0),
        (ExploreConfig(n_robots=1, max_speed=0.5, frontier_gain=0.25), [0.5, 0.15, 0.8], 0.25),
    ):
        p = _params(cfg, cfg.loop_config(), fleet, truth, 0.096)
        np.testing.assert_allclose(p.nav.controller.v_max, v_max, rtol=1e-6)
        assert float(p.explore.frontier.gain_scale) == pytest.approx(gain)
        assert float(p.near_obstacle_speed) == pytest.approx(v_max[0])  # None: the limit everywhere
    cfg = ExploreConfig(n_robots=1, max_speed=0.5, near_obstacle_speed=0.26)
    assert float(_params(cfg, cfg.loop_config(), fleet, truth, 0.096).near_obstacle_speed) == pytest.approx(0.26)
    outlines = [
        np.asarray(_params(c, c.loop_config(), fleet, truth, 0.096).nav.controller.footprint_outline)
        for c in (ExploreConfig(n_robots=1), ExploreConfig(n_robots=1, outline_padding=0.1))
    ]
    corners = np.array([[1.0, 1.0], [1.0, -1.0], [-1.0, 1.0], [-1.0, -1.0]])  # footprint_outline's order
    np.testing.assert_allclose(outlines[1][:4] - outlines[0][:4], 0.1 * corners, atol=1e-6)  # out on both axes
    with pytest.raises(ValueError, match="outline_padding"):
        ExploreConfig(outline_padding=-0.1)
    with pytest.raises(ValueError, match="max_speed"):
        ExploreConfig(max_speed=0.0)
    with pytest.raises(ValueError, match="frontier_gain"):
        ExploreConfig(frontier_gain=-1.0)
    with pytest.raises(ValueError, match="near_obstacle_speed"):
        ExploreConfig(near_obstacle_speed=0.0)
    with pytest.raises(ValueError, match="max_speed"):
        ExploreConfig(max_speed=float("inf"))


def test_clear_cells_are_the_reachable_squares_no_box_touches():
    """Against a supersampled reference (11 x 11 points per cell inside a box or not, for the cells whose centre is
    within a cell diagonal of a box) on a generated house; cells a box only grazes (within 6 mm) may go either way."""
    from jaxquad.explore.fleet import clear_cells
    from jaxquad.nav import missions
    from jaxquad.sim.worlds import box_signed_distance, make_world, occupancy_map

    world = make_world("house", 3)
    truth = occupancy_map(world)
    reachable = missions.reachable_cells(np.where(truth.grid == 0, 1.0, np.inf))
    got = clear_cells(world, truth, reachable)
    centres = truth.cell_centers()
    sd = box_signed_distance(world, centres)
    near = np.abs(sd) < truth.resolution  # farther cells lie wholly inside or outside
    u = (np.arange(11) / 10 - 0.5) * truth.resolution
    sub = centres[near][:, None, None, :] + np.stack(np.meshgrid(u, u, indexing="ij"), -1)  # (n, 11, 11, 2)
    sd[near] = box_signed_distance(world, sub).min(axis=(1, 2))
    want = reachable & (sd > 0)
    sure = np.abs(sd) > 0.006
    np.testing.assert_array_equal(got[sure], want[sure])
    assert 0 < (reachable & ~got).sum() < 0.15 * reachable.sum()  # a band along every face, not the whole house


@pytest.mark.slow
def test_revisits_drive_back_to_where_the_robot_was(run, monkeypatch):
    """The fixture's run again with active loop closing after 2 s without a closure, to nodes 10 s old or more (the
    defaults, 60 s, do not fit a 48 s run): revisits begin, each goal is a pose the robot's SLAM path passed through
    at least 10 s before (node poses move only by loop closures, centimetres here), and the robot heads for it."""
    from jaxquad.explore import explore
    from jaxquad.explore.report import summarize
    from jaxquad.nav import revisit

    default = revisit.RevisitParams.default
    monkeypatch.setattr(revisit.RevisitParams, "default", lambda **kw: default(**kw, min_age=10.0))
    again = explore(dataclasses.replace(run.config, revisit_after=2.0))
    assert run.revisits[0] == 0 and not run.revisiting.any()
    on = again.revisiting[:, 0] & again.active[:, 0]
    starts = np.flatnonzero(on & ~np.r_[False, on[:-1]])
    assert len(starts) >= 1 and again.revisits[0] == len(starts)  # the state's count against the traced ticks
    for k in np.flatnonzero(on):
        earlier = again.pose[: k + 1, 0][again.t[: k + 1] <= again.t[k] - 10.0]
        assert np.min(np.linalg.norm(earlier[:, :2] - again.goal[k, 0, :2], axis=1)) < 0.1
    for k in starts:  # each revisit brings the robot nearer its goal
        end = k + np.argmin(on[k:]) - 1 if not on[k:].all() else len(on) - 1
        gap = [np.linalg.norm(again.pose[j, 0, :2] - again.goal[k, 0, :2]) for j in (k, end)]
        assert gap[1] < gap[0] or gap[1] < 0.5
    per_robot = summarize(again, 6.0)["per_robot"][0]
    assert per_robot["revisit_s"] == pytest.approx(on.sum() * 0.096, rel=1e-4)
    # Every accepted loop closure shows on its tick (none in 48 s here): the per-tick flags add up to the SLAM's own
    # count, and each flagged tick holds its candidate's chi-square, within the consistency test's bound.
    closed = again.loop_closed[:, 0]
    limit = again.config.slam_values()["loop_consistency_chi2"]
    assert closed.sum() == again.loops[0]
    assert np.all(again.loop_chi2[closed, 0] <= limit) and np.isfinite(again.loop_chi2[:, 0]).sum() >= closed.sum()
    assert not again.loop_closed[~again.active[:, 0], 0].any()


def _rectangle_distance(center, half, yaw, xy):
    """Signed distance (m) from points (P, 2) to a rotated rectangle, an independent NumPy form."""
    c, s = np.cos(yaw), np.sin(yaw)
    d = xy - center
    q = np.abs(np.stack([c * d[:, 0] + s * d[:, 1], -s * d[:, 0] + c * d[:, 1]], 1)) - half
    return np.linalg.norm(np.maximum(q, 0), axis=1) + np.minimum(q.max(1), 0)


@pytest.mark.slow
def test_low_obstacles_mark_a_box_lower_than_the_camera():
    """A Go2 started 1.8 m from the warehouse's lowest box (a pallet under the camera's scan plane), facing it, for
    14.4 s with the low-obstacle layer on: the SLAM map holds none of the pallet (its scans pass over it), the layer
    marks its face, and every cell the layer marks lies on or beside a true box."""
    from jaxquad.explore import ExploreConfig, explore
    from jaxquad.sim.worlds import box_signed_distance, make_world

    world = make_world("warehouse", 0)
    k = int(np.argmin(world.half[:, 2]))
    center, half, yaw = world.center[k, :2], world.half[k, :2], world.yaw[k]
    assert 2 * world.half[k, 2] < 0.3  # under the Go2's camera, about 0.32 m above the floor
    for a in np.linspace(0, 2 * np.pi, 32, endpoint=False):  # a clear start 1.8 m from its centre, facing it
        xy = center + 1.8 * np.array([np.cos(a), np.sin(a)])
        if box_signed_distance(world, xy[None])[0] > 0.75:
            break
    start = np.array([[xy[0], xy[1], a + np.pi]])
    cfg = ExploreConfig(world="warehouse", n_robots=1, seconds=14.4, samples=64, horizon=20, trace_robots=1,
                        low_obstacles=True)  # fmt: skip
    result = explore(cfg, starts=start)
    cells = result.truth.cell_centers().reshape(-1, 2)
    on_pallet = _rectangle_distance(center, half, yaw, cells) <= 0.05
    assert not (result.maps[0].reshape(-1)[on_pallet] > 65).any()
    marked = result.low[0].reshape(-1)
    assert (marked & (_rectangle_distance(center, half, yaw, cells) <= 0.15)).sum() >= 5
    assert np.all(box_signed_distance(world, cells[marked]) <= 0.25)
