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

Uncertainty: with foot-row noise of variance sigma^2 / w_l, the centred unknown u = v_base - S(p_bar)
omega decouples from omega (sum_l w_l d_l = 0), so Cov(u) = sigma^2 / n I and Cov(omega) = sigma^2 D^-1
with D the 3x3 matrix above, and
    Cov(v_base) = sigma^2 (I / n + S(p_bar) D^-1 S(p_bar)^T),         n = sum_l w_l,
the v block of sigma^2 (A^T W A)^-1. sigma^2 comes from the weighted foot residuals over their
3 n - 3 degrees of freedom, shrunk toward a prior sigma_0^2 worth nu_0 degrees of freedom:
    sigma^2 = (nu_0 sigma_0^2 + sum_l w_l |r_l|^2) / (nu_0 + 3 n - 3).
The prior is the floor for what residuals cannot show (errors shared by every stance foot) and the
whole estimate when only two feet stand (their residuals then mostly cancel).
"""

from __future__ import annotations

import equinox as eqx
import jax.numpy as jnp
from jaxtyping import Array, Bool, Float

from jaxquad.kernels._small_linalg import spd_solve
from jaxquad.kernels.lie import skew

# Floor on the IMU weight: keeps the 3x3 system invertible with fewer than three feet.
_MIN_IMU_WEIGHT = 1e-6
# Below this total foot weight there is no foot to average over: v_base is set to zero.
_MIN_TOTAL_WEIGHT = 1e-6
# Variance of v_base (m/s)^2 reported when no foot measures it.
UNOBSERVED_VAR = 1e4


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
    residual: Float[Array, "F 3"]  # m/s: v_base + omega x p_l + v_l per foot (0 for swing feet)
    cov_v_base: Float[Array, "3 3"]  # (m/s)^2: covariance of v_base (module docstring)


def rolling_contact(
    p_base_foot: Float[Array, "F 3"],
    v_base_foot: Float[Array, "F 3"],
    omega_base_foot: Float[Array, "F 3"],
    radius: Float[Array, "F"],
    n_base: Float[Array, "3"],
) -> tuple[Float[Array, "F 3"], Float[Array, "F 3"]]:
    """Contact points of round feet rolling without slipping, as the point feet `body_twist` expects.

    A sphere of radius r touches a locally flat floor (unit normal n, base frame, pointing up) at
    c = p - r n below its centre p. The foot's material point at c is at rest in the world while the
    foot rolls, and moves relative to the base at v + omega_foot x (-r n), where v is the centre's
    velocity and omega_foot the foot body's angular velocity relative to the base, both from joint
    motion (rad/s, base axes). The base's own rotation is accounted for by `body_twist`'s omega x c.
    Treating the centre as fixed instead under-counts the base speed by about r / (leg length + r)
    (the centre moves r per radian of leg swing). radius 0 gives the point-foot model unchanged.
    """
    offset = -radius[:, None] * n_base[None, :]
    return p_base_foot + offset, v_base_foot + jnp.cross(omega_base_foot, offset)


def body_twist(
    p_base_foot: Float[Array, "F 3"],
    v_base_foot: Float[Array, "F 3"],
    omega_imu: Float[Array, "3"],
    weights: Float[Array, "F"],
    imu_weight: float | Float[Array, ""] = 1.0,
    min_stance: float | Float[Array, ""] = 1.5,
    sigma_prior: float | Float[Array, ""] = 0.1,
    prior_dof: float | Float[Array, ""] = 3.0,
) -> Twist:
    """Least-squares base twist from F feet, for one robot (vmap over robots at the call site).

    p_base_foot: foot positions in the base frame (m). v_base_foot: foot velocities relative to the
    base from joint motion, J(q) qdot (m/s). omega_imu: gyro rate in the base frame (rad/s).
    weights: per-foot stance weights, clipped to [0, 1] (0 = swing; a swing foot's data is never read, so it
    may be NaN). imu_weight: weight of the gyro rows, floored at 1e-6. min_stance: effective stance
    count (sum of weights) from which the linear velocity counts as observed. sigma_prior (m/s) and
    prior_dof: the prior of the foot-velocity noise level behind `cov_v_base` (module docstring).
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

    residual = jnp.where(stance[:, None] & has_feet, v_base + jnp.cross(omega, p) + v, 0.0)
    ssr = jnp.sum(w * jnp.sum(residual**2, -1))
    dof = jnp.maximum(3.0 * n_stance - 3.0, 0.0)
    sigma2 = (prior_dof * sigma_prior**2 + ssr) / jnp.maximum(prior_dof + dof, 1e-6)
    S_bar = skew(p_bar)
    D_inv_St = spd_solve(lhs + w_imu * eye, S_bar.T)  # D^-1 S^T
    cov_v = sigma2 * (eye / total + S_bar @ D_inv_St)
    # No stance foot: v_base is not measured at all (a large but finite variance).
    cov_v = jnp.where(has_feet & finite, cov_v, UNOBSERVED_VAR * eye)
    return Twist(
        v_base=jnp.where(finite, v_base, 0.0),
        omega_base=jnp.where(finite, omega, 0.0),
        linear_observed=finite & (n_stance >= min_stance),
        n_stance=n_stance,
        valid=finite,
        residual=jnp.where(finite, residual, 0.0),
        cov_v_base=0.5 * (cov_v + cov_v.T),
    )
