"""Body twist from stance-leg kinematics and the gyro, as one weighted least-squares solve.

Each stance foot l is fixed in the world, so in the base frame
    v_base = -omega x p_base_foot_l - v_base_foot_l            (3 rows: [I  S(p_l)^T] V = -v_l)
and the gyro adds [0 I] V = omega_imu. With foot weights w_l (soft contacts in [0, 1]) and the IMU
weight w_imu the normal equations are 6x6; eliminating v_base leaves a 3x3 system for omega:
    v_base = -omega x p_bar - v_bar                            (weighted means of the stance feet)
    (sum_l w_l S(d_l)^T S(d_l) + w_imu I) omega = sum_l w_l S(d_l)^T e_l + w_imu omega_imu,
with d_l = p_l - p_bar, e_l = v_l - v_bar, S(d)^T S(d) = |d|^2 I - d d^T and S(d)^T e = e x d.
The 3x3 matrix is positive definite whenever w_imu > 0, for any number of feet, and is solved by an
unrolled LDL^T factorization (no pivoting needed for a positive definite matrix).
"""

from __future__ import annotations

import equinox as eqx
import jax.numpy as jnp
from jaxtyping import Array, Bool, Float

from jaxquad.kernels._small_linalg import spd_solve

# Floor on the IMU weight: keeps the 3x3 system invertible with fewer than three feet.
_MIN_IMU_WEIGHT = 1e-6
# Below this total foot weight there is no foot to average over: v_base is set to zero.
_MIN_TOTAL_WEIGHT = 1e-6


class Twist(eqx.Module):
    """Base twist in the base frame.

    `v_base` (m/s) is the weighted least-squares solution whenever some foot has weight; it is zero
    with no stance foot. `linear_observed` says whether the effective stance count reached
    `min_stance` (the paper needs two feet). `valid` is False when a used input was not finite;
    then every output is zero and `linear_observed` is False."""

    v_base: Float[Array, "3"]
    omega_base: Float[Array, "3"]
    linear_observed: Bool[Array, ""]
    n_stance: Float[Array, ""]
    valid: Bool[Array, ""]


def body_twist(
    p_base_foot: Float[Array, "F 3"],
    v_base_foot: Float[Array, "F 3"],
    omega_imu: Float[Array, "3"],
    weights: Float[Array, "F"],
    imu_weight: float | Float[Array, ""] = 1.0,
    min_stance: float | Float[Array, ""] = 1.5,
) -> Twist:
    """Least-squares base twist from F feet, for one robot (vmap over robots at the call site).

    p_base_foot: foot positions in the base frame (m). v_base_foot: foot velocities relative to the
    base from joint motion, J(q) qdot (m/s). omega_imu: gyro rate in the base frame (rad/s).
    weights: per-foot stance weights, clipped to [0, 1] (0 = swing; a swing foot's data is never read, so it
    may be NaN). imu_weight: weight of the gyro rows, floored at 1e-6. min_stance: effective stance
    count (sum of weights) from which the linear velocity counts as observed.
    """
    w = jnp.clip(weights, 0.0, 1.0)
    stance = w > 0
    finite = (
        jnp.all(jnp.where(stance[:, None], jnp.isfinite(p_base_foot) & jnp.isfinite(v_base_foot), True))
        & jnp.all(jnp.isfinite(omega_imu))
        & jnp.all(jnp.isfinite(weights))
    )
    # Safe-where: swing feet and invalid inputs become zeros before any arithmetic, so neither values
    # nor gradients see a NaN.
    w = jnp.where(finite & jnp.isfinite(weights), w, 0.0)
    p = jnp.where(stance[:, None] & finite, p_base_foot, 0.0)
    v = jnp.where(stance[:, None] & finite, v_base_foot, 0.0)
    omega_meas = jnp.where(finite, omega_imu, 0.0)
    w_imu = jnp.maximum(imu_weight, _MIN_IMU_WEIGHT)

    n_stance = jnp.sum(w)
    has_feet = n_stance > _MIN_TOTAL_WEIGHT
    total = jnp.where(has_feet, n_stance, 1.0)
    # Sums over the few feet as broadcast products: under vmap a dot of these tiny shapes would be a
    # separate batched-matmul call; these fuse with the elementwise code around them.
    p_bar = jnp.sum(w[:, None] * p, 0) / total
    v_bar = jnp.sum(w[:, None] * v, 0) / total
    d = p - p_bar
    e = v - v_bar
    eye = jnp.eye(3, dtype=p.dtype)
    lhs = jnp.sum(w[:, None, None] * (jnp.sum(d * d, -1)[:, None, None] * eye - d[:, :, None] * d[:, None, :]), 0)
    rhs = jnp.sum(w[:, None] * jnp.cross(e, d), 0) + w_imu * omega_meas
    omega = spd_solve(lhs + w_imu * eye, rhs)
    v_base = jnp.where(has_feet, -jnp.cross(omega, p_bar) - v_bar, 0.0)
    return Twist(
        v_base=jnp.where(finite, v_base, 0.0),
        omega_base=jnp.where(finite, omega, 0.0),
        linear_observed=finite & (n_stance >= min_stance),
        n_stance=n_stance,
        valid=finite,
    )
