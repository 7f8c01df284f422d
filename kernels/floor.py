"""Base height from the floor under the stance feet, fused with the integrated vertical velocity.

Leg odometry integrates the vertical velocity, so any bias in it (soft ground compressing at
touchdown and rebounding before lift-off, contacts declared early or late) becomes a height drift
without bound. On a locally flat floor the stance feet measure the height directly: with contact
points c_l in the base frame and R = R_world_base,
    h = -sum_l w_l (R c_l)_z / sum_l w_l            (base height above the floor, m).
A scalar Kalman filter fuses the two: predict z += dz (the odometry's vertical step) with process variance q^2 dt (q in
m/sqrt(s): the random walk of integrated velocity errors), update with the measurement
z_floor + h of variance s^2 / n (n feet). The floor height z_floor is where the feet first stood
(the state's height minus the first measurement), so the world frame keeps the log's origin.
On stairs or slopes this assumption fails; keep the filter for flat ground.
"""

from __future__ import annotations

import equinox as eqx
import jax.numpy as jnp
from jaxtyping import Array, Bool, Float


class FloorParams(eqx.Module):
    """Noise levels of the height filter (traced leaves)."""

    process_std: Float[Array, ""]  # m/sqrt(s): random walk of the integrated vertical velocity
    meas_std: Float[Array, ""]  # m: one foot's height measurement (ground compliance, kinematics)

    @classmethod
    def default(cls) -> "FloorParams":
        return cls(process_std=jnp.asarray(0.05), meas_std=jnp.asarray(0.02))


class FloorState(eqx.Module):
    z: Float[Array, ""]  # m: base height in the world
    var: Float[Array, ""]  # m^2: its variance
    floor_z: Float[Array, ""]  # m: world height of the floor under the feet
    has_floor: Bool[Array, ""]  # whether floor_z has been set by a first measurement


def floor_init(z0: Float[Array, ""], var0: float | Float[Array, ""] = 0.0) -> FloorState:
    """Start at the known height z0 (m) with variance var0 (m^2); the floor is set by the first stance."""
    z0 = jnp.asarray(z0)
    return FloorState(
        z=z0,
        var=jnp.asarray(var0, z0.dtype),
        floor_z=jnp.zeros_like(z0),
        has_floor=jnp.asarray(False),
    )


_MIN_WEIGHT = 1e-3  # stance weight (feet) below which the feet measure no height


def stance_height(
    p_contact_base: Float[Array, "F 3"],
    R_world_base: Float[Array, "3 3"],
    weights: Float[Array, "F"],
) -> tuple[Float[Array, ""], Float[Array, ""]]:
    """(h, n): base height above the floor (m) from the stance feet's contact points (base frame),
    and the stance weight n behind it (0: no measurement, h = 0). Swing feet are never read."""
    w = jnp.where(jnp.isfinite(weights), jnp.clip(weights, 0.0, 1.0), 0.0)
    z = (jnp.where(w[:, None] > 0, p_contact_base, 0.0) @ R_world_base.T)[:, 2]
    n = jnp.sum(w)
    # A measurement needs real stance weight: soft contacts of a swinging leg (n ~ 1e-30) would make
    # h's derivative w.r.t. the weights ~ z / n, overflowing gradients through the where below.
    ok_n = n > _MIN_WEIGHT
    h = -jnp.sum(w * z) / jnp.where(ok_n, n, 1.0)
    ok = ok_n & jnp.isfinite(h)
    return jnp.where(ok, h, 0.0), jnp.where(ok, n, 0.0)


def floor_step(
    params: FloorParams,
    state: FloorState,
    dz_world: Float[Array, ""],
    dt: Float[Array, ""],
    h: Float[Array, ""],
    n: Float[Array, ""],
) -> FloorState:
    """One predict (the odometry's vertical displacement dz_world, m, over dt s) and, where n > 0,
    one update with the height h (m) measured by n stance feet (`stance_height`). Non-finite or
    negative inputs skip the step they feed."""
    move = jnp.isfinite(dz_world) & jnp.isfinite(dt) & (dt >= 0)
    z = state.z + jnp.where(move, dz_world, 0.0)
    var = state.var + params.process_std**2 * jnp.where(move, dt, 0.0)

    measured = (n > 0) & jnp.isfinite(h)
    floor_z = jnp.where(measured & ~state.has_floor, z - h, state.floor_z)
    r = params.meas_std**2 / jnp.where(measured, n, 1.0)
    gain = jnp.where(measured, var / (var + r), 0.0)
    z = z + gain * (floor_z + jnp.where(measured, h, 0.0) - z)
    return FloorState(
        z=z,
        var=(1.0 - gain) * var,
        floor_z=floor_z,
        has_floor=state.has_floor | measured,
    )
