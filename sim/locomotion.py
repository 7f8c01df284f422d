"""Model-based trot controller for the simulated quadrupeds (no learning).

One robot per call: `gait_step` maps the ground-truth base and joint state plus a body velocity
command to joint torques. It tracks foot targets kept in the *level frame* (base origin, yaw of the
base, z up): stance feet slide backwards with the commanded body motion, swing feet fly to a
Raibert foothold; the targets are turned into the trunk frame through the commanded body roll and
pitch (so the stance legs hold height and attitude), solved by analytic leg IK and tracked by joint
PD plus a gravity share J^T f on the stance legs. On robots with a spine (badger) the spine swings
with the trot and the rear legs' targets are expressed in the rear trunk through the measured
spine angle.

Static structure (`Gait`, `jaxquad.sim.gait_structure`) comes from the MuJoCo model; every tunable number
(`GaitParams`) is a traced leaf, so a fleet can randomize gains and styles under `jax.vmap` without recompiling.
"""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Bool, Float

from jaxquad.kernels.lie import SO3, R_level_base, roll_pitch, rotation_matrix, yaw_of

from .gait import TROT_OFFSETS, leg_phases, raibert_foothold, swing_position
from .gait_structure import Gait
from .leg_ik import leg_fk, leg_ik

_GRAVITY = 9.81
_QD_MAX = 20.0  # rad/s: bound on differenced joint target velocities


def _f32(x) -> Array:
    return jnp.asarray(x, jnp.float32)


class GaitParams(eqx.Module):
    """Per-robot tunable numbers (all traced; shapes fixed so vmapped fleets never recompile)."""

    step_freq: Float[Array, ""]  # gait cycles per second (Hz)
    duty: Float[Array, ""]  # stance share of a cycle
    swing_height: Float[Array, ""]  # m
    body_height: Float[Array, ""]  # desired base height above the floor (m)
    kp: Float[Array, " 3"]  # joint stiffness for abduction, thigh, knee (N m / rad)
    kd: Float[Array, " 3"]  # joint damping (N m s / rad)
    kp_spine: Float[Array, ""]
    kd_spine: Float[Array, ""]
    spine_amp: Float[Array, ""]  # spine swing amplitude (rad), in phase with the trot
    k_raibert: Float[Array, ""]  # foothold feedback on velocity error (s)
    k_velocity: Float[Array, ""]  # stance feet slide faster by this share of the velocity shortfall
    max_step: Float[Array, ""]  # largest foothold offset from the home foot position (m)
    v_max: Float[Array, " 3"]  # command limits vx, vy (m/s), yaw rate (rad/s)
    acc_max: Float[Array, " 3"]  # command rate limits (m/s^2, m/s^2, rad/s^2)
    roll_amp: Float[Array, ""]  # deliberate body roll oscillation amplitude (rad)
    pitch_amp: Float[Array, ""]  # deliberate body pitch oscillation amplitude (rad)
    attitude_freq: Float[Array, ""]  # Hz; pitch leads roll by a quarter period
    k_attitude: Float[Array, ""]  # extra attitude correction per rad of error
    k_height: Float[Array, ""]  # extra leg extension per m of height error
    stop_go_period: Float[Array, ""]  # s; the command is zeroed for (1 - stop_go_duty) of it
    stop_go_duty: Float[Array, ""]  # 1 = never stop
    weight_ff: Float[Array, ""]  # share of the body weight fed forward through the stance legs
    time_offset: Float[Array, ""]  # s added to `t` for the attitude and stop-and-go patterns

    @classmethod
    def calm(cls, gait: Gait, **overrides) -> "GaitParams":
        """Smooth walking around 0.3-0.5 m/s, level body."""
        values = dict(
            step_freq=2.5,
            duty=0.5,
            swing_height=0.07,
            body_height=float(gait.body_height),
            kp=_stiffness(gait),
            kd=(1.0, 1.0, 1.0),
            kp_spine=60.0,
            kd_spine=2.0,
            spine_amp=0.05 if gait.has_spine else 0.0,
            k_raibert=0.15,
            k_velocity=0.5,
            max_step=0.15,
            v_max=(0.5, 0.3, 0.8),
            acc_max=(0.5, 0.5, 1.0),
            roll_amp=0.0,
            pitch_amp=0.0,
            attitude_freq=0.5,
            k_attitude=0.3,
            k_height=0.5,
            stop_go_period=4.0,
            stop_go_duty=1.0,
            weight_ff=1.0,
            time_offset=0.0,
        )
        values.update(overrides)
        return cls(**{k: _f32(v) for k, v in values.items()})

    @classmethod
    def aggressive(cls, gait: Gait, **overrides) -> "GaitParams":
        """Fast steps up to 1 m/s, abrupt command changes, stop-and-go, swinging body attitude."""
        values = dict(
            step_freq=3.0,
            swing_height=0.08,
            spine_amp=0.1 if gait.has_spine else 0.0,
            k_raibert=0.15,
            max_step=0.2,
            v_max=(1.0, 0.5, 1.5),
            acc_max=(3.0, 2.0, 4.0),
            roll_amp=0.15,
            pitch_amp=0.15,
            attitude_freq=0.8,
            k_attitude=1.0,
            stop_go_period=3.0,
            stop_go_duty=0.7,
        )
        values.update(overrides)
        return cls.calm(gait, **values)


def _stiffness(gait: Gait) -> tuple[float, float, float]:
    # Stiffness scaled with the weaker leg motor so a 0.5 rad error saturates it (go2: ~47, badger: 32).
    tau = float(np.min(np.asarray(gait.tau_limit)[np.asarray(gait.leg_act)]))
    k = 2.0 * tau
    return (k, k, k)


class GaitState(eqx.Module):
    phase: Float[Array, ""]  # gait cycles since start
    cmd: Float[Array, " 3"]  # rate-limited command vx, vy, yaw rate (body frame)
    p_level_foot: Float[Array, "4 3"]  # foot centre targets in the level frame (m)
    p_level_lift: Float[Array, "4 3"]  # where each foot last lifted off, level frame (m)
    stance: Bool[Array, " 4"]
    q_des: Float[Array, "4 3"]  # last joint targets (rad), differenced into target velocities
    ok: Bool[Array, ""]  # False once a non-finite input was seen (torques then stay zero)


def gait_init(gait: Gait, params: GaitParams) -> GaitState:
    p0 = _home_level(gait, params)
    stance, _ = leg_phases(jnp.zeros(()), _f32(TROT_OFFSETS), params.duty)
    return GaitState(
        phase=jnp.zeros(()),
        cmd=jnp.zeros(3),
        p_level_foot=p0,
        p_level_lift=p0,
        stance=stance,
        q_des=leg_ik(gait.legs, gait.p_base_foot_home)[0],
        ok=jnp.ones((), bool),
    )


def _home_level(gait: Gait, params: GaitParams) -> Float[Array, "4 3"]:
    z = -params.body_height + gait.foot_radius
    return gait.p_base_foot_home.at[:, 2].set(z)


def base_to_leg_trunk(gait: Gait, p_base_foot: Float[Array, "4 3"], q_spine: Float[Array, ""]) -> Float[Array, "4 3"]:
    """Foot points from the base frame into the frame of the trunk carrying each leg (m).

    Legs on the rear trunk of a spined robot see the point rotated back by the spine angle (rad)
    about the spine anchor; the other legs' trunk is the base itself.
    """
    R_spine = SO3.from_y_radians(gait.spine_sign * q_spine).as_matrix()
    p_rear = gait.p_base_spine + (p_base_foot - gait.p_base_spine) @ R_spine  # rows: R^T p
    return jnp.where(jnp.array(gait.on_spine)[:, None], p_rear, p_base_foot)


def gait_step(
    gait: Gait,
    params: GaitParams,
    state: GaitState,
    qpos: Float[Array, " nq"],
    qvel: Float[Array, " nv"],
    command: Float[Array, " 3"],
    t: Float[Array, ""],
    dt: Float[Array, ""],
) -> tuple[GaitState, Float[Array, " nu"]]:
    """New state and joint torques (nu,) for one control period `dt` (s) at time `t` (s).

    `command` is (vx, vy, yaw rate) in the body frame (m/s, rad/s); it is clipped to `v_max`,
    gated by the stop-and-go pattern and rate limited by `acc_max`. Non-finite inputs zero the
    torques and latch `state.ok` to False, so one bad robot cannot poison a batch.
    """
    ok = state.ok & jnp.all(jnp.isfinite(qpos)) & jnp.all(jnp.isfinite(qvel)) & jnp.all(jnp.isfinite(command))
    qpos = jnp.where(ok, qpos, 0.0).at[3].set(jnp.where(ok, qpos[3], 1.0))
    qvel = jnp.where(ok, qvel, 0.0)
    command = jnp.where(ok, command, 0.0)

    # Base state (free joint: world position, wxyz quaternion; world linear, body angular velocity).
    R_world_base = rotation_matrix(qpos[3:7])
    roll, pitch = roll_pitch(qpos[3:7])
    yaw = yaw_of(qpos[3:7])
    cy, sy = jnp.cos(yaw), jnp.sin(yaw)
    v_level = jnp.array([cy * qvel[0] + sy * qvel[1], -sy * qvel[0] + cy * qvel[1]])

    # Command: limits, stop-and-go, rate limits.
    t = t + params.time_offset  # desynchronizes the patterns of a fleet
    go = jnp.mod(t, params.stop_go_period) < params.stop_go_duty * params.stop_go_period
    target = jnp.where(go, jnp.clip(command, -params.v_max, params.v_max), 0.0)
    step = params.acc_max * dt
    cmd = state.cmd + jnp.clip(target - state.cmd, -step, step)

    # Gait clock and foot targets in the level frame.
    phase = state.phase + params.step_freq * dt
    stance, progress = leg_phases(phase, _f32(TROT_OFFSETS), params.duty)
    lifted = state.stance & ~stance
    p_lift = jnp.where(lifted[:, None], state.p_level_foot, state.p_level_lift)

    home = _home_level(gait, params)
    z_ground = home[:, 2] - params.k_height * (params.body_height - qpos[2])
    p_prev = state.p_level_foot
    # Stance feet carry the body at the command, plus a push where the body lags behind it.
    yaw_rate = (R_world_base @ qvel[3:6])[2]
    v_slide = cmd[:2] + params.k_velocity * jnp.clip(cmd[:2] - v_level, -0.5, 0.5)
    w_slide = cmd[2] + params.k_velocity * jnp.clip(cmd[2] - yaw_rate, -0.5, 0.5)
    slide = v_slide + w_slide * jnp.stack([-p_prev[:, 1], p_prev[:, 0]], -1)
    p_stance = jnp.concatenate([p_prev[:, :2] - slide * dt, z_ground[:, None]], -1)

    t_stance = params.duty / params.step_freq
    land_xy = raibert_foothold(home[:, :2], v_level, cmd[:2], cmd[2], t_stance, params.k_raibert)
    offset = land_xy - home[:, :2]
    offset = offset * jnp.minimum(1.0, params.max_step / jnp.maximum(jnp.linalg.norm(offset, axis=-1), 1e-9))[:, None]
    p_land = jnp.concatenate([home[:, :2] + offset, z_ground[:, None]], -1)
    p_swing = swing_position(p_lift, p_land, progress, params.swing_height)
    p_level = jnp.where(stance[:, None], p_stance, p_swing)

    # Level frame -> trunk frame through the commanded roll and pitch (with feedback).
    w = 2.0 * jnp.pi * params.attitude_freq * t
    roll_des = params.roll_amp * jnp.sin(w)
    pitch_des = params.pitch_amp * jnp.cos(w)
    roll_cmd = roll_des + params.k_attitude * (roll_des - roll)
    pitch_cmd = pitch_des + params.k_attitude * (pitch_des - pitch)
    p_base_foot = p_level @ R_level_base(roll_cmd, pitch_cmd)  # rows: R^T p

    # Spine: swing with the trot; rear feet expressed in the rear trunk via the measured angle.
    on_spine = jnp.array(gait.on_spine)[:, None]
    q_spine = qpos[gait.spine_qpos] if gait.has_spine else jnp.zeros(())
    R_spine = SO3.from_y_radians(gait.spine_sign * q_spine).as_matrix()
    p_trunk_foot = base_to_leg_trunk(gait, p_base_foot, q_spine)

    q_des, _ = leg_ik(gait.legs, p_trunk_foot)
    idx_q, idx_v = np.asarray(gait.leg_qpos), np.asarray(gait.leg_dof)
    q, qd = qpos[idx_q], qvel[idx_v]
    qd_des = jnp.clip((q_des - state.q_des) / dt, -_QD_MAX, _QD_MAX)
    tau_pd = params.kp * (q_des - q) + params.kd * (qd_des - qd)

    # Gravity share through the stance legs: tau = J^T f, f the push of the foot on the ground.
    n_stance = jnp.maximum(jnp.sum(stance), 1).astype(jnp.float32)
    f_world = jnp.array([0.0, 0.0, -1.0]) * (params.weight_ff * gait.mass * _GRAVITY / n_stance)
    f_base = R_world_base.T @ f_world
    f_trunk = jnp.where(stance[:, None], jnp.where(on_spine, f_base @ R_spine, f_base), 0.0)
    jac = jax.vmap(jax.jacfwd(leg_fk, argnums=1))(gait.legs, q)  # (4, 3 xyz, 3 joints)
    tau_ff = jnp.einsum("lij,li->lj", jac, f_trunk)

    tau = jnp.zeros(gait.nu).at[np.asarray(gait.leg_act)].set(tau_pd + tau_ff)
    if gait.has_spine:
        q_spine_des = params.spine_amp * jnp.sin(2.0 * jnp.pi * phase)
        tau_spine = params.kp_spine * (q_spine_des - q_spine) - params.kd_spine * qvel[gait.spine_dof]
        tau = tau.at[gait.spine_act].set(tau_spine)
    tau = jnp.where(ok, jnp.clip(tau, -gait.tau_limit, gait.tau_limit), 0.0)

    new_state = GaitState(
        phase=jnp.mod(phase, 1.0),
        cmd=cmd,
        p_level_foot=p_level,
        p_level_lift=p_lift,
        stance=stance,
        q_des=q_des,
        ok=ok,
    )
    return new_state, tau
