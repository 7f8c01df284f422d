"""Leg-odometry twist robust to slipping feet: iteratively reweighted least squares over the stance feet.

A slipping foot (or one declared in stance too early or too late) breaks the "foot fixed in the world"
rows of `body_twist`. Each iteration solves the weighted least squares, takes every stance foot's
residual norm |r_l| = |v_base + omega x p_l + v_l| (m/s) and multiplies the foot's stance weight by
a robust weight of it:
    Huber   u(r) = min(1, c / r)            (linear loss beyond c)
    Cauchy  u(r) = 1 / (1 + (r / c)^2)       (redescending: a gross outlier is all but ignored)
with the scale c (m/s). The iteration count is static and unrolled, so the solve is one fused
block under jit and vmap. A foot whose robust weight falls below `slip_weight` is flagged as slipping.

Identifiability: the gyro fixes omega, so the stance feet agree on v_base up to their residuals.
With three or four stance feet a lone slipping foot stands out; with two (a trot's diagonal pair)
their residuals are equal and opposite, both feet are down-weighted alike and the solution is
unchanged, so the flags then mean "the pair disagrees", not which foot slipped.

A prior base velocity `v_prior` (the previous sample's, a few ms old) breaks that tie: each stance
foot's weight is also multiplied by the robust weight of its residual against the prior,
|v_prior + omega x p_l + v_l| with omega of the first solve. The base's velocity changes by
centimetres per second within a sample while a foot that still slides at touchdown or already
moves at lift-off is off by tenths of a metre per second, on its own, however many feet stand.
On simulated Go2 and Badger trots with true contacts such edge samples made the plain solve
under-count the forward speed by 3 %, the reweighting without the prior by up to 1.7 % (Badger).
"""

from __future__ import annotations

import equinox as eqx
import jax.numpy as jnp
from jaxtyping import Array, ArrayLike, Bool, Float

from jaxquad.kernels.twist import Twist, body_twist

LOSSES = ("huber", "cauchy")


class RobustTwist(eqx.Module):
    """The twist of the last reweighted solve with the weights it used."""

    twist: Twist
    weights: Float[Array, "F"]  # stance weight x robust weight of each foot
    robust_weight: Float[Array, "F"]  # in (0, 1]; 1 for swing feet
    slip: Bool[Array, "F"]  # stance feet whose robust weight fell below slip_weight


def robust_weight(residual_norm: Float[Array, "*B"], scale: Float[ArrayLike, ""], loss: str) -> Float[Array, "*B"]:
    """u(r) of the module docstring for residual norms r >= 0 (m/s) and scale c > 0 (m/s)."""
    x = residual_norm / scale
    if loss == "huber":
        return 1.0 / jnp.maximum(x, 1.0)
    if loss == "cauchy":
        return 1.0 / (1.0 + x * x)
    raise ValueError(f"loss must be one of {LOSSES}, got {loss!r}")


def robust_body_twist(
    p_base_foot: Float[Array, "F 3"],
    v_base_foot: Float[Array, "F 3"],
    omega_imu: Float[Array, "3"],
    weights: Float[Array, "F"],
    imu_weight: float | Float[Array, ""] = 1.0,
    min_stance: float | Float[Array, ""] = 1.5,
    scale: float | Float[Array, ""] = 0.1,
    slip_weight: float | Float[Array, ""] = 0.5,
    sigma_prior: float | Float[Array, ""] = 0.1,
    prior_dof: float | Float[Array, ""] = 3.0,
    *,
    n_iter: int = 3,
    loss: str = "huber",
    v_prior: Float[Array, "3"] | None = None,
) -> RobustTwist:
    """`body_twist` with `n_iter` (static) reweighting steps of robust loss `loss` (static) at scale
    `scale` (m/s). Arguments as `body_twist`. `linear_observed` and `n_stance` count the stance
    weights (a foot down-weighted as an outlier still stands); the velocities, residuals and the
    covariance are those of the final reweighted solve. n_iter = 0 is `body_twist` itself.
    v_prior (m/s, base frame; None: no prior): every reweighting also multiplies each stance foot's
    weight by the robust weight of its residual against it (module docstring); a non-finite prior
    is ignored."""
    if loss not in LOSSES:
        raise ValueError(f"loss must be one of {LOSSES}, got {loss!r}")
    w0 = jnp.where(jnp.isfinite(weights), jnp.clip(weights, 0.0, 1.0), 0.0)
    solve = lambda w: body_twist(
        p_base_foot,
        v_base_foot,
        omega_imu,
        w,
        imu_weight,
        min_stance,
        sigma_prior,
        prior_dof,
    )  # noqa: E731
    twist, u = solve(weights), jnp.ones_like(w0)
    c = jnp.maximum(scale, 1e-9)
    residual_norm = lambda r: jnp.sqrt(jnp.sum(r**2, -1) + 1e-12)  # noqa: E731 (smooth at 0 for gradients)
    u_prior = jnp.ones_like(w0)
    if v_prior is not None and n_iter > 0:
        prior_ok = jnp.all(jnp.isfinite(v_prior))
        stance = (w0 > 0)[:, None]
        # Swing feet may hold NaN: zeroed before any arithmetic, as in body_twist.
        p, v = jnp.where(stance, p_base_foot, 0.0), jnp.where(stance, v_base_foot, 0.0)
        r_prior = jnp.where(prior_ok, v_prior, 0.0) + jnp.cross(twist.omega_base, p) + v
        u_prior = jnp.where((w0 > 0) & prior_ok & twist.valid, robust_weight(residual_norm(r_prior), c, loss), 1.0)
    for _ in range(n_iter):
        u = jnp.where(w0 > 0, robust_weight(residual_norm(twist.residual), c, loss), 1.0) * u_prior
        twist = solve(jnp.where(jnp.isfinite(weights), w0 * u, weights))
    n_stance = jnp.sum(w0)
    twist = eqx.tree_at(
        lambda t: (t.n_stance, t.linear_observed),
        twist,
        (n_stance, twist.valid & (n_stance >= min_stance)),
    )
    return RobustTwist(twist=twist, weights=w0 * u, robust_weight=u, slip=(w0 > 0) & (u < slip_weight))
