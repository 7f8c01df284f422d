"""Attitude from gyro and accelerometer alone: a Mahony complementary filter on SO(3).

The gyro is integrated on the unit quaternion; the accelerometer, read as the direction of
"up" in the base frame while the robot is not accelerating much, corrects roll and pitch and,
through an integral term, the gyro bias (Mahony, Hamel, Pflimlin, IEEE TAC 2008, eq. 32):

    omega = gyro - b + kp e,    b_dot = -ki e,    e = a_n x (R^T e_z)

with a_n the normalized accelerometer reading and R = R_world_base. Yaw is unobservable from
these sensors and starts at 0. A reading whose norm is off g by more than `acc_gate` (relative)
or that is not finite does not correct; a gyro reading that is not finite holds the attitude.

When the robot reports its attitude R_y (an onboard filter's quaternion), `step_toward` is the same
filter with the error measured against it, e = log(R^T R_y) (the passive complementary filter of the
same paper, eq. 13, with the exact logarithm for vex(P_a(R^T R_y))): the gyro carries the attitude
between reports, whose per-sample noise it smooths out, and the integral term estimates the gyro
bias, which the leg odometry's omega x p would otherwise read as base velocity.
"""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
from jaxtyping import Array, Bool, Float

from jaxquad.kernels.lie import SO3, quat_from_rpy, rotation_matrix

GRAVITY = 9.81  # m/s^2


class AttitudeParams(eqx.Module):
    """Filter gains, traced so a sweep never recompiles."""

    kp: Float[Array, ""]  # 1/s: proportional gain on the gravity-direction error
    ki: Float[Array, ""]  # 1/s^2: integral gain, estimates the gyro bias
    acc_gate: Float[Array, ""]  # relative deviation of |acc| from g beyond which no correction

    @classmethod
    def default(cls) -> "AttitudeParams":
        return cls(kp=jnp.asarray(1.0), ki=jnp.asarray(0.1), acc_gate=jnp.asarray(0.3))

    @classmethod
    def toward_report(cls) -> "AttitudeParams":
        """Gains of `step_toward`: a reported attitude is a cleaner reference than the accelerometer (no
        motion disturbs it), so the loop can be faster; ki = kp^2 / 4 makes it critically damped, time
        constant 1 / (kp / 2) = 1 s: the report's per-sample noise is averaged over ~250 samples at
        250 Hz and the gyro bias is found within seconds (acc_gate unused)."""
        return cls(kp=jnp.asarray(2.0), ki=jnp.asarray(1.0), acc_gate=jnp.asarray(0.3))


class AttitudeState(eqx.Module):
    q_world_base: Float[Array, "4"]  # w x y z
    gyro_bias: Float[Array, "3"]  # rad/s, in the base frame


def attitude_from_acc(acc: Float[Array, "3"]) -> Float[Array, "4"]:
    """Roll and pitch that make R^T e_z parallel to the accelerometer reading; yaw 0.

    Identity when the reading is not finite or zero.
    """
    ok = jnp.all(jnp.isfinite(acc)) & (acc @ acc > 0)
    u = jnp.where(ok, acc, jnp.array([0.0, 0.0, 1.0], acc.dtype))
    roll = jnp.arctan2(u[1], u[2])
    pitch = jnp.arctan2(-u[0], jnp.sqrt(u[1] ** 2 + u[2] ** 2))
    return quat_from_rpy(roll, pitch, jnp.zeros_like(roll))


def init(q_world_base: Float[Array, "4"]) -> AttitudeState:
    return AttitudeState(q_world_base=q_world_base, gyro_bias=jnp.zeros(3, dtype=q_world_base.dtype))


def report_usable(q_wxyz: Float[Array, "4"]) -> Bool[Array, ""]:
    """A reported attitude is used when it is finite and within 10 % of a unit quaternion's squared norm."""
    return jnp.all(jnp.isfinite(q_wxyz)) & (jnp.abs(jnp.sum(q_wxyz**2) - 1.0) < 0.1)


def _gyro_usable(gyro: Float[Array, "3"], dt: Float[Array, ""]) -> Bool[Array, ""]:
    """A gyro reading moves the attitude when it and the step dt > 0 are finite."""
    return jnp.all(jnp.isfinite(gyro)) & jnp.isfinite(dt) & (dt > 0)


def _correct(params: AttitudeParams, state: AttitudeState, gyro, gyro_ok, err, dt) -> AttitudeState:
    """The filter's update for an attitude error `err` (base frame, rad): the gyro less the bias estimate
    plus kp err integrated over dt (nothing when the gyro is unusable), the bias driven by -ki err."""
    dt_used = jnp.where(gyro_ok, dt, 0.0)
    omega = jnp.where(gyro_ok, gyro, 0.0) - state.gyro_bias + params.kp * err
    q = (SO3(state.q_world_base) @ SO3.exp(omega * dt_used)).wxyz
    q = q / jnp.linalg.norm(q)
    return AttitudeState(q_world_base=q, gyro_bias=state.gyro_bias - params.ki * err * dt_used)


def step(
    params: AttitudeParams,
    state: AttitudeState,
    gyro: Float[Array, "3"],
    acc: Float[Array, "3"],
    dt: Float[Array, ""],
) -> tuple[AttitudeState, Bool[Array, "2"]]:
    """Advance by dt seconds. Returns the new state and flags (gyro used, accelerometer used)."""
    gyro_ok = _gyro_usable(gyro, dt)
    acc_sq = jnp.where(jnp.all(jnp.isfinite(acc)), acc @ acc, 0.0)
    acc_norm = jnp.sqrt(jnp.where(acc_sq > 0, acc_sq, 1.0))
    acc_ok = (acc_sq > 0) & (jnp.abs(acc_norm - GRAVITY) < params.acc_gate * GRAVITY) & gyro_ok
    a_n = jnp.where(acc_ok, acc, 0.0) / acc_norm

    up_base = rotation_matrix(state.q_world_base)[2]  # R^T e_z
    err = jnp.where(acc_ok, jnp.cross(a_n, up_base), 0.0)
    return _correct(params, state, gyro, gyro_ok, err, dt), jnp.stack([gyro_ok, acc_ok])


def step_toward(
    params: AttitudeParams,
    state: AttitudeState,
    gyro: Float[Array, "3"],
    q_meas_wxyz: Float[Array, "4"],
    dt: Float[Array, ""],
) -> tuple[AttitudeState, Bool[Array, "2"]]:
    """Advance by dt seconds, corrected toward the reported attitude q_meas (module docstring; acc_gate
    unused). A non-finite or non-unit report does not correct. Returns the state and (gyro used,
    attitude used)."""
    gyro_ok = _gyro_usable(gyro, dt)
    meas_ok = report_usable(q_meas_wxyz) & gyro_ok
    q_meas = jnp.where(meas_ok, q_meas_wxyz, state.q_world_base)
    err = (SO3(state.q_world_base).inverse() @ SO3(q_meas / jnp.linalg.norm(q_meas))).log()  # base frame
    err = jnp.where(meas_ok, err, 0.0)
    return _correct(params, state, gyro, gyro_ok, err, dt), jnp.stack([gyro_ok, meas_ok])


def estimate_attitude(
    params: AttitudeParams,
    t: Float[Array, "T"],
    gyro: Float[Array, "T 3"],
    acc: Float[Array, "T 3"],
    q0_world_base: Float[Array, "4"] | None = None,
) -> tuple[Float[Array, "T 4"], Bool[Array, "T 2"]]:
    """Run the filter over a sequence (one robot). Sample k integrates gyro[k-1] over t[k]-t[k-1]
    and corrects with acc[k-1], the reading taken with the attitude of sample k-1.

    Starts from `q0_world_base`, or from roll and pitch of the first accelerometer reading.
    Returns q_world_base per sample and the (gyro used, accelerometer used) flags.
    """
    q0 = attitude_from_acc(acc[0]) if q0_world_base is None else q0_world_base
    dt = jnp.diff(t)

    def body(state, x):
        g, a, h = x
        state, flags = step(params, state, g, a, h)
        return state, (state.q_world_base, flags)

    _, (qs, flags) = jax.lax.scan(body, init(q0), (gyro[:-1], acc[:-1], dt))
    # Flags of step k describe the readings of sample k-1; the last sample's readings are unused.
    last = jnp.zeros((1, 2), dtype=bool)
    return jnp.concatenate([q0[None], qs]), jnp.concatenate([flags, last])
