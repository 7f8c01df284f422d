"""Quaternion and rotation helpers shared by the estimators, the dynamics and the simulator: (w, x, y, z)."""

from __future__ import annotations

import jax.numpy as jnp
from jaxtyping import Array, Float

# Below this squared angle the closed forms divide by ~0; their Taylor series take over.
_SMALL_ANGLE_SQ = 1e-6


def skew(w: Float[Array, "3"]) -> Float[Array, "3 3"]:
    """Matrix S(w) with S(w) x = w x x."""
    zero = jnp.zeros_like(w[0])
    return jnp.array(
        [[zero, -w[2], w[1]], [w[2], zero, -w[0]], [-w[1], w[0], zero]], dtype=w.dtype
    )


def quat_multiply(a: Float[Array, "4"], b: Float[Array, "4"]) -> Float[Array, "4"]:
    """Hamilton product a (x) b."""
    aw, av = a[0], a[1:]
    bw, bv = b[0], b[1:]
    return jnp.concatenate([(aw * bw - av @ bv)[None], aw * bv + bw * av + jnp.cross(av, bv)])


def quat_to_matrix(q: Float[Array, "4"]) -> Float[Array, "3 3"]:
    """Rotation matrix of a unit quaternion (normalized here, so small drift is harmless)."""
    w, x, y, z = q / jnp.linalg.norm(q)
    return jnp.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
            [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
            [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
        ]
    )


def quat_exp(phi: Float[Array, "3"]) -> Float[Array, "4"]:
    """Unit quaternion of the rotation vector phi (rad); finite value and gradient at phi = 0."""
    theta_sq = phi @ phi
    small = theta_sq < _SMALL_ANGLE_SQ
    theta = jnp.sqrt(jnp.where(small, 1.0, theta_sq))
    # sin(theta/2)/theta, Taylor 1/2 - theta^2/48 near 0.
    half_sinc = jnp.where(small, 0.5 - theta_sq / 48.0, jnp.sin(0.5 * theta) / theta)
    cos_half = jnp.where(small, 1.0 - theta_sq / 8.0, jnp.cos(0.5 * theta))
    return jnp.concatenate([cos_half[None], half_sinc * phi])


def so3_exp_coefficients(theta_sq: Float[Array, ""]) -> tuple[Array, Array, Array]:
    """A = sin t / t, B = (1 - cos t) / t^2, C = (t - sin t) / t^3 with Taylor series near t = 0."""
    small = theta_sq < _SMALL_ANGLE_SQ
    t2 = jnp.where(small, 1.0, theta_sq)
    t = jnp.sqrt(t2)
    a = jnp.where(small, 1.0 - theta_sq / 6.0, jnp.sin(t) / t)
    b = jnp.where(small, 0.5 - theta_sq / 24.0, (1.0 - jnp.cos(t)) / t2)
    c = jnp.where(small, 1.0 / 6.0 - theta_sq / 120.0, (t - jnp.sin(t)) / (t2 * t))
    return a, b, c


def quat_from_roll_pitch_yaw(
    roll: Float[Array, ""], pitch: Float[Array, ""], yaw: Float[Array, ""]
) -> Float[Array, "4"]:
    """q = Rz(yaw) Ry(pitch) Rx(roll) as a quaternion."""
    cr, sr = jnp.cos(0.5 * roll), jnp.sin(0.5 * roll)
    cp, sp = jnp.cos(0.5 * pitch), jnp.sin(0.5 * pitch)
    cy, sy = jnp.cos(0.5 * yaw), jnp.sin(0.5 * yaw)
    return jnp.stack(
        [
            cr * cp * cy + sr * sp * sy,
            sr * cp * cy - cr * sp * sy,
            cr * sp * cy + sr * cp * sy,
            cr * cp * sy - sr * sp * cy,
        ]
    )
