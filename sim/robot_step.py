"""The pure single-robot functions of a fleet: physics step (route follower, gait controller,
mjx.step, fall and collision checks), log sample (IMU, encoders, torques, ground truth), camera frame
and chunk. `jaxquad.sim.fleet` vmaps and compiles them; closed-loop work calls the same functions.

Ground truth of the feet: `gt_force` (T, 4, 3) is the force of the floor (every contact of the
foot geom) on each foot, world frame, N: the constraint solver's contact forces, which are the
forces that moved the robot because the built-in models let the solver converge (see their
`<option>`; a one-iteration solver reports forces inconsistent with the motion). `gt_contact`
(T, 4) is load-bearing contact: the foot's total normal force exceeds `GT_CONTACT_MIN_FORCE`
(1 N). Geometric touch (penetration of the foot sphere) outlasts it by a few samples at lift-off,
when the soft contact is still compressed but no longer pushes.

One instant per sample: `mjx.step` computes the derived quantities (sensors, contacts and their
forces, actuator forces, camera poses) at the state it starts from and then integrates, so after a
step they describe the previous state. A sample therefore reports the joints and the base pose of
that state (`RobotState.qpos_sensed`, `qvel_sensed`), at time t - dt; reading the integrated qpos and
qvel instead put the gyro, accelerometer, contacts and camera one physics step (4 ms) behind them.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import NamedTuple

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Bool, Float, Int, PRNGKeyArray

from jaxquad.kernels.lie import yaw_of
from jaxquad.kernels.raycast import Boxes, cast_depth

from . import sensors as S
from .locomotion import GaitParams, GaitState, gait_init, gait_step
from .route_follow import RouteParams, RouteState, route_init, route_step

_MAX_TILT_COS = 0.5  # cos(60 deg)
GT_CONTACT_MIN_FORCE = 1.0  # N: normal force above which a foot counts as in contact (0.7% of go2's weight)
# MuJoCo cameras look along -z with +y up; the optical frame looks along +z with +y down.
_R_MJCAM_OPTICAL = np.diag([1.0, -1.0, -1.0])


class RobotState(eqx.Module):
    """State of one robot between physics steps."""

    data: object  # mjx.Data
    # qpos, qvel at which `data`'s derived quantities were computed (the last step's starting state)
    qpos_sensed: Float[Array, " nq"]
    qvel_sensed: Float[Array, " nv"]
    gait: GaitState
    route: RouteState
    imu: S.ImuState
    key: PRNGKeyArray
    t: Float[Array, ""]  # s
    fallen: Bool[Array, ""]
    collided: Bool[Array, ""]
    fall_step: Int[Array, ""]  # physics step of the fall, -1 while upright


class RobotSetup(eqx.Module):
    """Per-robot constants of a run (vmapped with the state)."""

    gait_params: GaitParams
    route_params: RouteParams
    noise: S.SensorNoise
    waypoints: Float[Array, "K 2"]
    boxes: Boxes


class FleetFunctions(NamedTuple):
    """Pure single-robot functions of a fleet (vmap them with `Fleet.model_in_axes` for the model)."""

    init: Callable  # (model, setup, qpos0, key) -> RobotState
    physics_step: Callable  # (model, setup, state) -> state: route follower, then `drive`
    sample: Callable  # (model, setup, state) -> (state, per-sample sensor and ground-truth dict)
    frame: Callable  # (model, setup, state) -> (state, samples of one camera period [, depth image])
    chunk: Callable  # (model, setup, state, frames) -> (state, samples of `frames` camera periods)
    drive: Callable  # (model, setup, state, cmd) -> state: gait controller on a body command, mjx.step, falls
    camera: Callable  # (model, setup, state) -> (state, depth image (H, W) m): one depth frame now


def make_functions(fleet, gyro_adr: int, acc_adr: int) -> FleetFunctions:
    """The pure functions of `fleet` (a `jaxquad.sim.fleet.Fleet`; its static parts are closed over)."""
    from mujoco.mjx._src.support import contact_force  # not re-exported by mjx

    from jaxquad._mjx import mjx

    robot, gait, cfg = fleet.robot, fleet.gait, fleet.config
    dt = jnp.float32(fleet.dt)
    qa = robot.base_qpos_adr
    qpos_adr, dof_adr = np.asarray(robot.qpos_adr), np.asarray(robot.dof_adr)
    foot_geoms = jnp.asarray(robot.foot_geom_ids)
    min_height = 0.5 * float(gait.body_height)
    rays = jnp.asarray(fleet.rays)
    # Only static numbers are closed over, never `fleet` itself (its arrays would stay alive with the cache).
    log_dt, logs_per_frame = fleet.log_dt, fleet.logs_per_frame
    cam_id = robot.camera_id

    def init_one(model, setup: RobotSetup, qpos, key) -> RobotState:
        # Derived quantities (sensors, camera pose) are filled by the first physics step.
        data = mjx.make_data(model).replace(qpos=qpos)
        k_imu, key = jax.random.split(key)
        return RobotState(
            data=data,
            qpos_sensed=data.qpos,
            qvel_sensed=data.qvel,
            gait=gait_init(gait, setup.gait_params),
            route=route_init(setup.waypoints, qpos[qa : qa + 2]),
            imu=S.imu_init(setup.noise, k_imu),
            key=key,
            t=jnp.zeros(()),
            fallen=jnp.zeros((), bool),
            collided=jnp.zeros((), bool),
            fall_step=jnp.full((), -1, jnp.int32),
        )

    def physics_step(model, setup: RobotSetup, s: RobotState) -> RobotState:
        d = s.data
        yaw = yaw_of(d.qpos[qa + 3 : qa + 7])
        pose = jnp.stack([d.qpos[qa], d.qpos[qa + 1], yaw])
        route, (cmd, _) = route_step(setup.route_params, s.route, setup.waypoints, pose)
        new = drive(model, setup, s, cmd)
        route = jax.tree_util.tree_map(lambda old, r: jnp.where(new.fallen, old, r), s.route, route)
        return eqx.tree_at(lambda r: r.route, new, route)

    def drive(model, setup: RobotSetup, s: RobotState, cmd: Float[Array, " 3"]) -> RobotState:
        d = s.data
        g, tau = gait_step(gait, setup.gait_params, s.gait, d.qpos, d.qvel, cmd, s.t, dt)
        d_new = mjx.step(model, d.replace(ctrl=tau))
        w, x, y, _ = d_new.qpos[qa + 3 : qa + 7]
        up_z = 1 - 2 * (x * x + y * y)  # world z of the base's z axis
        finite = jnp.all(jnp.isfinite(d_new.qpos)) & jnp.all(jnp.isfinite(d_new.qvel))
        down = ~finite | (d_new.qpos[qa + 2] < min_height) | (up_z < _MAX_TILT_COS)
        fallen = s.fallen | down
        # Freeze a fallen robot: keep its last valid state (a non-finite one never enters).
        keep = lambda old, new: jnp.where(fallen, old, new)  # noqa: E731
        step_no = jnp.round(s.t / dt).astype(jnp.int32)
        return RobotState(
            data=jax.tree_util.tree_map(keep, d, d_new),
            qpos_sensed=keep(s.qpos_sensed, d.qpos),
            qvel_sensed=keep(s.qvel_sensed, d.qvel),
            gait=jax.tree_util.tree_map(keep, s.gait, g),
            route=s.route,
            imu=s.imu,
            key=s.key,
            t=s.t + dt,
            fallen=fallen,
            collided=s.collided,
            fall_step=jnp.where(down & ~s.fallen, step_no + 1, s.fall_step),
        )

    def sample(model, setup: RobotSetup, s: RobotState) -> tuple[RobotState, dict]:
        d, qpos, qvel = s.data, s.qpos_sensed, s.qvel_sensed  # one instant (module docstring)
        key, k_imu, k_enc, k_tau = jax.random.split(s.key, 4)
        quat = qpos[qa + 3 : qa + 7]
        imu, (gyro, acc, quat_meas) = S.imu_step(
            setup.noise,
            s.imu,
            k_imu,
            d.sensordata[gyro_adr : gyro_adr + 3],
            d.sensordata[acc_adr : acc_adr + 3],
            quat,
            log_dt,
        )
        q, qd = S.encoders(setup.noise, k_enc, qpos[qpos_adr], qvel[dof_adr])
        tau = S.joint_torque(setup.noise, k_tau, d.actuator_force)
        # Force of each contact in its frame (normal first; the normal points from geom 0 to geom 1)
        # and in the world frame; summed per foot with the sign of the force on the foot geom.
        con = d._impl.contact
        f_con = jnp.stack([contact_force(model, d, i)[:3] for i in range(con.geom.shape[0])])
        f_world = jnp.einsum("ci,cij->cj", f_con, con.frame)
        sign = jnp.where(con.geom[:, 1:2] == foot_geoms[None], 1.0, 0.0) - jnp.where(
            con.geom[:, 0:1] == foot_geoms[None], 1.0, 0.0
        )
        gt_force = jnp.einsum("cf,cj->fj", sign, f_world)
        contact = jnp.abs(sign).T @ f_con[:, 0] > GT_CONTACT_MIN_FORCE
        xy = qpos[qa : qa + 2]
        inside = _inside_any_box(setup.boxes, xy)
        s = eqx.tree_at(lambda r: (r.imu, r.key, r.collided), s, (imu, key, s.collided | inside))
        out = dict(
            q=q,
            qd=qd,
            tau=tau,
            gyro=gyro,
            acc=acc,
            quat_wxyz=quat_meas,
            gt_pose=jnp.concatenate([qpos[qa : qa + 3], quat]),
            gt_contact=contact,
            gt_force=gt_force,
            valid=~s.fallen,
        )
        return s, out

    def frame(model, setup: RobotSetup, s: RobotState):
        def log_period(s, _):
            s = jax.lax.fori_loop(0, cfg.log_every, lambda _, s: physics_step(model, setup, s), s)
            return sample(model, setup, s)

        s, outs = jax.lax.scan(log_period, s, None, length=logs_per_frame)
        if not cfg.depth:
            return s, outs
        s, depth = camera(model, setup, s)
        return s, (outs, depth)

    def camera(model, setup: RobotSetup, s: RobotState):
        d = s.data
        R_world_cam = d.cam_xmat[cam_id] @ jnp.asarray(_R_MJCAM_OPTICAL, jnp.float32)
        depth_true = cast_depth(d.cam_xpos[cam_id], R_world_cam, rays, setup.boxes)
        key, k_depth = jax.random.split(s.key)
        depth = S.depth_camera(setup.noise, k_depth, depth_true, rays)
        return eqx.tree_at(lambda r: r.key, s, key), depth

    def chunk_one(model, setup: RobotSetup, s: RobotState, frames: int):
        s, outs = jax.lax.scan(lambda s, _: frame(model, setup, s), s, None, length=frames)
        if cfg.depth:
            outs, depth = outs
            outs = dict(outs, depth=depth)
        # (frames, logs_per_frame, ...) -> (samples, ...)
        outs = {k: (v if k == "depth" else v.reshape((-1,) + v.shape[2:])) for k, v in outs.items()}
        return s, outs

    return FleetFunctions(init_one, physics_step, sample, frame, chunk_one, drive, camera)


def _inside_any_box(boxes: Boxes, xy: Float[Array, " 2"]) -> Bool[Array, ""]:
    p = xy - boxes.center[:, :2]
    c, s = jnp.cos(boxes.yaw), jnp.sin(boxes.yaw)
    lx, ly = c * p[:, 0] + s * p[:, 1], -s * p[:, 0] + c * p[:, 1]
    return jnp.any((jnp.abs(lx) < boxes.half[:, 0]) & (jnp.abs(ly) < boxes.half[:, 1]))
