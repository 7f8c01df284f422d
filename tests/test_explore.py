"""Exploration: blacklisting after the timeout, view goals for a frontier out of reach, and a kinematic closed loop
that maps a small two-room world."""

import dataclasses

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from _slot_maps import room_with_slots

from jaxquad import nav
from jaxquad.kernels import mppi
from jaxquad.kernels.view_goals import ViewParams

RES = 0.05
NAV = nav.NavParams.default(n_samples=128, horizon=25, n_path_points=48, path_stride=3, replan_ticks=10)
EXP = nav.ExploreParams.default()
SENSOR_RANGE = 1.5  # m: an ideal disk sensor (no occlusion) reveals the true map around the robot


def _two_rooms():
    """5 x 4 m, a wall with a 0.8 m door in the middle, one box in the right room."""
    grid = np.zeros((80, 100), np.int8)
    grid[[0, -1], :] = 100
    grid[:, [0, -1]] = 100
    grid[:, 49:51] = 100
    grid[30:46, 49:51] = 0
    grid[10:25, 70:80] = 100
    return grid


def _reveal(known, truth, pose):
    h, w = truth.shape
    rr, cc = jnp.meshgrid(jnp.arange(h, dtype=jnp.float32), jnp.arange(w, dtype=jnp.float32), indexing="ij")
    d2 = ((cc + 0.5) * RES - pose[0]) ** 2 + ((rr + 0.5) * RES - pose[1]) ** 2
    return jnp.where(d2 <= SENSOR_RANGE**2, truth, known)


@jax.jit
def _explore_loop(truth, start, key, params=EXP):
    def period(carry, k):
        pose, known, ex, st = carry
        known = _reveal(known, truth, pose)
        grid = nav.cost_grid(NAV, known, jnp.zeros(2), RES)
        ex, _choice = nav.explore.update(params, ex, known, grid, pose, NAV.replan_ticks * NAV.controller.dt)
        st = nav.replan(NAV, st, nav.NavInputs(pose=pose, goal=ex.goal, grid=grid, key=k))

        def tick(c, kk):
            p, s = c
            s, out = nav.step(NAV, s, nav.NavInputs(pose=p, goal=ex.goal, grid=grid, key=kk))
            cmd = jnp.where(ex.done, 0.0, out.cmd)
            return (mppi.rollout(p, cmd[None], NAV.controller.dt)[0], s), p

        (pose, st), poses = jax.lax.scan(tick, (pose, st), jax.random.split(k, NAV.replan_ticks))
        return (pose, known, ex, st), (poses, ex.done, grid.cost_at(poses[:, :2]))

    known0 = jnp.full(truth.shape, -1, jnp.int8)
    carry = (start, known0, nav.explore.init(truth.shape), nav.init(NAV, start))
    (_pose, known, _ex, _), (_poses, done, costs) = jax.lax.scan(period, carry, jax.random.split(key, 120))
    return known, done, costs


def test_explores_two_rooms():
    """It finishes, knows it, never enters an obstacle's inscribed radius; the view goals that follow the frontiers
    (here: bits of the outer walls never within the sensor's range) leave fewer cells unknown than without them."""
    truth = _two_rooms()
    start, key = jnp.array([0.8, 2.0, 0.0]), jax.random.key(0)
    free = truth == 0
    unknown = {}
    for views in (True, False):
        known, done, costs = _explore_loop(jnp.asarray(truth), start, key, nav.ExploreParams.default(view_goals=views))
        known, done = np.asarray(known), np.asarray(done)
        assert np.mean(known[free] >= 0) > 0.9
        assert done[-1]  # it knows it has finished
        assert np.all(np.asarray(costs) < 253)  # never inside the inscribed radius of a known obstacle
        unknown[views] = np.sum(known < 0)
    assert unknown[True] < unknown[False], unknown


def test_goal_without_progress_is_blacklisted_after_timeout():
    truth = _two_rooms()
    known = np.where(np.arange(100)[None, :] < 25, truth, -1).astype(np.int8)  # left part known
    known[38:42, 24:26] = 100  # splits the frontier line at column 25 into two clusters
    grid = nav.cost_grid(NAV, jnp.asarray(known), jnp.zeros(2), RES)
    pose = jnp.array([0.5, 2.0, 0.0])
    update = jax.jit(nav.explore.update)
    ex = nav.explore.init(known.shape)
    goals = []
    for _ in range(5):  # the robot never moves: 10 s per update
        ex, choice = update(EXP, ex, jnp.asarray(known), grid, pose, 10.0)
        assert bool(choice.found)
        goals.append(np.asarray(ex.goal[:2]))
    # Goal chosen at t = 0 s, no progress at 10, 20, 30 s; blacklisted at 40 s (> 30 s): a new goal.
    assert all(np.allclose(g, goals[0]) for g in goals[:4])
    assert np.linalg.norm(goals[4] - goals[0]) > 0.5
    assert bool(np.asarray(ex.blacklist)[tuple(np.asarray(grid.cell_of(jnp.asarray(goals[0]))))])


def test_goal_is_kept_until_reached_then_blacklisted():
    """Two frontier clusters; the robot keeps its goal when the other becomes nearer (a fresh robot at that pose
    picks the other: the negative control), and blacklists it once within reach_radius (its frontier is left)."""
    truth = _two_rooms()
    known = np.where(np.arange(100)[None, :] < 25, truth, -1).astype(np.int8)
    known[38:42, 24:26] = 100  # two clusters on the frontier line x = 1.25 m: lower (y < 1.9 m) and upper
    grid = nav.cost_grid(NAV, jnp.asarray(known), jnp.zeros(2), RES)
    update = jax.jit(nav.explore.update)
    occ = jnp.asarray(known)
    ex, _ = update(EXP, nav.explore.init(known.shape), occ, grid, jnp.array([0.5, 1.0, 0.0]), 1.0)
    lower = np.asarray(ex.goal[:2])
    assert lower[1] < 1.9
    nearer_upper = jnp.array([0.6, 2.3, 0.0])
    fresh, _ = update(EXP, nav.explore.init(known.shape), occ, grid, nearer_upper, 1.0)
    upper = np.asarray(fresh.goal[:2])
    assert upper[1] > 2.1  # a robot without a goal picks the nearest cluster
    ex, _ = update(EXP, ex, occ, grid, nearer_upper, 1.0)
    np.testing.assert_allclose(np.asarray(ex.goal[:2]), lower, atol=0.11)  # committed: the goal stays
    assert not np.asarray(ex.blacklist).any()
    at_goal = jnp.asarray([lower[0] - 0.3, lower[1], 0.0])  # within reach_radius, the frontier still there
    ex, _ = update(EXP, ex, occ, grid, at_goal, 1.0)
    assert bool(np.asarray(ex.blacklist)[tuple(np.asarray(grid.cell_of(jnp.asarray(lower))))])
    np.testing.assert_allclose(np.asarray(ex.goal[:2]), upper, atol=0.11)


def _room_with_slot():
    """4 x 4 m room, all known; in its top wall a slot 0.4 m wide whose inner part is unknown (a frontier 0.4 m
    long, under min_size, in cells the robot cannot reach)."""
    return room_with_slots(80, (36,))


def test_a_slot_out_of_reach_is_looked_into_then_exploration_is_done():
    known = jnp.asarray(_room_with_slot())
    grid = nav.cost_grid(NAV, known, jnp.zeros(2), RES)
    update = jax.jit(nav.explore.update)
    pose = jnp.array([1.0, 1.0, 0.0])
    ex, choice = update(EXP, nav.explore.init(known.shape), known, grid, pose, 1.0)
    assert not bool(choice.found) and bool(ex.has_goal) and bool(ex.viewing) and not bool(ex.done)
    off = nav.ExploreParams.default(view_goals=False)
    ex_off, _ = update(off, nav.explore.init(known.shape), known, grid, pose, 1.0)
    assert bool(ex_off.done) and not bool(ex_off.has_goal)
    # Standing at each goal, turned to it: done with after view_dwell (3 s); the map never changes here, so the
    # slot's 8 frontier cells are looked at until each lies within 0.15 m of one looked at, and then it is done.
    views = 0
    while bool(ex.has_goal):
        assert bool(ex.viewing) and not bool(ex.done) and views < 4
        goal, target = np.asarray(ex.goal), np.asarray(ex.target)
        assert 1.8 <= target[0] <= 2.2 and 3.3 <= target[1] <= 3.35  # the slot's first unknown cells
        assert float(grid.cost_at(jnp.asarray(goal[None, :2]))[0]) < 253  # a cell the robot can stand on
        np.testing.assert_allclose(goal[2], np.arctan2(target[1] - goal[1], target[0] - goal[0]), atol=1e-5)
        for _ in range(3):
            assert not bool(ex.viewed[tuple(np.asarray(grid.cell_of(jnp.asarray(target))))])
            ex, _ = update(EXP, ex, known, grid, jnp.asarray(goal), 1.0)
        assert bool(ex.viewed[tuple(np.asarray(grid.cell_of(jnp.asarray(target))))])
        views += 1
    assert views >= 2 and bool(ex.done) and np.asarray(ex.viewed)[66, 36:44].all()


def test_targets_nothing_sees_are_set_aside_so_a_farther_one_gets_its_view():
    """With one frontier cell scored per period, a walled-off pocket nearer the robot than the slot: the periods find
    no view and set the pocket's cells aside one by one, not done meanwhile, until one looks into the slot."""
    grid = _room_with_slot()
    grid[20:30, 2:12] = 100  # a walled pocket in the room's left corner, unknown inside ...
    grid[22:28, 4:10] = -1
    grid[22:28, 3] = 0  # ... but for free cells along its inner wall: 0.3 m of frontier no reachable cell sees
    known = jnp.asarray(grid)
    costs = nav.cost_grid(NAV, known, jnp.zeros(2), RES)
    one = eqx.tree_at(lambda p: p.view, EXP, ViewParams.default(n_scored=1))
    update = jax.jit(nav.explore.update)
    pose = jnp.array([1.0, 1.0, 0.0])
    ex, periods = nav.explore.init(known.shape), 0
    while periods < 12 and not bool(ex.has_goal):
        assert not bool(ex.done)  # frontier cells are left to score
        ex, _ = update(one, ex, known, costs, pose, 1.0)
        periods += 1
    assert periods == 7 and bool(ex.viewing) and 3.3 <= float(ex.target[1]) <= 3.35  # the pocket's 6 cells, one each
    assert np.asarray(ex.viewed)[22:28, 4].all()
    off = dataclasses.replace(one, view_goals=False)  # the pocket is never set aside without views
    ex_off, _ = update(off, nav.explore.init(known.shape), known, costs, pose, 1.0)
    assert not bool(ex_off.viewed.any()) and bool(ex_off.done)


def _two_slots():
    return room_with_slots(80, (36, 8))  # a second slot in the top wall, at the room's left


def test_a_view_goal_is_kept_as_the_robot_walks_and_one_without_progress_is_set_aside_and_blacklisted():
    known = jnp.asarray(_two_slots())
    grid = nav.cost_grid(NAV, known, jnp.zeros(2), RES)
    update = jax.jit(nav.explore.update)
    ex, _ = update(EXP, nav.explore.init(known.shape), known, grid, jnp.array([2.9, 1.0, 0.0]), 1.0)
    first = np.asarray(ex.target)
    assert bool(ex.viewing) and first[0] > 1.7  # the right slot (x 1.8-2.2 m), nearer
    # Walked over to the left: a fresh robot there looks into the left slot; this one keeps its target.
    left = jnp.array([0.6, 2.0, 0.0])
    fresh, _ = update(EXP, nav.explore.init(known.shape), known, grid, left, 1.0)
    assert float(fresh.target[0]) < 0.8
    ex, _ = update(EXP, ex, known, grid, left, 1.0)
    np.testing.assert_allclose(np.asarray(ex.target), first)
    # Then it stands there 31 s without getting nearer: the target is set aside and its goal blacklisted.
    goal = np.asarray(ex.goal)
    for _ in range(4):
        ex, _ = update(EXP, ex, known, grid, left, 10.0)
    assert bool(ex.viewed[tuple(np.asarray(grid.cell_of(jnp.asarray(first))))])
    assert bool(ex.blacklist[tuple(np.asarray(grid.cell_of(jnp.asarray(goal[:2]))))])
    assert not bool(ex.viewing) or np.linalg.norm(np.asarray(ex.goal[:2]) - goal[:2]) > 0.5
