"""Causal joint-velocity estimate for logs without qd: backward difference + first-order low-pass.

    d_k  = (q_k - q_{k-1}) / dt_k
    qd_k = qd_{k-1} + a_k (d_k - qd_{k-1}),    a_k = 1 - exp(-2 pi f_c dt_k)

The smoothing is the exact zero-order-hold discretization of 1 / (1 + s / (2 pi f_c)), and the
whole filter approximates s / (1 + s / w_c) with w_c = 2 pi f_c. For a sinusoid of angular
frequency w << 1/dt its gain is about 1/sqrt(1 + (w/w_c)^2) and its lag about atan(w/w_c),
to within w dt / 2 (the half-sample delay of the difference is offset by the smoothing acting
on the current sample): a 2 Hz gait component through f_c = 20 Hz at 500 Hz keeps 99.5 % of its
amplitude and lags 5.7 deg (7.9 ms). Per step, `dt` may vary (time gaps); a non-finite joint
reading holds that joint's last position and velocity, a non-positive or non-finite dt holds
everything.
"""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
from jaxtyping import Array, Bool, Float


class DifferentiatorParams(eqx.Module):
    cutoff_hz: Float[Array, ""]  # Hz, corner of the low-pass

    @classmethod
    def default(cls) -> "DifferentiatorParams":
        return cls(cutoff_hz=jnp.asarray(20.0))


class DifferentiatorState(eqx.Module):
    q_prev: Float[Array, "n"]  # last finite reading per joint (rad)
    qd: Float[Array, "n"]  # rad/s


def init(q0: Float[Array, "n"]) -> DifferentiatorState:
    """Start at rest; joints whose first reading is not finite start at 0 rad."""
    return DifferentiatorState(q_prev=jnp.where(jnp.isfinite(q0), q0, 0.0), qd=jnp.zeros_like(q0))


def step(
    params: DifferentiatorParams, state: DifferentiatorState, q: Float[Array, "n"], dt: Float[Array, ""]
) -> tuple[DifferentiatorState, Bool[Array, "n"]]:
    """Advance with the reading q taken dt seconds after the previous one.

    Returns the new state (its `qd` is the estimate) and, per joint, whether q was used.
    """
    dt_ok = jnp.isfinite(dt) & (dt > 0)
    used = jnp.isfinite(q) & dt_ok
    dt_safe = jnp.where(dt_ok, dt, 1.0)
    diff = (jnp.where(used, q, state.q_prev) - state.q_prev) / dt_safe
    a = -jnp.expm1(-2.0 * jnp.pi * params.cutoff_hz * dt_safe)
    qd = jnp.where(used, state.qd + a * (diff - state.qd), state.qd)
    q_prev = jnp.where(used, q, state.q_prev)
    return DifferentiatorState(q_prev=q_prev, qd=qd), used


def joint_velocities(params: DifferentiatorParams, t: Float[Array, "T"], q: Float[Array, "T n"]) -> Float[Array, "T n"]:
    """Joint velocities (rad/s) of a whole sequence for one robot; sample 0 reads 0."""

    def body(state, x):
        qk, dt = x
        state, _ = step(params, state, qk, dt)
        return state, state.qd

    state0 = init(q[0])
    _, qd = jax.lax.scan(body, state0, (q[1:], jnp.diff(t)))
    return jnp.concatenate([state0.qd[None], qd])
