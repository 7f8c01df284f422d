"""The closed autonomy loop of one simulated robot: simulator -> estimator -> localization -> navigation.

The gait controller walks on the body command of the navigation stack, which sees only what the
robot estimates: the odometry (leg-inertial from the estimator's per-sample step, or depth visual
odometry) and AMCL on the map, fed by scans sliced from the depth camera (IMU-stabilized or the
fixed-row baseline). Ground truth is read only to judge: a collision is the base footprint
overlapping a world box (the boxes are not in the physics model), a robot is lost when its
localization error stays above `lost_error` for `lost_time`.

Rates: physics and the estimator at the simulator's steps (250 Hz for the built-in robots), the depth
camera, scans, odometry and AMCL at the camera frames (31.25 Hz), the controller (MPPI) once per tick
of `frames_per_tick` frames (3: 0.096 s, the MPPI model step), replanning on a tick whose `replan`
input is set (a flag shared by all robots, so under `vmap` a `lax.cond` skips it on the other ticks)
or, without a plan, on the goal critics alone.

A robot visits the goals of its mission in turn. When the navigation stack reports arrival (its own
estimate within the controller's goal tolerance, `MppiParams.goal_xy_tol` / `goal_yaw_tol`), the attempt
ends `reached` if the true pose is within `success_xy` / `success_yaw` of the goal (0.25 m / 0.25 rad),
else `missed`; it ends `timeout` after `timeout_base + path length / timeout_speed` seconds (these three
end only the attempt), or `collided`, `lost`, `fallen` (these end the run; the goals left are `skipped`).

`state = init(params, inputs, qpos0, key)`, `state, out = tick(params, state, inputs)`: one robot,
pure, `vmap` over robots with `input_axes(fleet)`.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from typing import NamedTuple

import equinox as eqx
import jax
import jax.numpy as jnp
from jaxtyping import Array, Bool, Float, Int, PRNGKeyArray

from jaxquad.kernels.costmap import CostGrid
from jaxquad.kernels.likelihood_field import LikelihoodField
from jaxquad.kernels.particle_filter import AmclInputs, AmclParams, AmclState, amcl_init, amcl_step
from jaxquad.kernels.scan import BAND_REDUCTIONS
from jaxquad.nav import navigate as nav
from jaxquad.nav.body import ODOMETRY, SCANS, Body, BodyParams, make_body, pose_error

OUTCOMES = ("pending", "reached", "missed", "collided", "lost", "timeout", "fallen", "skipped")
PENDING, REACHED, MISSED, COLLIDED, LOST, TIMEOUT, FALLEN, SKIPPED = range(len(OUTCOMES))


@dataclasses.dataclass(frozen=True)
class LoopConfig:
    """Static choices (they select code)."""

    odometry: str = "leg"  # "leg": leg-inertial odometry; "visual": depth VO with a constant-velocity guess
    scans: str = "stabilized"  # "stabilized": IMU-levelled band; "baseline": fixed image rows
    n_goals: int = 5
    frames_per_tick: int = 3
    band_height: int = 1  # scan band rows (the authors' simulation used 5: the minimum over noisy rows reads short)
    band_reduce: str = "median"  # each ray's range from its band: "median" or the paper's "min" (kernels.scan)
    contacts: str = "truth"  # the estimator's contact source (the paper's simulations: ground truth)
    n_particles: int = 2000  # AMCL particles per robot

    def __post_init__(self):
        if self.odometry not in ODOMETRY:
            raise ValueError(f"odometry must be one of {ODOMETRY}, got {self.odometry!r}")
        if self.scans not in SCANS:
            raise ValueError(f"scans must be one of {SCANS}, got {self.scans!r}")
        if self.contacts not in ("truth", "mixed"):
            raise ValueError(f"contacts must be 'truth' or 'mixed', got {self.contacts!r}")
        if self.band_reduce not in BAND_REDUCTIONS:
            raise ValueError(f"band_reduce must be one of {BAND_REDUCTIONS}, got {self.band_reduce!r}")
        for name in ("n_goals", "frames_per_tick", "band_height", "n_particles"):
            if int(getattr(self, name)) < 1:
                raise ValueError(f"{name} must be >= 1, got {getattr(self, name)}")


class LoopParams(eqx.Module):
    """Tunable numbers of the loop (traced leaves; the sub-parameters carry their own static sizes)."""

    nav: nav.NavParams
    amcl: AmclParams
    body: BodyParams  # on-board estimation, scans and the footprint judged for collisions
    success_xy: Float[Array, ""]  # m, true distance to the goal at arrival for a success
    success_yaw: Float[Array, ""]  # rad
    lost_error: Float[Array, ""]  # m
    lost_time: Float[Array, ""]  # s
    timeout_base: Float[Array, ""]  # s
    timeout_speed: Float[Array, ""]  # m/s: the time limit's allowance per metre of planned path


class NavMap(eqx.Module):
    """What the navigation stack knows of one world (shared by the robots in it: `vmap` axis None)."""

    grid: CostGrid  # inflated costmap of the map
    field: LikelihoodField  # AMCL's likelihood field of the map
    table: nav.GoalTable  # cost-to-go of every goal in the pool


class LoopInputs(eqx.Module):
    model: object  # mjx.Model (batched as `Fleet.model_in_axes`)
    setup: object  # sim.RobotSetup
    nav_map: NavMap
    goal_ids: Int[Array, "*N G"]  # this robot's goals (every robot's before vmap), indices into nav_map.table
    replan: Bool[Array, ""]  # replan on this tick (one flag for the fleet)


class LoopState(eqx.Module):
    body: Body  # the simulated robot and its on-board estimation
    amcl: AmclState
    pose: Float[Array, " 3"]  # localization estimate x, y (m), yaw (rad), world (= map) frame
    nav: nav.NavState
    cmd: Float[Array, " 3"]  # body command to the gait controller
    goal: Int[Array, ""]  # index into the mission; n_goals once done
    attempt_start: Float[Array, ""]  # s
    limit: Float[Array, ""]  # s, time limit of the current attempt
    outcome: Int[Array, " G"]  # OUTCOMES codes
    elapsed: Float[Array, " G"]  # s from the start to the end of each attempt
    end_error: Float[Array, "G 2"]  # true position (m) and yaw (rad) error to the goal when it ended
    lost_for: Float[Array, ""]  # s the localization error has stayed above lost_error
    done: Bool[Array, ""]
    key: PRNGKeyArray


class LoopOutput(eqx.Module):
    """Per tick (leading axes B: a fleet adds time and robots)."""

    t: Float[Array, "*B"]  # s
    true_pose: Float[Array, "*B 3"]
    pose: Float[Array, "*B 3"]  # localization estimate
    odom: Float[Array, "*B 3"]  # odometry pose at the last frame
    loc_error: Float[Array, "*B F"]  # m, at each frame of the tick
    goal: Int[Array, "*B"]
    active: Bool[Array, "*B"]  # the run had not ended at the start of the tick
    recovering: Bool[Array, "*B"]
    cmd: Float[Array, "*B 3"]


class LoopFunctions(NamedTuple):
    init: Callable  # (params, inputs, qpos0, key) -> LoopState
    tick: Callable  # (params, state, inputs) -> (state, LoopOutput)


def make_loop(fleet, config: LoopConfig) -> LoopFunctions:
    """The loop's pure functions for `fleet` (a `jaxquad.sim.Fleet` with depth; static parts closed over)."""
    body = make_body(fleet, config.odometry, config.scans, config.band_height, config.contacts, config.band_reduce)
    frame_dt = float(fleet.frame_dt)

    def time_limit(params: LoopParams, m: NavMap, gid, pose):
        rc = m.grid.cell_of(pose[:2])
        h, w = m.table.weight.shape
        v = m.table.value[gid, jnp.clip(rc[0], 0, h - 1), jnp.clip(rc[1], 0, w - 1)]
        length = jnp.where(jnp.isfinite(v), v * m.grid.resolution, 0.0)
        return params.timeout_base + length / params.timeout_speed

    def init(params: LoopParams, inputs: LoopInputs, qpos0, key) -> LoopState:
        k_sim, k_amcl, k_step, key = jax.random.split(key, 4)
        b, depth = body.start(params.body, inputs.model, inputs.setup, qpos0, k_sim)
        start = body.true_pose(b.sim)
        # The operator gives AMCL the start pose (AMCL then spreads its particles around it).
        amcl = amcl_init(params.amcl, inputs.nav_map.field, start, k_amcl, config.n_particles)
        scan = body.scan(params.body, b.est, depth)
        amcl, out = amcl_step(
            params.amcl,
            inputs.nav_map.field,
            amcl,
            AmclInputs(body.leg_pose(b.est), scan.ranges, scan.bearings, k_step),
        )
        G = config.n_goals
        return LoopState(
            body=b,
            amcl=amcl,
            pose=out.pose,
            nav=nav.init(params.nav, out.pose),
            cmd=jnp.zeros(3),
            goal=jnp.zeros((), jnp.int32),
            attempt_start=b.sim.t,
            limit=time_limit(params, inputs.nav_map, inputs.goal_ids[0], out.pose),
            outcome=jnp.zeros(G, jnp.int32),
            elapsed=jnp.full(G, jnp.nan),
            end_error=jnp.full((G, 2), jnp.nan),
            lost_for=jnp.zeros(()),
            done=jnp.zeros((), bool),
            key=key,
        )

    def frame(params: LoopParams, inputs: LoopInputs, s: LoopState):
        b, depth, odom = body.frame(params.body, inputs.model, inputs.setup, s.body, s.cmd)
        scan = body.scan(params.body, b.est, depth)
        key, k_amcl = jax.random.split(s.key)
        amcl, out = amcl_step(
            params.amcl, inputs.nav_map.field, s.amcl, AmclInputs(odom, scan.ranges, scan.bearings, k_amcl)
        )
        err, _ = pose_error(out.pose, body.true_pose(b.sim))
        b = dataclasses.replace(b, sim=body.judge_collision(params.body, inputs.setup, b.sim))
        lost_for = jnp.where(err > params.lost_error, s.lost_for + frame_dt, 0.0)
        s = dataclasses.replace(s, body=b, amcl=amcl, pose=out.pose, lost_for=lost_for, key=key)
        return s, (err, odom)

    def tick(params: LoopParams, s: LoopState, inputs: LoopInputs) -> tuple[LoopState, LoopOutput]:
        active = ~s.done
        s, (err, odom) = jax.lax.scan(lambda c, _: frame(params, inputs, c), s, None, length=config.frames_per_tick)
        m, G = inputs.nav_map, config.n_goals
        k = jnp.minimum(s.goal, G - 1)
        gid = inputs.goal_ids[k]
        goal = m.table.goals[gid]
        key, k_nav = jax.random.split(s.key)
        plan = jax.lax.cond(
            inputs.replan, lambda: nav.plan_to(params.nav, m.grid, m.table, gid, s.pose), lambda: s.nav.plan
        )
        nav_state, out = nav.step(
            params.nav,
            nav.NavState(controller=s.nav.controller, plan=plan),
            nav.NavInputs(pose=s.pose, goal=goal, grid=m.grid, key=k_nav),
        )

        t, truth = s.body.sim.t, body.true_pose(s.body.sim)
        d_xy, d_yaw = pose_error(truth, goal)
        on_goal = (d_xy <= params.success_xy) & (d_yaw <= params.success_yaw)
        ended = jnp.select(
            [
                s.body.sim.collided,
                s.body.sim.fallen,
                s.lost_for >= params.lost_time - 0.5 * frame_dt,
                out.arrived,
                t - s.attempt_start > s.limit,
            ],
            [COLLIDED, FALLEN, LOST, jnp.where(on_goal, REACHED, MISSED), TIMEOUT],
            PENDING,
        )
        ended = jnp.where(active, ended, PENDING)
        finish = ended != PENDING
        terminal = (ended == COLLIDED) | (ended == FALLEN) | (ended == LOST)
        at_k = jnp.arange(G) == k
        outcome = jnp.where(finish & at_k, ended, s.outcome)
        outcome = jnp.where(terminal & (jnp.arange(G) > k), SKIPPED, outcome)
        elapsed = jnp.where(finish & at_k, t - s.attempt_start, s.elapsed)
        end_error = jnp.where((finish & at_k)[:, None], jnp.stack([d_xy, d_yaw]), s.end_error)
        goal_idx = jnp.where(terminal, G, jnp.where(finish, s.goal + 1, s.goal))
        done = s.done | (goal_idx >= G)
        next_gid = inputs.goal_ids[jnp.minimum(goal_idx, G - 1)]
        # A new goal: MPPI restarts, and until the next replan it drives on the goal critics (no plan).
        fresh = nav.init(params.nav, s.pose)
        nav_state = jax.tree.map(lambda a, b: jnp.where(finish, a, b), fresh, nav_state)
        cmd = jnp.where(done | finish, 0.0, out.cmd)
        s = dataclasses.replace(
            s,
            nav=nav_state,
            cmd=cmd,
            goal=goal_idx.astype(jnp.int32),
            outcome=outcome,
            elapsed=elapsed,
            end_error=end_error,
            done=done,
            key=key,
            attempt_start=jnp.where(finish, t, s.attempt_start),
            limit=jnp.where(finish, time_limit(params, m, next_gid, s.pose), s.limit),
        )
        return s, LoopOutput(
            t=t,
            true_pose=truth,
            pose=s.pose,
            odom=odom[-1],
            loc_error=err,
            goal=k,
            active=active,
            recovering=out.recovering & active,
            cmd=cmd,
        )

    return LoopFunctions(init=init, tick=tick)
