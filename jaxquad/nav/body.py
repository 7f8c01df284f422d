"""The robot's side of a closed loop, shared by navigation (`jaxquad.nav.closed_loop`) and exploration
(`jaxquad.explore.loop`): the simulated robot walking on a body command, what it estimates on board,
and what the truth says of it.

Per camera frame (`frame`): the simulator's sample periods (physics at its steps, one estimator step
per sample: leg-inertial odometry), then the depth image, the odometry pose at the frame (the leg
odometry, or depth visual odometry with the gyro's rotation since the last frame as its prior) and the
frame's scan (`scan`: an IMU-stabilized band or the fixed-row baseline). Ground truth is read only to
judge (`true_pose`, `judge_collision`: the base footprint overlapping a world box; the boxes are not
in the physics model).

`body, depth = start(params, model, setup, qpos0, key)`, `body, depth, odom = frame(params, model, setup,
body, cmd)`: one robot, pure; the loops `vmap` them over robots.
"""

from __future__ import annotations

import dataclasses
from typing import NamedTuple

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Bool, Float

from jaxquad import vo
from jaxquad.estimate.inputs import R_base_imu
from jaxquad.estimate.pipeline import PipelineConfig, PipelineParams, PipelineSample, pipeline_init, pipeline_step
from jaxquad.kernels.footprint import footprint_overlaps
from jaxquad.kernels.lie import SE3, SO3, roll_pitch, wrap_angle, yaw_of
from jaxquad.kernels.scan import CameraIntrinsics, baseline_scan, stabilized_scan

ODOMETRY = ("leg", "visual")
SCANS = ("stabilized", "baseline")


class BodyParams(eqx.Module):
    """Numbers of the robot's on-board estimation and of the judge (traced leaves)."""

    pipeline: PipelineParams
    vo: vo.VoParams | None  # with odometry="visual"
    intrinsics: CameraIntrinsics
    range_min: Float[Array, ""]  # m, scan limits
    range_max: Float[Array, ""]
    footprint_center: Float[Array, " 2"]  # m, centre of the robot's footprint rectangle in the base frame
    footprint_half: Float[Array, " 2"]  # m, its half length and width


class Body(eqx.Module):
    sim: object  # sim.RobotState
    est: object  # estimate.PipelineState
    vo: object  # vo.VoState, or None
    R_gyro: Float[Array, "3 3"]  # IMU rotation integrated since the last frame (visual odometry's prior)
    v_base: Float[Array, " 3"]  # m/s, leg-odometry velocity at the last sample, base frame
    omega_base: Float[Array, " 3"]  # rad/s
    cov_v_base: Float[Array, "3 3"]  # (m/s)^2, covariance of v_base
    valid: Bool[Array, ""]  # the last sample was valid and the estimator has not flagged a fall


class BodyFunctions(NamedTuple):
    start: object  # (params, model, setup, qpos0, key) -> (Body, depth)
    frame: object  # (params, model, setup, Body, cmd) -> (Body, depth, odom)
    scan: object  # (params, PipelineState, depth) -> kernels.scan.Scan
    true_pose: object  # (sim) -> (3,)
    judge_collision: object  # (params, setup, sim) -> sim with `collided` updated
    leg_pose: object  # (PipelineState) -> (3,) planar leg-odometry pose


def planar(p, q) -> Float[Array, " 3"]:
    return jnp.stack([p[0], p[1], yaw_of(q)])


def pose_error(a, b) -> tuple[Float[Array, ""], Float[Array, ""]]:
    """Position (m) and absolute heading (rad) differences of two planar poses."""
    return jnp.hypot(a[0] - b[0], a[1] - b[1]), jnp.abs(wrap_angle(a[2] - b[2]))


def make_body(
    fleet, odometry: str, scans: str, band_height: int, contacts: str, band_reduce: str = "median"
) -> BodyFunctions:
    """The body functions for `fleet` (a `jaxquad.sim.Fleet` with depth; static parts closed over)."""
    if odometry not in ODOMETRY:
        raise ValueError(f"odometry must be one of {ODOMETRY}, got {odometry!r}")
    if scans not in SCANS:
        raise ValueError(f"scans must be one of {SCANS}, got {scans!r}")
    if not fleet.config.depth:
        raise ValueError("the closed loop needs the depth camera (FleetConfig.depth=True)")
    fns, robot = fleet.functions, fleet.robot
    pcfg = PipelineConfig(contacts=contacts, has_qd=True, has_attitude=True)
    log_dt, logs_per_frame, log_every = float(fleet.log_dt), int(fleet.logs_per_frame), int(fleet.config.log_every)
    T_bc = np.asarray(fleet.T_base_camera, np.float64)
    R_imu_cam = jnp.asarray(np.asarray(R_base_imu(robot)).T @ T_bc[:3, :3], jnp.float32)
    visual = odometry == "visual"

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
        return planar(q[:3], q[3:])

    def leg_pose(est) -> Float[Array, " 3"]:
        return planar(est.pose.p_world_base, est.pose.q_world_base)

    def scan(params: BodyParams, est, depth):
        if scans == "stabilized":
            roll, pitch = roll_pitch(est.pose.q_world_base)
            return stabilized_scan(
                depth, params.intrinsics, roll, pitch, band_height, params.range_min, params.range_max, band_reduce
            )
        return baseline_scan(depth, params.intrinsics, band_height, params.range_min, params.range_max, band_reduce)

    def leg_T(est) -> Float[Array, "4 4"]:
        return SE3.from_rotation_and_translation(SO3(est.pose.q_world_base), est.pose.p_world_base).as_matrix()

    def start(params: BodyParams, model, setup, qpos0, key) -> tuple[Body, Array]:
        sim = fns.init(model, setup, qpos0, key)
        sim = physics(model, setup, sim, jnp.zeros(3))  # fills the derived quantities
        sim, smp = fns.sample(model, setup, sim)
        first = estimator_sample(smp, 0.0)
        gt = smp["gt_pose"]
        est = pipeline_init(robot, pcfg, params.pipeline, first, gt[:3], yaw_of(gt[3:]))
        est, out = pipeline_step(robot, pcfg, params.pipeline, est, first)
        sim, depth = fns.camera(model, setup, sim)
        vo_state = vo.init(params.vo, depth, leg_T(est)) if visual else None
        body = Body(sim, est, vo_state, jnp.eye(3), out.v_base, out.omega_base, out.cov_v_base, _valid(smp, out))
        return body, depth

    def frame(params: BodyParams, model, setup, b: Body, cmd) -> tuple[Body, Array, Float[Array, " 3"]]:
        def sample_period(b: Body, _):
            sim = physics(model, setup, b.sim, cmd)
            sim, smp = fns.sample(model, setup, sim)
            est, out = pipeline_step(robot, pcfg, params.pipeline, b.est, estimator_sample(smp, log_dt))
            g = jnp.where(jnp.isfinite(smp["gyro"]), smp["gyro"], 0.0)
            R_gyro = b.R_gyro @ SO3.exp(g * log_dt).as_matrix() if visual else b.R_gyro
            b = dataclasses.replace(
                b,
                sim=sim,
                est=est,
                R_gyro=R_gyro,
                v_base=out.v_base,
                omega_base=out.omega_base,
                cov_v_base=out.cov_v_base,
                valid=_valid(smp, out),
            )
            return b, None

        b, _ = jax.lax.scan(sample_period, b, None, length=logs_per_frame)
        sim, depth = fns.camera(model, setup, b.sim)
        if visual:
            R_cam = R_imu_cam.T @ b.R_gyro @ R_imu_cam
            vo_state, out = vo.step(
                params.vo, b.vo, vo.VoInputs(depth=depth, R_prev_cur_gyro=R_cam, T_world_base_leg=leg_T(b.est))
            )
            odom = planar(out.T_world_base[:3, 3], SO3.from_matrix(out.T_world_base[:3, :3]).wxyz)
        else:
            vo_state, odom = None, leg_pose(b.est)
        return dataclasses.replace(b, sim=sim, vo=vo_state, R_gyro=jnp.eye(3)), depth, odom

    def judge_collision(params: BodyParams, setup, sim):
        truth = true_pose(sim)
        cy, sy = jnp.cos(truth[2]), jnp.sin(truth[2])
        fc = params.footprint_center
        center = truth[:2] + jnp.stack([cy * fc[0] - sy * fc[1], sy * fc[0] + cy * fc[1]])
        rect = jnp.concatenate([center, truth[2:]])
        hit = jnp.any(footprint_overlaps(setup.boxes, rect, params.footprint_half))
        return eqx.tree_at(lambda r: r.collided, sim, sim.collided | hit)

    return BodyFunctions(start, frame, scan, true_pose, judge_collision, leg_pose)


def _valid(smp: dict, out) -> Bool[Array, ""]:
    return smp["valid"] & ~out.flags.fallen
