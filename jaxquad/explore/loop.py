"""The closed exploration loop of one simulated robot: simulator -> estimator -> online SLAM -> frontier goal
-> global plan -> MPPI, with no map given.

The robot side (physics, the estimator's leg-inertial odometry, depth visual odometry, scans, the
collision judge) is `jaxquad.nav.body`, as in the navigation loop. Per control tick (`frames_per_tick`
camera frames, 0.096 s) the last frame's scan, with the odometry and the leg odometry's planar twist,
goes through one step of the online SLAM (`jaxquad.slam`), whose pose drives the controller. Once per
planning period (a tick whose shared `replan` flag is set; under `vmap` a `lax.cond` skips it on the
other ticks) the SLAM map, redrawn from every node's scan if a loop closure has moved the nodes since the
last period (`slam.refresh_map`: the fleet's SLAM skips the redraw in its own step, where under `vmap` one
robot's closure made every robot wait for a redraw over all its nodes, nearly every tick in a fleet of 100),
becomes a costmap, `jaxquad.nav.explore.update` picks the nearest reachable
frontier (progress check and blacklist included), or once none is left a place from which to look at one out of
reach (a view goal), and the plan to it is read off the robot's own
cost-to-go (`nav.plan_from_start`). Between plans MPPI follows it on that costmap. With active loop closing
(`jaxquad.nav.revisit`, off unless its `after` is finite) the goal is for a while an old SLAM node's pose
instead, when the SLAM has gone that long without a loop closure; the frontier's progress clock waits. With
`ExploreLoopConfig.low_obstacles` the costmap also holds the obstacles under the scan plane that the depth image
shows (`kernels.low_obstacles`: a pallet lower than the camera is in no scan, so in no map).
Without a goal the robot turns in place (`spin_rate`) to look around: at the start, before its map has free
cells, and when exploration seems done; where the turn would bring its footprint onto a known obstacle of
the costmap (`kernels.critics.turn_is_clear`) it waits instead, holding the SLAM pose where the wait began
(`kernels.mppi.hold`: a trotting gait told to stand still drifts, by centimetres a second). Exploration is finished when
`nav.explore` says so (no goal of either kind, no frontier cell left to score for a view) and no goal has been found
for `finish_time` seconds.

Nothing from ground truth decides anything: the truth only judges. A run ends `collided` (the base
footprint overlaps a world box), `lost` (the SLAM pose more than `lost_error` from the truth for
`lost_time`), `fallen`, or `explored` (finished as above); the robot then stands still and its map
stays as it was. `coverage` (per tick) is the robot's known-free cells within the true reachable free
cells over those cells (`ExploreInputs.reachable`, on the SLAM map's cells); between a loop closure and the
next planning period it reads the map before its redraw.

`state = init(params, inputs, qpos0, key)`, `state, out = tick(params, state, inputs)`: one robot, pure.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from typing import NamedTuple

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Bool, Float, Int, PRNGKeyArray

from jaxquad import slam
from jaxquad.estimate.laser import planar_twist
from jaxquad.kernels import critics, mppi
from jaxquad.kernels.costmap import CostGrid
from jaxquad.kernels.lie import R2, roll_pitch
from jaxquad.kernels.low_obstacles import LowObstacleParams, low_obstacle_scan
from jaxquad.kernels.occupancy import occupancy_values
from jaxquad.kernels.scan import BAND_REDUCTIONS
from jaxquad.nav import explore, revisit
from jaxquad.nav import navigate as nav
from jaxquad.nav.body import Body, BodyParams, make_body, pose_error
from jaxquad.nav.missions import known_free

OUTCOMES = ("running", "explored", "collided", "lost", "fallen")
RUNNING, EXPLORED, COLLIDED, LOST, FALLEN = range(len(OUTCOMES))
# What moved the robot on a tick: MPPI along the plan, the turn to the goal's yaw inside its tolerance,
# standing at the goal, the stuck recovery (backup, turn or wait), the look-around turn without a goal, standing
# still without a goal where that turn is blocked, or nothing (the run had ended).
MODES = ("mppi", "goal_turn", "arrived", "recovery", "spin", "wait", "ended")
MPPI, GOAL_TURN, ARRIVED, RECOVERY, SPIN, WAIT, ENDED = range(len(MODES))
LOW_MARGIN = 0.2  # m: a low obstacle counts where it is this much nearer than the 2D scan's return


@dataclasses.dataclass(frozen=True)
class ExploreLoopConfig:
    """Static choices (they select code)."""

    odometry: str = "leg"  # "leg": leg-inertial odometry; "visual": depth VO with a constant-velocity guess
    scans: str = "stabilized"  # "stabilized": IMU-levelled band; "baseline": fixed image rows
    lo_constraints: str = "preintegrated"  # the SLAM's leg-odometry edges (jaxquad.slam.LO_CONSTRAINTS)
    frames_per_tick: int = 3
    band_height: int = 1  # scan band rows
    band_reduce: str = "median"  # each ray's range from its band: "median" or the paper's "min" (kernels.scan)
    contacts: str = "truth"  # the estimator's contact source
    low_obstacles: bool = False  # mark obstacles under the scan plane from the depth image (kernels.low_obstacles)

    def __post_init__(self):
        if self.lo_constraints not in slam.LO_CONSTRAINTS:
            raise ValueError(f"lo_constraints must be one of {slam.LO_CONSTRAINTS}, got {self.lo_constraints!r}")
        if self.band_reduce not in BAND_REDUCTIONS:
            raise ValueError(f"band_reduce must be one of {BAND_REDUCTIONS}, got {self.band_reduce!r}")
        for name in ("frames_per_tick", "band_height"):
            if int(getattr(self, name)) < 1:
                raise ValueError(f"{name} must be >= 1, got {getattr(self, name)}")


class ExploreLoopParams(eqx.Module):
    """Tunable numbers (traced leaves; the sub-parameters carry their own static sizes)."""

    nav: nav.NavParams
    explore: explore.ExploreParams
    revisit: revisit.RevisitParams
    low: LowObstacleParams  # read with ExploreLoopConfig.low_obstacles
    slam_spec: slam.SlamSpec  # static: capacities, search sizes, the map's cells
    slam: slam.SlamParams
    body: BodyParams
    yaw_rate_std: Float[Array, ""]  # rad/s, std of the leg-odometry yaw rate (the SLAM's leg edges)
    spin_rate: Float[Array, ""]  # rad/s, turning in place without a goal
    # m/s: the forward limit where the robot's costmap cell is inflated (within the inflation radius of a known
    # obstacle) or unknown, when below `nav.controller`'s (`near_obstacle_limit`)
    near_obstacle_speed: Float[Array, ""]
    finish_time: Float[Array, ""]  # s without a goal (turning) before exploration counts as finished
    lost_error: Float[Array, ""]  # m
    lost_time: Float[Array, ""]  # s


class ExploreInputs(eqx.Module):
    model: object  # mjx.Model (batched as `Fleet.model_in_axes`)
    setup: object  # sim.RobotSetup
    reachable: Bool[Array, "H W"]  # truth, to judge coverage only: reachable free cells on the SLAM map's cells
    replan: Bool[Array, ""]  # plan on this tick (one flag for the fleet)


class ExploreLoopState(eqx.Module):
    body: Body
    slam: slam.SlamState
    pose: Float[Array, " 3"]  # the SLAM's pose of the base, map (= world) frame
    grid: CostGrid  # costmap of the SLAM map at the last planning period
    low: Bool[Array, "H W"]  # cells of obstacles seen under the scan plane, on the SLAM map's cells ((0, 0) when off)
    explore: explore.ExploreState
    revisit: revisit.RevisitState
    nav: nav.NavState
    cmd: Float[Array, " 3"]  # body command to the gait controller
    waiting: Bool[Array, ""]  # no goal and no clear turn: holding `held_at`
    held_at: Float[Array, " 3"]  # the SLAM pose where the wait began
    no_goal_for: Float[Array, ""]  # s since a goal (frontier or view) was last found
    lost_for: Float[Array, ""]  # s the SLAM pose error has stayed above lost_error
    distance: Float[Array, ""]  # m walked (true path, in the plane)
    outcome: Int[Array, ""]  # OUTCOMES code
    end_t: Float[Array, ""]  # s when the run ended (NaN while running)
    key: PRNGKeyArray


class ExploreOutput(eqx.Module):
    """Per tick (leading axes B: a fleet adds time and robots)."""

    t: Float[Array, "*B"]  # s
    true_pose: Float[Array, "*B 3"]
    pose: Float[Array, "*B 3"]  # SLAM pose
    error: Float[Array, "*B"]  # m, SLAM position error
    coverage: Float[Array, "*B"]  # known-free over true reachable free cells
    goal: Float[Array, "*B 3"]  # the frontier or view goal, or the revisited node's pose
    has_goal: Bool[Array, "*B"]
    revisiting: Bool[Array, "*B"]  # the goal is a revisit (`jaxquad.nav.revisit`)
    viewing: Bool[Array, "*B"]  # the goal is a view goal (`jaxquad.nav.explore`)
    mode: Int[Array, "*B"]  # MODES code: what commanded the robot on the tick
    active: Bool[Array, "*B"]  # the run had not ended at the start of the tick
    loop_closed: Bool[Array, "*B"]  # the SLAM accepted a loop closure on the tick
    loop_chi2: Float[Array, "*B"]  # its candidate's consistency chi-square (`slam.SlamOutput.loop_chi2`; NaN: none)


class ExploreFunctions(NamedTuple):
    init: Callable  # (params, inputs, qpos0, key) -> ExploreLoopState
    tick: Callable  # (params, state, inputs) -> (state, ExploreOutput)


def coverage(values: Int[Array, "H W"], reachable: Bool[Array, "H W"]) -> Float[Array, ""]:
    """Known-free cells (`nav.missions.known_free`) among the `reachable` cells, over their count."""
    free = known_free(values) & reachable
    return jnp.sum(free) / jnp.maximum(jnp.sum(reachable), 1)


def goal_of(ex: explore.ExploreState, rv: revisit.RevisitState) -> tuple[Float[Array, " 3"], Bool[Array, ""]]:
    """(goal pose, whether there is one): the revisited node while a revisit lasts, else the frontier or view goal."""
    return jnp.where(rv.active, rv.goal, ex.goal), rv.active | ex.has_goal


def near_obstacle_limit(
    controller: mppi.MppiParams, near_speed: Float[Array, ""], grid: CostGrid, pose: Float[Array, " 3"]
) -> mppi.MppiParams:
    """The controller with its forward limit lowered to `near_speed` while the robot's cell of `grid` has a cost
    (inflated, inscribed, lethal or unknown), as Nav2's regulated controllers slow down near obstacles."""
    near = grid.cost_at(pose[:2]) > 0
    v_max = controller.v_max.at[0].set(
        jnp.where(near, jnp.minimum(near_speed, controller.v_max[0]), controller.v_max[0])
    )
    return eqx.tree_at(lambda c: c.v_max, controller, v_max)


def idle_command(
    controller: mppi.MppiParams,
    spin_rate: Float[Array, ""],
    pose: Float[Array, " 3"],
    can_turn: Bool[Array, ""],
    waiting: Bool[Array, ""],
    held_at: Float[Array, " 3"],
) -> tuple[Float[Array, " 3"], Float[Array, " 3"]]:
    """(command, pose held) without a goal: turn in place at `spin_rate` (rad/s) where the turn is clear,
    else wait, holding the SLAM pose where the wait began (`kernels.mppi.hold`, with `controller`'s gain,
    radius and limits)."""
    hold, held_at = mppi.hold(controller, pose, held_at, waiting)
    cmd = jnp.where(can_turn, jnp.array([0.0, 0.0, 1.0]) * spin_rate, hold)
    return jnp.where(jnp.all(jnp.isfinite(pose)), cmd, 0.0), held_at


def make_explore_loop(fleet, config: ExploreLoopConfig) -> ExploreFunctions:
    """The loop's pure functions for `fleet` (a `jaxquad.sim.Fleet` with depth; static parts closed over)."""
    body = make_body(fleet, config.odometry, config.scans, config.band_height, config.contacts, config.band_reduce)
    tick_dt = config.frames_per_tick * float(fleet.frame_dt)
    cam_xy = jnp.asarray(np.asarray(fleet.T_base_camera)[:2, 3], jnp.float32)  # the camera in the base frame, m

    def mark_low(params: ExploreLoopParams, low, grid: CostGrid, b: Body, depth, scan, pose, active):
        """`low` (on `grid`'s cells) with this frame's obstacles under the scan plane marked, placed by the SLAM
        pose: those nearer than what the frame's 2D `scan` sees along their bearings by `LOW_MARGIN` (what the scan
        sees, the map holds), never cleared (a cell needs `min_points` points, so few are false)."""
        roll, pitch = roll_pitch(b.est.pose.q_world_base)
        seen = low_obstacle_scan(depth, params.body.intrinsics, roll, pitch, params.low)
        n = seen.bearings.shape[0]
        step = seen.bearings[1] - seen.bearings[0]
        k = jnp.floor((scan.bearings - seen.bearings[0]) / step + 0.5).astype(jnp.int32)  # the nearest bin centre
        k = jnp.where((k >= 0) & (k < n), k, n)  # beams outside every bin go to a slot that is dropped
        wall = jax.ops.segment_min(jnp.where(jnp.isfinite(scan.ranges), scan.ranges, jnp.inf), k, num_segments=n + 1)
        wall = wall[:n]
        nearer = seen.ranges < jnp.where(jnp.isfinite(wall), wall, jnp.inf) - LOW_MARGIN
        cam = pose[:2] + R2(pose[2]) @ cam_xy
        hit = jnp.isfinite(seen.ranges) & nearer & active & jnp.all(jnp.isfinite(pose))
        ray = pose[2] + seen.bearings
        xy = cam + jnp.where(hit, seen.ranges, 0.0)[:, None] * jnp.stack([jnp.cos(ray), jnp.sin(ray)], axis=-1)
        rc = grid.cell_of(xy)
        rows, cols = low.shape
        inside = hit & (rc[:, 0] >= 0) & (rc[:, 0] < rows) & (rc[:, 1] >= 0) & (rc[:, 1] < cols)
        return low.at[jnp.where(inside, rc[:, 0], rows), rc[:, 1]].set(True, mode="drop")

    def slam_step(params: ExploreLoopParams, s: slam.SlamState, b: Body, scan, odom, active=True):
        """One SLAM step on the frame's scan; an inactive robot's scan has no stamp and adds nothing."""
        q = b.est.pose.q_world_base
        twist, cov = planar_twist(q, b.v_base, b.omega_base, b.cov_v_base, params.yaw_rate_std)
        inputs = slam.SlamInputs(
            t=jnp.where(active, b.sim.t, jnp.nan),
            odom=odom,
            ranges=jnp.where(b.valid, scan.ranges, jnp.nan),
            valid=b.valid & ~jnp.isnan(scan.ranges),
            lo_pose=body.leg_pose(b.est),
            lo_twist=twist,
            lo_twist_cov=cov,
            lo_valid=b.valid & active,
        )
        return slam.step(params.slam_spec, params.slam, s, inputs)

    def plan(params: ExploreLoopParams, s: ExploreLoopState, period: float):
        """The planning period: the SLAM map (redrawn if a loop closure moved its nodes), its costmap, the next
        goal (a revisit of an old node, else a frontier) and the plan to it."""
        g = params.slam_spec.grid
        slam_state = slam.refresh_map(params.slam_spec, params.slam, s.slam)
        values = occupancy_values(slam_state.grid)
        # The frontiers read the SLAM map; the costmap also holds the obstacles under the scan plane.
        blocked = jnp.where(s.low, jnp.asarray(100, values.dtype), values) if config.low_obstacles else values
        grid = nav.cost_grid(params.nav, blocked, jnp.array([g.origin_x, g.origin_y], jnp.float32), g.resolution)
        weight, value = explore.robot_value(params.explore, grid, s.pose)
        nodes = revisit.Nodes(slam_state.graph.poses, slam_state.node_t, slam_state.graph.node_mask)
        running = s.outcome == RUNNING
        rv = revisit.update(
            params.revisit, s.revisit, nodes, slam_state.loops, s.body.sim.t, s.pose, grid, value, period, running
        )
        # The frontier's progress clock stands still over a period the robot spent on a revisit.
        ex, _ = explore.update(
            params.explore, s.explore, values, grid, s.pose, jnp.where(s.revisit.active, 0.0, period), value
        )
        goal, has_goal = goal_of(ex, rv)
        p = nav.plan_from_start(params.nav, grid, weight, value, grid.cell_of(goal[:2]), s.pose)
        p = eqx.tree_at(lambda x: x.ok, p, p.ok & has_goal)
        # A new goal (one that moved): MPPI restarts from a zero sequence on the new plan.
        moved = jnp.linalg.norm(goal[:2] - goal_of(s.explore, s.revisit)[0][:2])
        moved = moved > params.explore.blacklist_radius
        fresh = nav.init(params.nav, s.pose).controller
        ctrl = jax.tree.map(lambda a, b: jnp.where(moved, a, b), fresh, s.nav.controller)
        return slam_state, grid, ex, rv, nav.NavState(controller=ctrl, plan=p)

    def init(params: ExploreLoopParams, inputs: ExploreInputs, qpos0, key) -> ExploreLoopState:
        k_sim, key = jax.random.split(key)
        b, depth = body.start(params.body, inputs.model, inputs.setup, qpos0, k_sim)
        slam_state = slam.init(params.slam_spec, params.slam, body.scan(params.body, b.est, depth).bearings)
        # The odometry starts at the true start pose (the operator's), so the map frame is the world's and the
        # SLAM pose is the odometry's until the first tick's scan makes the first node (a SLAM step here would
        # compile the whole SLAM a second time, for one scan).
        pose = body.leg_pose(b.est)
        g = params.slam_spec.grid
        shape = (g.rows, g.cols)
        unknown = jnp.full(shape, 255.0, jnp.float32)  # no map yet: every cell unknown
        origin = jnp.array([g.origin_x, g.origin_y], jnp.float32)
        return ExploreLoopState(
            body=b,
            slam=slam_state,
            pose=pose,
            grid=CostGrid(unknown, origin, jnp.asarray(g.resolution, jnp.float32), jnp.zeros(shape, jnp.float32)),
            low=jnp.zeros(shape if config.low_obstacles else (0, 0), bool),
            explore=explore.init(shape),
            revisit=revisit.init(params.slam_spec.nodes),
            nav=nav.init(params.nav, pose),
            cmd=jnp.zeros(3),
            waiting=jnp.array(False),
            held_at=pose,
            no_goal_for=jnp.zeros(()),
            lost_for=jnp.zeros(()),
            distance=jnp.zeros(()),
            outcome=jnp.asarray(RUNNING, jnp.int32),
            end_t=jnp.asarray(jnp.nan, jnp.float32),
            key=key,
        )

    def tick(params: ExploreLoopParams, s: ExploreLoopState, inputs: ExploreInputs):
        active = s.outcome == RUNNING
        before = body.true_pose(s.body.sim)

        def frame(b, _):
            b, depth, odom = body.frame(params.body, inputs.model, inputs.setup, b, s.cmd)
            b = dataclasses.replace(b, sim=body.judge_collision(params.body, inputs.setup, b.sim))
            return b, (depth, odom)

        b, (depth, odom) = jax.lax.scan(frame, s.body, None, length=config.frames_per_tick)
        # A finished run keeps its map: the SLAM sees nothing more.
        scan = body.scan(params.body, b.est, depth[-1])
        slam_state, out = slam_step(params, s.slam, b, scan, odom[-1], active)
        loop_closed, loop_chi2 = active & out.loop_closed, jnp.where(active, out.loop_chi2, jnp.nan)
        pose = jnp.where(active, out.pose, s.pose)
        low = mark_low(params, s.low, s.grid, b, depth[-1], scan, pose, active) if config.low_obstacles else s.low
        s = dataclasses.replace(s, body=b, slam=slam_state, pose=pose, low=low)

        period = params.nav.replan_ticks * tick_dt
        slam_state, grid, ex, rv, nav_state = jax.lax.cond(
            inputs.replan, lambda: plan(params, s, period), lambda: (s.slam, s.grid, s.explore, s.revisit, s.nav)
        )
        goal, has_goal = goal_of(ex, rv)
        key, k_nav = jax.random.split(s.key)
        controller = near_obstacle_limit(params.nav.controller, params.near_obstacle_speed, grid, s.pose)
        nav_params = eqx.tree_at(lambda p: p.controller, params.nav, controller)
        nav_state, ctrl = nav.step(nav_params, nav_state, nav.NavInputs(pose=s.pose, goal=goal, grid=grid, key=k_nav))
        can_turn = critics.turn_is_clear(s.pose, grid, params.nav.controller.footprint_disks)
        idle, held_at = idle_command(params.nav.controller, params.spin_rate, s.pose, can_turn, s.waiting, s.held_at)
        cmd = jnp.where(has_goal, ctrl.cmd, idle)
        mode = jnp.select(
            [~active, ~has_goal & can_turn, ~has_goal, ctrl.recovering, ctrl.arrived, ctrl.goal_turn],
            [ENDED, SPIN, WAIT, RECOVERY, ARRIVED, GOAL_TURN],
            MPPI,
        )
        no_goal_for = jnp.where(has_goal, 0.0, s.no_goal_for + tick_dt)

        t, truth = b.sim.t, body.true_pose(b.sim)
        error, _ = pose_error(s.pose, truth)
        lost_for = jnp.where(error > params.lost_error, s.lost_for + tick_dt, 0.0)
        ended = jnp.select(
            [
                b.sim.collided,
                b.sim.fallen,
                lost_for >= params.lost_time - 0.5 * tick_dt,
                ex.done & (no_goal_for >= params.finish_time),
            ],
            [COLLIDED, FALLEN, LOST, EXPLORED],
            RUNNING,
        )
        outcome = jnp.where(active, ended, s.outcome)
        still = outcome == RUNNING
        s = dataclasses.replace(
            s,
            slam=slam_state,
            grid=grid,
            explore=ex,
            revisit=rv,
            nav=nav_state,
            cmd=jnp.where(still, cmd, 0.0),
            waiting=mode == WAIT,
            held_at=held_at,
            no_goal_for=no_goal_for,
            lost_for=lost_for,
            distance=s.distance + jnp.where(active, jnp.hypot(*(truth[:2] - before[:2])), 0.0),
            outcome=outcome,
            end_t=jnp.where(active & ~still, t, s.end_t),
            key=key,
        )
        return s, ExploreOutput(
            t=t,
            true_pose=truth,
            pose=s.pose,
            error=error,
            coverage=coverage(occupancy_values(slam_state.grid), inputs.reachable),
            goal=goal,
            has_goal=has_goal,
            revisiting=rv.active,
            viewing=ex.viewing & ~rv.active,
            mode=mode.astype(jnp.int8),
            active=active,
            loop_closed=loop_closed,
            loop_chi2=loop_chi2,
        )

    return ExploreFunctions(init=init, tick=tick)
