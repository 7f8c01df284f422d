"""MPPI: the kinematic rollout against an Euler loop; closed loops in the kinematic model around an obstacle."""

import math

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxquad.kernels import mppi
from jaxquad.kernels.costmap import (
    INSCRIBED,
    CostGrid,
    CostmapParams,
    costmap_from_occupancy,
    costmap_layers,
)
from jaxquad.kernels.footprint import footprint_disks, footprint_overlaps
from jaxquad.kernels.planner import cost_to_go, descend, step_weights
from jaxquad.kernels.raycast import Boxes

RES = 0.05
PARAMS = mppi.MppiParams.default(n_samples=256, horizon=30)


def _room() -> np.ndarray:
    """4 x 4 m room with walls, a 1 m block in the middle between start and goal (occupancy)."""
    grid = np.zeros((80, 80), np.int8)
    grid[[0, -1], :] = 100
    grid[:, [0, -1]] = 100
    grid[25:55, 35:45] = 100
    return grid


def _world(inscribed_radius: float = 0.2):
    """The room's cost grid, with its depth layer."""
    params = CostmapParams.default(inscribed_radius=inscribed_radius)
    cost, depth = costmap_layers(jnp.asarray(_room()), RES, params)
    return CostGrid(cost=cost, origin=jnp.zeros(2), resolution=jnp.asarray(RES), depth=depth)


def _plan(grid: CostGrid, start, goal):
    weight = step_weights(grid.cost, 3.0)
    g = grid.cell_of(jnp.asarray(goal[:2]))
    value = cost_to_go(weight, jnp.zeros(weight.shape, bool).at[g[0], g[1]].set(True))
    cells, valid, complete = descend(value, weight, grid.cell_of(jnp.asarray(start[:2])), n_points=96, stride=2)
    return grid.center_of(cells), valid, complete


@eqx.filter_jit
def _closed_loop(grid, start, goal, key, params=PARAMS, drift=None):
    """300 ticks of the kinematic model, with `drift` (world-frame x, y (m/s), yaw rate) added whatever the
    command: a trotting gait that creeps."""
    path, valid, _ = _plan(grid, start, goal)
    drift = jnp.zeros(3) if drift is None else drift

    def tick(carry, k):
        pose, state = carry
        inputs = mppi.MppiInputs(pose=pose, path=path, path_valid=valid, goal=goal, grid=grid, key=k)
        state, out = mppi.step(params, state, inputs)
        pose = mppi.rollout(pose, out.cmd[None], params.dt)[0] + drift * params.dt
        return (pose, state), (pose, out.arrived, out.cmd)

    keys = jax.random.split(key, 300)
    _, (poses, arrived, cmds) = jax.lax.scan(tick, (start, mppi.init(params, start)), keys)
    return poses, arrived, cmds


def test_rollout_matches_euler_loop():
    rng = np.random.default_rng(0)
    pose = np.array([0.3, -1.0, 2.5])
    u = rng.normal(size=(20, 3))
    got = np.asarray(
        mppi.rollout(
            jnp.asarray(pose, jnp.float32),
            jnp.asarray(u, jnp.float32),
            jnp.float32(0.1),
        )
    )
    x, y, th = pose
    for t in range(20):
        vx, vy, wz = u[t]
        x += (math.cos(th) * vx - math.sin(th) * vy) * 0.1
        y += (math.sin(th) * vx + math.cos(th) * vy) * 0.1
        th += wz * 0.1
        np.testing.assert_allclose(got[t], [x, y, th], atol=1e-5)


@pytest.mark.parametrize("seed", [0, 1])
def test_reaches_goal_around_obstacle_without_touching_it(seed):
    grid = _world()
    start = jnp.array([0.6, 2.0, 0.0])
    goal = jnp.array([3.4, 2.1, math.pi / 2])
    poses, arrived, cmds = _closed_loop(grid, start, goal, jax.random.key(seed))
    poses, arrived, cmds = np.asarray(poses), np.asarray(arrived), np.asarray(cmds)
    assert arrived.any(), poses[-1]
    first = int(np.argmax(arrived))
    # It kept closing the position error while turning to the goal yaw: well inside the 0.25 m tolerance.
    assert np.linalg.norm(poses[first - 1, :2] - np.asarray(goal[:2])) < 0.125
    assert abs((poses[first - 1, 2] - math.pi / 2 + math.pi) % (2 * math.pi) - math.pi) < 0.25
    assert np.all(np.asarray(grid.cost_at(jnp.asarray(poses[:, :2]))) < INSCRIBED)
    lo, hi = np.asarray(PARAMS.v_min), np.asarray(PARAMS.v_max)
    assert np.all(cmds >= lo - 1e-6) and np.all(cmds <= hi + 1e-6)
    assert np.all(cmds[first:] == 0.0)  # it stays put once there


def _l_corridor(inscribed_radius: float):
    """A 0.7 m wide corridor turning left by 90 degrees in a solid 4 x 4 m block: its cost grid and its
    obstacle cells as boxes (for the exact footprint judge)."""
    occ = np.full((80, 80), 100, np.int8)
    occ[10:24, 6:66] = 0  # y 0.5-1.2, x 0.3-3.3
    occ[10:74, 52:66] = 0  # x 2.6-3.3, y 0.5-3.7
    cost = costmap_from_occupancy(jnp.asarray(occ), RES, CostmapParams.default(inscribed_radius=inscribed_radius))
    rc = np.argwhere(occ >= 65)
    boxes = Boxes(
        center=jnp.asarray(np.c_[(rc[:, ::-1] + 0.5) * RES, np.full(len(rc), 0.5)], jnp.float32),
        half=jnp.tile(jnp.array([RES / 2, RES / 2, 0.5]), (len(rc), 1)),
        yaw=jnp.zeros(len(rc)),
    )
    return CostGrid(cost=cost, origin=jnp.zeros(2), resolution=jnp.asarray(RES)), boxes


def test_rectangular_robot_keeps_its_whole_footprint_clear():
    """A Go2-sized planform (0.63 x 0.34 m, centred 0.08 m behind the base) round a corridor's corner: with its
    covering disks checked the rectangle never touches a wall; checked at the base alone (a 0.2 m disk) it
    does in some runs."""
    center, half = jnp.array([-0.076, 0.0]), jnp.array([0.315, 0.17])
    disks, radius = footprint_disks(center, half)
    with_disks = eqx.tree_at(lambda p: p.footprint_disks, PARAMS, disks)
    start, goal = jnp.array([0.75, 0.85, 0.0]), jnp.array([2.95, 3.2, math.pi / 2])
    hits = {}
    for name, params, r in (("disks", with_disks, float(radius)), ("point", PARAMS, 0.2)):
        grid, boxes = _l_corridor(r)
        hits[name] = []
        for seed in range(3):
            poses, arrived, _ = _closed_loop(grid, start, goal, jax.random.key(seed), params)
            assert np.asarray(arrived).any(), (name, seed)
            hits[name].append(int(np.asarray(_touches(boxes, poses, center, half)).sum()))
    assert hits["disks"] == [0, 0, 0] and max(hits["point"]) > 0, hits


@jax.jit
def _touches(boxes, poses, center, half):
    """Whether the rectangle (centre `center`, base frame) at each base pose overlaps a box."""

    def one(p):
        c, s = jnp.cos(p[2]), jnp.sin(p[2])
        rect = p.at[:2].add(jnp.array([[c, -s], [s, c]]) @ center)
        return jnp.any(footprint_overlaps(boxes, rect, half))

    return jax.vmap(one)(poses)


def _stuck_run(grid, pose, n, disks=((0.0, 0.0),)):
    params = mppi.MppiParams.default(
        n_samples=64, horizon=10, progress_timeout=1.0, recovery_time=0.5, footprint_disks=disks
    )
    path = jnp.broadcast_to(jnp.array([3.4, 3.4]), (8, 2))

    def tick(state, k):  # the robot never moves, whatever it is told
        inputs = mppi.MppiInputs(
            pose=pose, path=path, path_valid=jnp.ones(8, bool), goal=jnp.array([3.4, 3.4, 0.0]), grid=grid, key=k
        )
        state, out = mppi.step(params, state, inputs)
        return state, (out.recovering, out.cmd)

    return jax.lax.scan(tick, mppi.init(params, pose), jax.random.split(jax.random.key(0), n))[1]


def test_stuck_robot_backs_up_or_turns():
    grid = _world()
    rec, cmd = jax.jit(_stuck_run, static_argnums=2)(grid, jnp.array([2.0, 0.6, 0.0]), 20)
    rec, cmd = np.asarray(rec), np.asarray(cmd)
    # No progress for 1 s (ten ticks of 0.1 s, to float rounding) -> 0.5 s of backing up, then MPPI again.
    first = int(np.argmax(rec))
    assert first in (9, 10) and rec[first : first + 5].all() and not rec[first + 5 :].any()
    np.testing.assert_allclose(cmd[first : first + 5], np.tile([-0.1, 0.0, 0.0], (5, 1)), atol=1e-7)
    # Facing away from a wall 0.2 m behind: no room to back up, so it turns in place.
    rec, cmd = jax.jit(_stuck_run, static_argnums=2)(grid, jnp.array([0.25, 2.0, 0.0]), 13)
    np.testing.assert_allclose(np.asarray(cmd)[11], [0.0, 0.0, 0.5], atol=1e-7)


def test_backup_checks_the_footprint():
    """A Go2-sized robot facing away from a wall: its rear disk (0.29 m behind the base, radius 0.2 m) decides
    whether the 0.05 m backup (and 0.1 m more) stays clear, where the base point alone would back up."""
    disks, radius = footprint_disks(jnp.array([-0.076, 0.0]), jnp.array([0.315, 0.17]))
    grid = _world(float(radius))
    run = jax.jit(_stuck_run, static_argnums=2)
    # Base 0.7 m from the wall's cell centres: rear disk centre 0.41 m, 0.26 m after the checked 0.15 m.
    cmd = np.asarray(run(grid, jnp.array([0.725, 2.0, 0.0]), 13, disks)[1])
    np.testing.assert_allclose(cmd[11], [-0.1, 0.0, 0.0], atol=1e-7)
    # 0.55 m: the rear disk would come within 0.11 m of the wall: it turns instead; the base alone backs up.
    cmd = np.asarray(run(grid, jnp.array([0.575, 2.0, 0.0]), 13, disks)[1])
    np.testing.assert_allclose(cmd[11], [0.0, 0.0, 0.5], atol=1e-7)
    cmd = np.asarray(run(grid, jnp.array([0.575, 2.0, 0.0]), 13)[1])
    np.testing.assert_allclose(cmd[11], [-0.1, 0.0, 0.0], atol=1e-7)
    # The same 0.575 m from the wall behind, 0.3 m from the wall beside: turning to face along that wall's normal
    # would swing the rear disk (0.29 m behind the base) into it. Neither backing up nor turning is safe: it waits.
    from jaxquad.kernels.critics import footprint_cost, turn_is_clear

    corner = jnp.array([0.575, 0.3, 0.0])
    assert float(footprint_cost(corner[None, None], grid, disks).max()) < INSCRIBED
    assert not bool(turn_is_clear(corner, grid, disks))
    rec, cmd = (np.asarray(a) for a in run(grid, corner, 13, disks))
    assert rec[11] and np.all(cmd[11] == 0.0), cmd[11]


def test_a_robot_that_creeps_holds_where_it_arrived():
    """A gait creeping 3 cm/s backwards (world -x) once arrived: the hold step (gain k = 2/s) pulls it back to the
    pose where it arrived, up to the steady offset v / k = 1.5 cm of the discrete loop e <- e (1 - k dt) + v dt;
    with the gain at 0 it creeps on until the goal tolerance (0.25 m) sends it back."""
    grid = _world()
    start, goal = jnp.array([0.6, 2.0, 0.0]), jnp.array([3.4, 2.1, math.pi / 2])
    drift = jnp.array([-0.03, 0.0, 0.0])
    for gain, far in ((2.0, False), (0.0, True)):
        params = eqx.tree_at(lambda p: p.hold_gain, PARAMS, jnp.float32(gain))
        poses, arrived, _ = _closed_loop(grid, start, goal, jax.random.key(0), params, drift)
        poses, arrived = np.asarray(poses), np.asarray(arrived)
        first = int(np.argmax(arrived))
        assert arrived.any() and first < 250, first
        there = poses[first - 1]  # the pose its first standing tick saw
        off = np.linalg.norm(poses[first:, :2] - there[:2], axis=1)
        if far:
            assert off.max() > 0.1, off.max()  # creeping on, to the goal tolerance's edge
        else:
            assert np.all(off < 0.016), off.max()
            np.testing.assert_allclose(off[-1], 0.015, atol=1e-3)


def test_a_recovery_that_stands_holds_its_pose():
    """The corner of the test above, where the stuck robot may neither back up nor turn: once its pose moves
    (a creep of 2 cm), the command walks it back to where the recovery began (toward_pose with the hold gain)."""
    disks, radius = footprint_disks(jnp.array([-0.076, 0.0]), jnp.array([0.315, 0.17]))
    grid = _world(float(radius))
    params = mppi.MppiParams.default(
        n_samples=64, horizon=10, progress_timeout=1.0, recovery_time=2.0, footprint_disks=disks
    )
    corner = jnp.array([0.575, 0.3, 0.0])
    poses = jnp.concatenate([jnp.tile(corner, (12, 1)), jnp.tile(corner + jnp.array([0.02, -0.01, 0.05]), (3, 1))])

    def tick(state, xs):
        pose, k = xs
        inputs = mppi.MppiInputs(pose, jnp.tile(jnp.array([3.4, 3.4]), (8, 1)), jnp.ones(8, bool),
                                 jnp.array([3.4, 3.4, 0.0]), grid, k)  # fmt: skip
        state, out = mppi.step(params, state, inputs)
        return state, (out.recovering, out.cmd)

    rec, cmd = jax.jit(
        lambda: jax.lax.scan(tick, mppi.init(params, corner), (poses, jax.random.split(jax.random.key(0), 15)))[1]
    )()
    rec, cmd = np.asarray(rec), np.asarray(cmd)
    assert rec[11:].all() and np.all(cmd[11] == 0.0), (rec, cmd[11])
    want = mppi.toward_pose(params, poses[12], corner, params.hold_gain, params.hold_gain)
    np.testing.assert_allclose(cmd[12:], np.tile(np.asarray(want), (3, 1)), atol=1e-6)
    assert cmd[12, 0] < 0 and cmd[12, 2] < 0  # back towards the corner, and turning back


@pytest.mark.parametrize("yaw", [0.0, 0.7, -2.5])
def test_goal_phase_closes_position_error_towards_the_goal(yaw):
    """Inside the goal tolerance: yaw rate k_yaw * error, and a planar velocity k_xy * (goal - pose) in the
    body frame, scaled as a whole into the limits (its world direction points at the goal)."""
    grid = _world()
    pose = jnp.array([2.0, 0.6, yaw])
    for offset in (np.array([0.05, -0.03]), np.array([-0.2, 0.12])):
        goal = jnp.array([2.0 + offset[0], 0.6 + offset[1], yaw + 1.0])
        inputs = mppi.MppiInputs(pose, jnp.zeros((8, 2)), jnp.zeros(8, bool), goal, grid, jax.random.key(0))
        _, out = jax.jit(mppi.step)(PARAMS, mppi.init(PARAMS, pose), inputs)
        cmd = np.asarray(out.cmd)
        c, s = math.cos(yaw), math.sin(yaw)
        v_world = np.array([c * cmd[0] - s * cmd[1], s * cmd[0] + c * cmd[1]])
        want = 0.8 * offset
        v_body = np.array([c * want[0] + s * want[1], -s * want[0] + c * want[1]])
        hi, lo = np.asarray(PARAMS.v_max[:2]), -np.asarray(PARAMS.v_min[:2])
        scale = min(1.0, *(np.where(v_body >= 0, hi, lo) / np.abs(v_body)))
        np.testing.assert_allclose(v_world, scale * want, atol=1e-6)
        np.testing.assert_allclose(cmd[2], 0.8, atol=1e-6)  # k_yaw 1.5 x 1 rad, at the 0.8 rad/s limit


def test_non_finite_pose_gives_zero_command_and_flag():
    grid = _world()
    pose = jnp.array([jnp.nan, 2.0, 0.0])
    path = jnp.zeros((8, 2))
    inputs = mppi.MppiInputs(
        pose,
        path,
        jnp.ones(8, bool),
        jnp.array([3.0, 2.0, 0.0]),
        grid,
        jax.random.key(0),
    )
    params = mppi.MppiParams.default(n_samples=16, horizon=5)
    _, out = jax.jit(mppi.step)(params, mppi.init(params, jnp.zeros(3)), inputs)
    assert not bool(out.valid) and np.all(np.asarray(out.cmd) == 0.0)


def test_step_vmaps_over_robots():
    grid = _world()
    params = mppi.MppiParams.default(n_samples=32, horizon=8)
    poses = jnp.array([[0.6, 2.0, 0.0], [3.0, 3.0, 1.0], [1.0, 1.0, -1.0]])
    path = jnp.broadcast_to(jnp.linspace(jnp.array([0.6, 0.6]), jnp.array([3.4, 3.4]), 20), (3, 20, 2))
    inputs = jax.vmap(mppi.MppiInputs)(  # one robot's inputs per call: its annotations hold
        poses,
        path,
        jnp.ones((3, 20), bool),
        jnp.tile(jnp.array([3.4, 3.4, 0.0]), (3, 1)),
        jax.tree.map(lambda x: jnp.stack([x] * 3), grid),
        jax.random.split(jax.random.key(1), 3),
    )
    states = jax.vmap(mppi.init, in_axes=(None, 0))(params, poses)
    _, out = jax.jit(jax.vmap(mppi.step, in_axes=(None, 0, 0)))(params, states, inputs)
    for i in range(3):
        one = jax.tree.map(lambda x, i=i: x[i], inputs)
        _, ref = jax.jit(mppi.step)(params, mppi.init(params, poses[i]), one)
        np.testing.assert_allclose(np.asarray(out.cmd[i]), np.asarray(ref.cmd), atol=1e-5)


def _wrap(a):
    return (a + math.pi) % (2 * math.pi) - math.pi


def test_critics_match_loop_references():
    from scipy import ndimage

    from jaxquad.kernels import critics

    rng = np.random.default_rng(4)
    grid = _world()
    cost = np.asarray(grid.cost)
    depth = np.clip(1.0 - ndimage.distance_transform_edt(_room() < 65) * RES / 0.2, 0.0, 1.0)
    traj = np.c_[rng.uniform(-0.2, 4.2, (6 * 7, 2)), rng.uniform(-4, 4, 6 * 7)].reshape(6, 7, 3).astype(np.float32)
    u = rng.normal(size=(6, 7, 3)).astype(np.float32)
    u_prev = rng.normal(size=3).astype(np.float32)
    goal = np.array([3.0, 1.0, 2.0], np.float32)
    carrot = np.array([1.0, 3.5], np.float32)
    window = rng.uniform(0, 4, (5, 2)).astype(np.float32)
    disks = np.array([[-0.3, 0.05], [0.0, 0.0], [0.25, -0.02]], np.float32)  # footprint disk centres, base frame
    yes, no = jnp.array(True), jnp.array(False)
    got = {
        "obstacle": critics.obstacle(jnp.asarray(traj), grid, jnp.float32(1000.0), jnp.asarray(disks)),
        "goal_distance": critics.goal_distance(jnp.asarray(traj), jnp.asarray(goal), yes),
        "goal_heading": critics.goal_heading(jnp.asarray(traj), jnp.asarray(goal), yes),
        "path_follow": critics.path_follow(jnp.asarray(traj), jnp.asarray(carrot), no),
        "path_align": critics.path_align(jnp.asarray(traj), jnp.asarray(window), no),
        "path_heading": critics.path_heading(jnp.asarray(traj), jnp.asarray(carrot), no),
        "smoothness": critics.smoothness(jnp.asarray(u), jnp.asarray(u_prev)),
    }
    graded_hits = 0
    for s in range(6):
        cells, deepest = [], []
        for x, y, th in traj[s]:
            worst, deep = 0.0, 0.0
            for dx, dy in disks:  # each disk centre in the world, then its cell
                px, py = x + math.cos(th) * dx - math.sin(th) * dy, y + math.sin(th) * dx + math.cos(th) * dy
                r, c = math.floor(py / RES), math.floor(px / RES)
                on_grid = 0 <= r < 80 and 0 <= c < 80
                worst = max(worst, cost[r, c] if on_grid else 254.0)
                deep = max(deep, depth[r, c] if on_grid else 1.0)
            cells.append(worst)
            deepest.append(deep)
        cells, deepest = np.array(cells), np.array(deepest)
        graded = 1.0 + deepest.max() + deepest.mean()  # how deep and for how long inside the inscribed radius
        graded_hits += bool(np.any(cells >= 253) and 1.0 < graded < 3.0)
        want = {
            "obstacle": np.mean(np.minimum(cells, 252) / 252) + (1000.0 * graded if np.any(cells >= 253) else 0.0),
            "goal_distance": np.mean([math.dist(p[:2], goal[:2]) for p in traj[s]]),
            "goal_heading": np.mean([abs(_wrap(p[2] - goal[2])) for p in traj[s]]),
            "path_follow": math.dist(traj[s, -1, :2], carrot),
            "path_align": np.mean([min(math.dist(p[:2], q) for q in window) for p in traj[s]]),
            "path_heading": np.mean(
                [abs(_wrap(math.atan2(carrot[1] - p[1], carrot[0] - p[0]) - p[2])) for p in traj[s]]
            ),
            "smoothness": np.mean([np.sum((u[s, t] - (u[s, t - 1] if t else u_prev)) ** 2) for t in range(7)]),
        }
        for name, value in want.items():
            assert float(got[name][s]) == pytest.approx(value, rel=1e-4, abs=1e-5), (name, s)
    assert graded_hits >= 2  # samples in collision, graded by depth (neither 0 nor all 1)
    # The goal critics are off far from the goal, the path critics near it.
    assert float(jnp.max(critics.goal_distance(jnp.asarray(traj), jnp.asarray(goal), no))) == 0.0
    assert float(jnp.max(critics.path_align(jnp.asarray(traj), jnp.asarray(window), yes))) == 0.0


def test_outline_on_unknown_or_lethal_cells_collides():
    """A room whose left part no scan has seen: samples whose outline points (NumPy, each rotated into the world)
    land on an unknown or lethal cell anywhere along them take the collision cost, whatever their disks do."""
    from jaxquad.kernels import critics

    occ = _room()
    occ[:, :30] = -1  # unknown, up to x = 1.5 m
    params = CostmapParams.default(inscribed_radius=0.2)
    cost, depth = costmap_layers(jnp.asarray(occ), RES, params)
    grid = CostGrid(cost=cost, origin=jnp.zeros(2), resolution=jnp.asarray(RES), depth=depth)
    disks = np.array([[0.0, 0.0]], np.float32)
    outline = np.array([[0.3, 0.17], [0.3, -0.17], [-0.3, 0.17], [-0.3, -0.17], [0.0, 0.17], [0.0, -0.17]], np.float32)
    rng = np.random.default_rng(5)
    # Poses by a straight stretch of the unknown's edge (x 1.5 m), clear of the walls' and the block's inscribed zones.
    start = np.c_[rng.uniform(1.52, 2.3, 40), rng.uniform(0.45, 0.95, 40), rng.uniform(-4, 4, 40)]
    step = rng.normal(0.0, [0.03, 0.03, 0.3], (40, 1, 3))
    traj = (start[:, None, :] + np.linspace(0.0, 1.0, 5)[None, :, None] * step).astype(np.float32)
    args = (jnp.asarray(traj), grid, jnp.float32(1000.0), jnp.asarray(disks))
    with_outline = np.asarray(critics.obstacle(*args, jnp.asarray(outline)))
    without = np.asarray(critics.obstacle(*args))
    cells = np.asarray(cost)
    n_outline_only = 0
    for s in range(40):
        on_bad = False
        for x, y, th in traj[s]:
            for dx, dy in outline:
                px, py = x + math.cos(th) * dx - math.sin(th) * dy, y + math.sin(th) * dx + math.cos(th) * dy
                r, c = math.floor(py / RES), math.floor(px / RES)
                on_bad |= not (0 <= r < 80 and 0 <= c < 80) or cells[r, c] >= 254
        disk_hit = without[s] >= 1000.0
        assert (with_outline[s] >= 1000.0) == (on_bad or disk_hit), s
        if on_bad and not disk_hit:
            n_outline_only += 1
            np.testing.assert_allclose(with_outline[s] - without[s], 1000.0, rtol=1e-5)  # graded: depth 0 there
        else:
            np.testing.assert_allclose(with_outline[s], without[s], rtol=1e-6)
    assert 5 <= n_outline_only <= 35, n_outline_only  # both kinds of sample drawn


def test_nominal_is_the_softmax_weighted_mean_of_the_samples():
    """With one sample far better than the rest and a tiny temperature, the new nominal is that sample."""
    from scipy import ndimage

    grid = _world()
    params = mppi.MppiParams.default(n_samples=64, horizon=10, temperature=1e-4)
    pose = jnp.array([1.0, 1.0, 0.0])
    goal = jnp.array([1.5, 1.0, 0.0])  # near: only the goal critics and the smoothness/obstacle ones act
    inputs = mppi.MppiInputs(pose, jnp.broadcast_to(goal[:2], (8, 2)), jnp.ones(8, bool), goal, grid, jax.random.key(3))
    state = mppi.init(params, pose)
    _, out = jax.jit(mppi.step)(params, state, inputs)
    # Reference: the samples as the controller draws them, scored by a NumPy sum of the same critics.
    u = np.asarray(mppi._sample(params, state.nominal, inputs.key))
    traj = np.asarray(mppi.rollout(pose, jnp.asarray(u), params.dt))
    w = np.asarray(params.weights)
    cost = w[1] * np.mean(np.linalg.norm(traj[..., :2] - np.asarray(goal[:2]), axis=-1), axis=-1)
    cost += w[2] * np.mean(np.abs(_wrap(traj[..., 2])), axis=-1)
    du = np.diff(np.concatenate([np.zeros((64, 1, 3)), u], axis=1), axis=1)
    cost += w[6] * np.mean(np.sum(du**2, axis=-1), axis=-1)
    cells = np.asarray(grid.cost_at(jnp.asarray(traj[..., :2])))
    rc = np.floor(traj[..., 1::-1] / RES).astype(int)  # the default footprint: one disk at the base
    depth = np.clip(1.0 - ndimage.distance_transform_edt(_room() < 65) * RES / 0.2, 0.0, 1.0)[rc[..., 0], rc[..., 1]]
    graded = 1.0 + depth.max(-1) + depth.mean(-1)
    hit = np.any(cells >= 253, -1)
    cost += w[0] * np.mean(np.minimum(cells, 252) / 252, axis=-1) + np.where(hit, 1000.0, 0.0) * graded
    best = int(np.argmin(cost))
    np.testing.assert_allclose(np.asarray(out.trajectory), traj[best], atol=1e-4)
    np.testing.assert_allclose(np.asarray(out.cmd), u[best, 0], atol=1e-5)


def test_turn_is_clear_matches_the_disks_distance_to_obstacles():
    """A turn in place is clear exactly when every covering disk stays farther than its radius from obstacle
    cells at every heading (a NumPy sweep of 720 headings; poses within 0.1 m of the threshold are skipped:
    the grid and the 32 headings resolve it to a few cm); unknown cells never block."""
    from scipy.spatial import cKDTree

    from jaxquad.kernels.critics import turn_is_clear

    disks, radius = footprint_disks(jnp.array([-0.076, 0.0]), jnp.array([0.315, 0.1715]))
    pad = 0.1
    grid = _world(float(radius) + pad)
    occ = np.zeros((80, 80), bool)
    occ[[0, -1], :] = occ[:, [0, -1]] = True
    occ[25:55, 35:45] = True
    rows, cols = np.nonzero(occ)
    centres = np.stack([(cols + 0.5) * RES, (rows + 0.5) * RES], -1)
    rng = np.random.default_rng(0)
    poses = np.concatenate([rng.uniform(0.1, 3.9, (300, 2)), rng.uniform(-np.pi, np.pi, (300, 1))], 1)
    yaw = np.linspace(0, 2 * np.pi, 720, endpoint=False)
    d = np.asarray(disks)
    check = jax.jit(jax.vmap(turn_is_clear, in_axes=(0, None, None)))
    got = np.asarray(check(jnp.asarray(poses, jnp.float32), grid, disks))
    tree, c, s = cKDTree(centres), np.cos(yaw), np.sin(yaw)
    rot = np.stack([np.stack([c, -s], -1), np.stack([s, c], -1)], 1)  # (720, 2, 2) at yaw 0
    margins = []
    for pose in poses:  # the headings sweep the full circle, so the start yaw does not matter
        world = pose[:2] + np.einsum("nij,kj->nki", rot, d)
        margins.append(tree.query(world.reshape(-1, 2))[0].min() - (float(radius) + pad))
    margins = np.array(margins)
    sure = np.abs(margins) > 0.1
    assert sure.sum() > 200 and (margins[sure] > 0).sum() > 20 and (margins[sure] < 0).sum() > 20
    np.testing.assert_array_equal(got[sure], margins[sure] > 0)
    free = np.where(occ, -1, 0).astype(np.int8)  # the same obstacles unknown: nothing blocks a turn ...
    cost = costmap_from_occupancy(jnp.asarray(free), RES, CostmapParams.default())
    unknown = CostGrid(cost=cost, origin=jnp.zeros(2), resolution=jnp.asarray(RES))
    edge = np.min(np.concatenate([poses[:, :2], 4.0 - poses[:, :2]], 1), axis=1) - np.linalg.norm(d, axis=1).max()
    inside = edge > 0  # ... but a disk centre off the grid does
    sure = np.abs(edge) > 0.06
    assert inside[sure].any() and (~inside[sure]).any() and not got[inside & sure].all()
    got_unknown = np.asarray(check(jnp.asarray(poses, jnp.float32), unknown, disks))
    np.testing.assert_array_equal(got_unknown[sure], inside[sure])


def test_goal_turn_next_to_an_obstacle_is_left_to_the_critics():
    """At the goal's position beside the block, turning from facing along it to facing it would swing the Go2's
    covering disks into the block's inscribed cells (the negative control, and its rectangle into the block); the
    controller does not turn in place there, and its disks stay out of those cells. In the open the same goal is
    the proportional turn."""
    from jaxquad.kernels.critics import footprint_cost

    center, half = jnp.array([-0.076, 0.0]), jnp.array([0.315, 0.17])
    disks, radius = footprint_disks(center, half)
    params = eqx.tree_at(lambda p: p.footprint_disks, PARAMS, disks)
    grid = _world(float(radius))
    block = Boxes(jnp.array([[2.0, 2.0, 0.5]]), jnp.array([[0.25, 0.75, 0.5]]), jnp.zeros(1))
    pose = jnp.array([1.52, 2.0, math.pi / 2])  # base 0.23 m from the block's face, long axis along it
    sweep = jnp.stack([jnp.full(64, 1.52), jnp.full(64, 2.0), jnp.linspace(math.pi / 2, 0.0, 64)], -1)
    assert np.asarray(_touches(block, sweep, center, half)).any()  # turning in place there hits the block
    assert np.asarray(footprint_cost(sweep[None], grid, disks)).max() >= INSCRIBED
    assert np.asarray(footprint_cost(pose[None, None], grid, disks)).max() < INSCRIBED
    goal = pose.at[2].set(0.0)
    poses, _, cmds = _closed_loop(grid, pose, goal, jax.random.key(0), params)
    assert np.asarray(footprint_cost(poses[None], grid, disks)).max() < INSCRIBED
    assert not np.allclose(np.asarray(cmds[0]), [0.0, 0.0, -0.8], atol=1e-3)
    free = jnp.array([0.9, 2.0, math.pi / 2])
    _, _, cmds = _closed_loop(grid, free, free.at[2].set(0.0), jax.random.key(0), params)
    np.testing.assert_allclose(np.asarray(cmds[0]), [0.0, 0.0, -0.8], atol=1e-6)  # k_yaw x -pi/2, clipped
