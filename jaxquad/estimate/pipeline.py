"""The estimation pipeline over robot logs: contacts, leg-inertial odometry, one `lax.scan` per robot.

Per sample k (dt = t_k - t_{k-1}):
  1. joint velocities: the log's qd, or the causal differentiating filter on q;
  2. attitude: the Mahony filter on the gyro, corrected toward the log's quat_wxyz or, without one,
     by the accelerometer; its gyro-bias estimate is removed from the gyro used below;
  3. contacts: ground truth, the robot's sensor flags, or the momentum observer (plain or mixed;
     by default on the actuated joints' momentum rows, estimating full 3D foot forces and
     thresholding their z components, with the model's joint damping and friction in tau_bar:
     `jaxquad.dynamics.momentum_terms`);
  4. foot positions and velocities in the base frame from the MJX model (jaxquad.dynamics:
     forward kinematics and v_base_foot = J(q) qd), moved to the contact points of the round feet
     rolling on the floor (kernels.rolling_contact, `PipelineConfig.rolling`);
  5. the twist least squares on the stance feet and the gyro, reweighted against slipping feet
     (kernels.robust_body_twist, `PipelineConfig.robust`; each foot also against the previous
     sample's velocity, `robust_prior`), with its covariance and slip flags; a foot's weight ramps
     up over its first `settle_s` of stance (`PipelineConfig.settle`);
  6. the pose: the twist of sample k-1 integrated over dt on SE(3), orientation from step 2, height
     fused with the floor under the stance feet (kernels.floor, `PipelineConfig.floor`).

Bad data never reaches the trajectory as NaN; each case is flagged per sample (`Flags`):
non-finite joint readings hold the joint's last value; a non-finite gyro reading is replaced by the last
one, and a non-finite accelerometer reading or reported attitude does not correct the attitude;
saturated torques or non-finite torques skip the observer step (contacts held); a step with fewer
than `min_stance` feet or an invalid solve reuses the last good twist (its covariance that of the last
good one plus (`held_accel_std` x the time held)^2, unobserved across a gap or after a fall); a time
gap longer than `max_gap_s` is not integrated (pose held) and restarts the observer; a robot whose base
tilts past `fall_tilt_rad`, or whose input `valid` goes False, is marked fallen from then on and its pose
held.

`pipeline_init` / `pipeline_step` are one sample of one robot (`state, out = pipeline_step(..., state,
sample)`), what a closed loop calls as its sensors arrive; `estimate_robot` scans them over a log (params a
traced pytree, so it vmaps over parameter sets and differentiates w.r.t. observer numbers through soft
contacts); `estimate_fleet` is it jitted and vmapped over robots, compiled once per robot model and
configuration, with the robots split over the devices (`jaxquad.parallel`).
"""

from __future__ import annotations

import dataclasses
import functools

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from jaxquad import dynamics, parallel
from jaxquad.estimate import attitude as att
from jaxquad.estimate import differentiate as dif
from jaxquad.estimate.inputs import R_base_imu, RobotInputs, full_state, gaps, observer_rows, robot_inputs, torque_ok
from jaxquad.estimate.odometry import Pose, odometry_step
from jaxquad.estimate.pipeline_types import (
    Estimate,
    Flags,
    PipelineConfig,
    PipelineParams,
    PipelineSample,
    PipelineState,
)
from jaxquad.kernels import ContactEstimate, ContactObserver, ObserverParams, robust_body_twist, rolling_contact
from jaxquad.kernels import floor as flr
from jaxquad.kernels.lie import SO3, rotation_matrix
from jaxquad.kernels.twist import UNOBSERVED_VAR

# Stance time (s) of a foot already down when the log starts (it counts as settled); also the clock's cap.
_SETTLED_S = 1e3


def observer_params_for_axes(params: ObserverParams, axes: str) -> ObserverParams:
    """Observer numbers for force rows of `axes` per foot: for "xyz" every per-foot number is repeated
    for the x, y and z rows (row 3 f + a), as `dynamics.momentum_terms(..., axes="xyz")` orders them;
    only the z rows' post-processing is used (`vertical_estimate`)."""
    if axes == "z":
        return params
    rep = lambda x: jnp.repeat(x, 3, axis=-1)  # noqa: E731
    return dataclasses.replace(
        params, alpha=rep(params.alpha), threshold_on=rep(params.threshold_on), threshold_off=rep(params.threshold_off)
    )


def vertical_estimate(estimate: ContactEstimate, axes: str) -> ContactEstimate:
    """The z rows of an observer estimate over force rows of `axes` (a no-op for "z")."""
    if axes == "z":
        return estimate
    z = lambda x: x[..., 2::3]  # noqa: E731
    return dataclasses.replace(
        estimate,
        force_z=z(estimate.force_z),
        force_z_filtered=z(estimate.force_z_filtered),
        contact=z(estimate.contact),
        contact_soft=z(estimate.contact_soft),
    )


def _hold(ok, new, old):
    return jax.tree.map(lambda a, b: jnp.where(ok, a, b), new, old)


def pipeline_init(
    robot,
    config: PipelineConfig,
    params: PipelineParams,
    first: PipelineSample,
    p0_world_base: Float[Array, "3"],
    yaw0: Float[Array, ""],
) -> PipelineState:
    """The state before the first sample `first` (which `pipeline_step` then processes with dt = 0):
    joints and attitude from it, position `p0_world_base` (m) and, without an attitude input, heading
    `yaw0` (rad)."""
    n_feet = len(robot.foot_names)
    R_imu = jnp.asarray(R_base_imu(robot), dtype=first.gyro.dtype)
    q0 = jnp.where(jnp.isfinite(first.q), first.q, jnp.asarray(robot.q_home, first.q.dtype))
    if config.has_attitude:
        qa0 = first.quat_wxyz
        quat0 = jnp.where(jnp.all(jnp.isfinite(qa0)), qa0, jnp.array([1.0, 0.0, 0.0, 0.0]))
    else:
        quat0 = att.attitude_from_acc(R_imu @ first.acc)
        quat0 = (SO3.from_z_radians(yaw0) @ SO3(quat0)).wxyz
    quat0 = quat0 / jnp.linalg.norm(quat0)
    if config.contacts in ("observer", "mixed"):
        obs_params = observer_params_for_axes(params.observer, config.observer_axes)
        n_force = n_feet * (3 if config.observer_axes == "xyz" else 1)
        n_rows = observer_rows(robot, config.observer_rows).size
        obs0 = ContactObserver().init(obs_params, jnp.zeros(n_rows, first.q.dtype), n_force)
    else:
        obs0 = None
    zeros3 = jnp.zeros(3, first.gyro.dtype)
    return PipelineState(
        diff=dif.init(q0),
        att=att.init(quat0),
        obs=obs0,
        pose=Pose(p_world_base=p0_world_base, q_world_base=quat0),
        q_last=q0,
        qd_last=jnp.zeros_like(q0),
        gyro_last=zeros3,
        weight_last=jnp.zeros(n_feet, first.gyro.dtype),
        stance_s=jnp.full(n_feet, _SETTLED_S, first.gyro.dtype),
        v_last=zeros3,
        omega_last=zeros3,
        cov_last=UNOBSERVED_VAR * jnp.eye(3, dtype=first.gyro.dtype),
        held_s=jnp.zeros((), first.gyro.dtype),
        fallen=jnp.asarray(False),
        floor=flr.floor_init(p0_world_base[2]),
    )


def pipeline_step(
    robot, config: PipelineConfig, params: PipelineParams, c: PipelineState, x: PipelineSample
) -> tuple[PipelineState, Estimate]:
    """One sample (steps 1-6 of the module doc); the Estimate's leaves have no time axis."""
    observer = config.contacts in ("observer", "mixed")
    n_feet = len(robot.foot_names)
    R_imu = jnp.asarray(R_base_imu(robot), dtype=x.gyro.dtype)
    rows = observer_rows(robot, config.observer_rows)
    obs_params = observer_params_for_axes(params.observer, config.observer_axes)
    dt, q, qd_in, tau, gyro_imu, acc_imu = x.dt, x.q, x.qd, x.tau, x.gyro, x.acc
    quat_in, w_in, valid_in = x.quat_wxyz, x.contact_weight, x.valid
    first, gap = gaps(dt, params.max_gap_s)  # sample 0: nothing to integrate
    dt_int = jnp.where(first | gap, 0.0, dt)

    # 1. joints: hold non-finite readings.
    q_ok = jnp.isfinite(q)
    q_use = jnp.where(q_ok, q, c.q_last)
    if config.has_qd:
        qd_ok = jnp.isfinite(qd_in)
        qd_use = jnp.where(qd_ok, qd_in, c.qd_last)
        diff_state = c.diff
        bad_joints = ~jnp.all(q_ok & qd_ok)
    else:
        diff_state, _ = dif.step(params.differentiator, c.diff, q, jnp.where(gap, 0.0, dt))
        qd_use = diff_state.qd
        bad_joints = ~jnp.all(q_ok)

    # 2. attitude.
    gyro_ok = jnp.all(jnp.isfinite(gyro_imu))
    gyro = jnp.where(gyro_ok, R_imu @ jnp.where(gyro_ok, gyro_imu, 0.0), c.gyro_last)
    acc = R_imu @ acc_imu
    if config.has_attitude:
        qa_ok = att.report_usable(quat_in)
        att_state, _ = att.step_toward(params.attitude_report, c.att, gyro, quat_in, dt_int)
        # Across a gap the gyro carried nothing: restart at the report.
        restart = gap & qa_ok
        att_state = eqx.tree_at(
            lambda s: s.q_world_base, att_state, jnp.where(restart, quat_in, att_state.q_world_base)
        )
        bad_imu = ~(qa_ok & gyro_ok)
        # A fall shows at once in the report; the filter follows it within about 1 / kp.
        up_z = jnp.where(qa_ok, rotation_matrix(jnp.where(qa_ok, quat_in, 1.0))[2, 2], 1.0)
    else:
        att_state, used = att.step(params.attitude, c.att, gyro, acc, dt_int)
        bad_imu = ~(used[0] | first) | ~jnp.all(jnp.isfinite(acc_imu))
        up_z = 1.0
    quat = att_state.q_world_base / jnp.linalg.norm(att_state.q_world_base)
    omega_imu = gyro - att_state.gyro_bias  # the filter's bias estimate removed
    R_world_base = rotation_matrix(quat)
    up_z = jnp.minimum(up_z, R_world_base[2, 2])  # world z of the base's z axis
    fallen = c.fallen | ~valid_in | (up_z < jnp.cos(params.fall_tilt_rad))

    # 3. contacts.
    tau_ok = torque_ok(robot, tau, params.torque_saturation)
    # Full state for the model: base velocity from the last twist (world linear, body angular).
    qpos, qvel = full_state(robot, c.pose.p_world_base, quat, q_use, R_world_base @ c.v_last, omega_imu, qd_use)
    if observer:
        tau_obs = jnp.where(tau_ok, tau, 0.0)
        p_mom, tau_bar, J_z = dynamics.momentum_terms(
            robot, qpos, qvel, tau_obs, passive=config.observer_passive, axes=config.observer_axes
        )
        p_mom, tau_bar, J_z = p_mom[rows], tau_bar[rows], J_z[:, rows]
        obs_prev = jax.tree.map(lambda a: a, c.obs)
        # After a gap the momentum residual is meaningless: restart the estimate at p.
        obs_prev = eqx.tree_at(lambda s: s.p_hat, obs_prev, jnp.where(gap | first, p_mom, obs_prev.p_hat))
        obs_dt = jnp.where(tau_ok & ~gap & ~first, dt, jnp.nan)  # NaN dt: the step is rejected (held)
        obs_state, est = ContactObserver().step(obs_params, obs_prev, p_mom, tau_bar, J_z, obs_dt)
        est = vertical_estimate(est, config.observer_axes)
        contact, contact_soft = est.contact, est.contact_soft
        force_z, force_f = est.force_z, est.force_z_filtered
        weight = contact_soft if config.soft_contacts else contact.astype(contact_soft.dtype)
    else:
        obs_state = None
        w_ok = jnp.isfinite(w_in)
        weight = jnp.where(w_ok, jnp.clip(w_in, 0.0, 1.0), c.weight_last)
        contact, contact_soft = weight > 0.5, weight
        force_z = force_f = jnp.zeros_like(weight)

    # A foot that has just touched down still slides (simulated: up to 0.47 m/s on its first sample, which
    # reads as a slower base): its twist weight ramps up over its first settle_s of stance.
    stance_s = jnp.where(contact, jnp.minimum(c.stance_s + dt_int, _SETTLED_S), 0.0)
    settled = jnp.clip(stance_s / jnp.maximum(params.settle_s, 1e-6), 0.0, 1.0)
    w_twist = weight * settled if config.settle else weight

    # 4-5. kinematics and twist.
    legs = dynamics.leg_kinematics(robot, qpos, qvel)
    radius = jnp.asarray(robot.foot_radius if config.rolling else np.zeros(n_feet), qpos.dtype)
    n_floor = R_world_base[2]  # the world's up axis in base axes: the normal of a level floor
    p_foot, v_foot = rolling_contact(legs.p_base_foot, legs.v_base_foot, legs.omega_base_foot, radius, n_floor)
    rob = robust_body_twist(
        p_foot,
        v_foot,
        omega_imu,
        w_twist,
        params.imu_weight,
        params.min_stance,
        params.robust_scale,
        0.5,
        params.sigma_prior,
        params.prior_dof,
        n_iter=config.robust_iters if config.robust != "none" else 0,
        loss="huber" if config.robust == "none" else config.robust,
        v_prior=c.v_last if config.robust_prior else None,
    )
    tw = rob.twist
    tw_ok = tw.valid & tw.linear_observed
    v_base = jnp.where(tw_ok, tw.v_base, c.v_last)
    # A held twist is as good as the last observed one, less what the base may have accelerated since
    # (the solve's own covariance without stance says nothing about the held value). Held across a
    # time gap (of unknown length) or zeroed by a fall, nothing measured it.
    held_s = jnp.where(tw_ok, 0.0, c.held_s + dt_int)
    eye3 = jnp.eye(3, dtype=c.cov_last.dtype)
    cov_last = jnp.where(tw_ok, tw.cov_v_base, jnp.where(gap, UNOBSERVED_VAR * eye3, c.cov_last))
    cov_v_base = cov_last + (params.held_accel_std * held_s) ** 2 * eye3
    omega = jnp.where(tw_ok, tw.omega_base, omega_imu)

    # 6. pose: the previous sample's twist over dt; held once fallen.
    moved = odometry_step(c.pose, c.v_last, c.omega_last, dt_int, quat)
    if config.floor:
        h, n_h = flr.stance_height(p_foot, R_world_base, weight)
        dz = moved.p_world_base[2] - c.pose.p_world_base[2]
        # Across a gap the pose is held, the floor update too.
        floor_state = flr.floor_step(params.floor, c.floor, dz, dt_int, h, jnp.where(gap, 0.0, n_h))
        moved = Pose(p_world_base=moved.p_world_base.at[2].set(floor_state.z), q_world_base=moved.q_world_base)
    else:
        floor_state = c.floor
    pose = _hold(~fallen, moved, c.pose)

    new = PipelineState(
        diff=diff_state,
        att=att_state,
        obs=obs_state,
        pose=pose,
        q_last=q_use,
        qd_last=qd_use,
        gyro_last=gyro,
        weight_last=weight,
        stance_s=stance_s,
        v_last=jnp.where(fallen, 0.0, v_base),
        omega_last=jnp.where(fallen, 0.0, omega),
        cov_last=jnp.where(fallen, UNOBSERVED_VAR * eye3, cov_last),
        held_s=held_s,
        fallen=fallen,
        floor=_hold(~fallen, floor_state, c.floor),
    )
    flags = Flags(
        bad_joints=bad_joints,
        bad_imu=bad_imu,
        bad_torque=~tau_ok if observer else jnp.asarray(False),
        gap=gap,
        no_stance=~tw_ok,
        fallen=fallen,
    )
    out = Estimate(
        p_world_base=pose.p_world_base,
        q_world_base=pose.q_world_base,
        v_base=v_base,
        omega_base=omega,
        contact=contact,
        contact_soft=contact_soft,
        force_z=force_z,
        force_z_filtered=force_f,
        qd=qd_use,
        cov_v_base=cov_v_base,
        twist_weight=w_twist,
        slip=rob.slip,
        flags=flags,
    )
    return new, out


def estimate_robot(robot, config: PipelineConfig, params: PipelineParams, inputs: RobotInputs) -> Estimate:
    """Run the pipeline over one robot's inputs (pure; jit and vmap at the call site)."""
    # The rows of `inputs` enter the scan as a dict; each step builds its one-sample PipelineSample.
    rows = {name: getattr(inputs, name) for name in PipelineSample.__dataclass_fields__}
    first = PipelineSample(**jax.tree.map(lambda a: a[0], rows))
    state = pipeline_init(robot, config, params, first, inputs.p0_world_base, inputs.yaw0)
    _, out = jax.lax.scan(lambda c, r: pipeline_step(robot, config, params, c, PipelineSample(**r)), state, rows)
    return out


@functools.lru_cache(maxsize=8)
def _compiled(robot, config: PipelineConfig, axes: tuple, mesh):
    fn = jax.vmap(functools.partial(estimate_robot, robot, config), in_axes=axes)
    return jax.jit(parallel.shard_batched(fn, mesh, axes, 0))


def estimate_fleet(
    robot,
    config: PipelineConfig,
    params: PipelineParams,
    inputs: RobotInputs,
    batched_params: bool = False,
    devices: int | None = None,
) -> Estimate:
    """`estimate_robot` over N robots (inputs with a leading axis N), jitted once per robot model
    and configuration; `batched_params` vmaps the parameters too (one set per robot). The robots are
    split over `devices` devices (default all), padded to a multiple of them with copies of the last."""
    mesh = parallel.mesh(devices)
    n, axes = inputs.q.shape[0], (0 if batched_params else None, 0)
    args = parallel.place(parallel.pad((params, inputs), parallel.padded_size(n, mesh), axes), mesh, axes)
    return parallel.unpad(_compiled(robot, config, axes, mesh)(*args), n)


def inputs_from_log(robot, log, contacts: str = "truth") -> tuple[RobotInputs, PipelineConfig]:
    """`inputs.robot_inputs` of the log (leading robot axis) and the static configuration it allows."""
    inputs = robot_inputs(robot, log, contacts)
    config = PipelineConfig(contacts=contacts, has_qd="qd" in log, has_attitude="quat_wxyz" in log)
    return inputs, config
