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
import numpy as np
from jaxtyping import Array, Bool, Float, Int, PRNGKeyArray

from jaxquad import vo
from jaxquad.estimate.inputs import R_base_imu
from jaxquad.estimate.pipeline import PipelineConfig, PipelineParams, PipelineSample, pipeline_init, pipeline_step
from jaxquad.kernels.costmap import CostGrid
from jaxquad.kernels.footprint import footprint_overlaps
from jaxquad.kernels.lie import SE3, SO3, roll_pitch, wrap_angle, yaw_of
from jaxquad.kernels.likelihood_field import LikelihoodField
from jaxquad.kernels.particle_filter import AmclInputs, AmclParams, AmclState, amcl_init, amcl_step
from jaxquad.kernels.scan import CameraIntrinsics, baseline_scan, stabilized_scan
from jaxquad.nav import navigate as nav

OUTCOMES = ("pending", "reached", "missed", "collided", "lost", "timeout", "fallen", "skipped")
PENDING, REACHED, MISSED, COLLIDED, LOST, TIMEOUT, FALLEN, SKIPPED = range(len(OUTCOMES))
ODOMETRY = ("leg", "visual")
SCANS = ("stabilized", "baseline")


@dataclasses.dataclass(frozen=True)
class LoopConfig:
    """Static choices (they select code)."""

    odometry: str = "leg"  # "leg": leg-inertial odometry; "visual": depth VO with a constant-velocity guess
    scans: str = "stabilized"  # "stabilized": IMU-levelled band; "baseline": fixed image rows
    n_goals: int = 5
    frames_per_tick: int = 3
    band_height: int = 1  # scan band rows (the authors' simulation used 5: the minimum over noisy rows reads short)
    contacts: str = "truth"  # the estimator's contact source (the paper's simulations: ground truth)
    n_particles: int = 2000  # AMCL particles per robot

    def __post_init__(self):
        if self.odometry not in ODOMETRY:
            raise ValueError(f"odometry must be one of {ODOMETRY}, got {self.odometry!r}")
        if self.scans not in SCANS:
            raise ValueError(f"scans must be one of {SCANS}, got {self.scans!r}")
        if self.contacts not in ("truth", "mixed"):
            raise ValueError(f"contacts must be 'truth' or 'mixed', got {self.contacts!r}")
        for name in ("n_goals", "frames_per_tick", "band_height", "n_particles"):
            if int(getattr(self, name)) < 1:
                raise ValueError(f"{name} must be >= 1, got {getattr(self, name)}")


class LoopParams(eqx.Module):
    """Tunable numbers of the loop (traced leaves; the sub-parameters carry their own static sizes)."""

    nav: nav.NavParams
    amcl: AmclParams
    pipeline: PipelineParams
    vo: vo.VoParams | None  # with odometry="visual"
    intrinsics: CameraIntrinsics
    range_min: Float[Array, ""]  # m, scan limits
    range_max: Float[Array, ""]
    footprint_center: Float[Array, " 2"]  # m, centre of the robot's footprint rectangle in the base frame
    footprint_half: Float[Array, " 2"]  # m, its half length and width
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
    sim: object  # sim.RobotState
    est: object  # estimate.PipelineState
    vo: object  # vo.VoState, or None
    R_gyro: Float[Array, "3 3"]  # IMU rotation integrated since the last frame (visual odometry's prior)
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


def _planar(p, q) -> Float[Array, " 3"]:
    return jnp.stack([p[0], p[1], yaw_of(q)])


def _pose_error(a, b) -> tuple[Float[Array, ""], Float[Array, ""]]:
    return jnp.hypot(a[0] - b[0], a[1] - b[1]), jnp.abs(wrap_angle(a[2] - b[2]))


def make_loop(fleet, config: LoopConfig) -> LoopFunctions:
    """The loop's pure functions for `fleet` (a `jaxquad.sim.Fleet` with depth; static parts closed over)."""
    fns, robot = fleet.functions, fleet.robot
    if not fleet.config.depth:
        raise ValueError("the closed loop needs the depth camera (FleetConfig.depth=True)")
    pcfg = PipelineConfig(contacts=config.contacts, has_qd=True, has_attitude=True)
    log_dt, logs_per_frame, log_every = float(fleet.log_dt), int(fleet.logs_per_frame), int(fleet.config.log_every)
    frame_dt = float(fleet.frame_dt)
    T_bc = np.asarray(fleet.T_base_camera, np.float64)
    R_imu_cam = jnp.asarray(np.asarray(R_base_imu(robot)).T @ T_bc[:3, :3], jnp.float32)
    visual = config.odometry == "visual"

    def physics(model, setup, s, cmd):
        return jax.lax.fori_loop(0, log_every, lambda _, r: fns.drive(model, setup, r, cmd), s)

    def estimator_sample(smp: dict, dt) -> PipelineSample:
        return PipelineSample(
            dt=jnp.asarray(dt, jnp.float32),
            q=smp["q"],
            qd=smp["qd"],
            tau=smp["tau"],
            gyro=smp["gyro"],
            acc=smp["acc"],
            quat_wxyz=smp["quat_wxyz"],
            contact_weight=smp["gt_contact"].astype(jnp.float32),
            valid=smp["valid"],
        )

    def true_pose(sim) -> Float[Array, " 3"]:
        q = sim.data.qpos[robot.base_qpos_adr : robot.base_qpos_adr + 7]
        return _planar(q[:3], q[3:])

    def scan_of(params: LoopParams, est, depth):
        if config.scans == "stabilized":
            roll, pitch = roll_pitch(est.pose.q_world_base)
            return stabilized_scan(
                depth, params.intrinsics, roll, pitch, config.band_height, params.range_min, params.range_max
            )
        return baseline_scan(depth, params.intrinsics, config.band_height, params.range_min, params.range_max)

    def leg_T(est) -> Float[Array, "4 4"]:
        return SE3.from_rotation_and_translation(SO3(est.pose.q_world_base), est.pose.p_world_base).as_matrix()

    def odometry(params: LoopParams, s: LoopState, depth):
        """(vo state, planar odometry pose) at a frame."""
        if not visual:
            return None, _planar(s.est.pose.p_world_base, s.est.pose.q_world_base)
        R_cam = R_imu_cam.T @ s.R_gyro @ R_imu_cam
        vo_state, out = vo.step(
            params.vo, s.vo, vo.VoInputs(depth=depth, R_prev_cur_gyro=R_cam, T_world_base_leg=leg_T(s.est))
        )
        return vo_state, _planar(out.T_world_base[:3, 3], SO3.from_matrix(out.T_world_base[:3, :3]).wxyz)

    def time_limit(params: LoopParams, m: NavMap, gid, pose):
        rc = m.grid.cell_of(pose[:2])
        h, w = m.table.weight.shape
        v = m.table.value[gid, jnp.clip(rc[0], 0, h - 1), jnp.clip(rc[1], 0, w - 1)]
        length = jnp.where(jnp.isfinite(v), v * m.grid.resolution, 0.0)
        return params.timeout_base + length / params.timeout_speed

    def init(params: LoopParams, inputs: LoopInputs, qpos0, key) -> LoopState:
        k_sim, k_amcl, k_step, key = jax.random.split(key, 4)
        sim = fns.init(inputs.model, inputs.setup, qpos0, k_sim)
        sim = physics(inputs.model, inputs.setup, sim, jnp.zeros(3))  # fills the derived quantities
        sim, smp = fns.sample(inputs.model, inputs.setup, sim)
        first = estimator_sample(smp, 0.0)
        gt = smp["gt_pose"]
        est = pipeline_init(robot, pcfg, params.pipeline, first, gt[:3], yaw_of(gt[3:]))
        est, _ = pipeline_step(robot, pcfg, params.pipeline, est, first)
        sim, depth = fns.camera(inputs.model, inputs.setup, sim)
        start = true_pose(sim)
        # The operator gives AMCL the start pose (AMCL then spreads its particles around it).
        amcl = amcl_init(params.amcl, inputs.nav_map.field, start, k_amcl, config.n_particles)
        odom = _planar(est.pose.p_world_base, est.pose.q_world_base)
        vo_state = vo.init(params.vo, depth, leg_T(est)) if visual else None
        scan = scan_of(params, est, depth)
        amcl, out = amcl_step(
            params.amcl, inputs.nav_map.field, amcl, AmclInputs(odom, scan.ranges, scan.bearings, k_step)
        )
        G = config.n_goals
        return LoopState(
            sim=sim,
            est=est,
            vo=vo_state,
            R_gyro=jnp.eye(3),
            amcl=amcl,
            pose=out.pose,
            nav=nav.init(params.nav, out.pose),
            cmd=jnp.zeros(3),
            goal=jnp.zeros((), jnp.int32),
            attempt_start=sim.t,
            limit=time_limit(params, inputs.nav_map, inputs.goal_ids[0], out.pose),
            outcome=jnp.zeros(G, jnp.int32),
            elapsed=jnp.full(G, jnp.nan),
            end_error=jnp.full((G, 2), jnp.nan),
            lost_for=jnp.zeros(()),
            done=jnp.zeros((), bool),
            key=key,
        )

    def frame(params: LoopParams, inputs: LoopInputs, s: LoopState):
        def sample_period(s: LoopState, _):
            sim = physics(inputs.model, inputs.setup, s.sim, s.cmd)
            sim, smp = fns.sample(inputs.model, inputs.setup, sim)
            est, _ = pipeline_step(robot, pcfg, params.pipeline, s.est, estimator_sample(smp, log_dt))
            g = jnp.where(jnp.isfinite(smp["gyro"]), smp["gyro"], 0.0)
            R_gyro = s.R_gyro @ SO3.exp(g * log_dt).as_matrix() if visual else s.R_gyro
            return dataclasses.replace(s, sim=sim, est=est, R_gyro=R_gyro), None

        s, _ = jax.lax.scan(sample_period, s, None, length=logs_per_frame)
        sim, depth = fns.camera(inputs.model, inputs.setup, s.sim)
        vo_state, odom = odometry(params, s, depth)
        scan = scan_of(params, s.est, depth)
        key, k_amcl = jax.random.split(s.key)
        amcl, out = amcl_step(
            params.amcl, inputs.nav_map.field, s.amcl, AmclInputs(odom, scan.ranges, scan.bearings, k_amcl)
        )
        truth = true_pose(sim)
        err, _ = _pose_error(out.pose, truth)
        cy, sy = jnp.cos(truth[2]), jnp.sin(truth[2])
        fc = params.footprint_center
        center = truth[:2] + jnp.stack([cy * fc[0] - sy * fc[1], sy * fc[0] + cy * fc[1]])
        rect = jnp.concatenate([center, truth[2:]])
        hit = jnp.any(footprint_overlaps(inputs.setup.boxes, rect, params.footprint_half))
        sim = eqx.tree_at(lambda r: r.collided, sim, sim.collided | hit)
        lost_for = jnp.where(err > params.lost_error, s.lost_for + frame_dt, 0.0)
        s = dataclasses.replace(
            s, sim=sim, vo=vo_state, R_gyro=jnp.eye(3), amcl=amcl, pose=out.pose, lost_for=lost_for, key=key
        )
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

        t, truth = s.sim.t, true_pose(s.sim)
        d_xy, d_yaw = _pose_error(truth, goal)
        on_goal = (d_xy <= params.success_xy) & (d_yaw <= params.success_yaw)
        ended = jnp.select(
            [
                s.sim.collided,
                s.sim.fallen,
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
