"""Rotation helpers shared by alignment and the error metrics (single pose; vmap for many)."""

from __future__ import annotations

import jax.numpy as jnp
from jaxtyping import Array, Float


def rotation_from_quat_xyzw(q_xyzw: Float[Array, "4"]) -> Float[Array, "3 3"]:
    """Rotation matrix of a quaternion (scalar last); scaled by sqrt(2 / |q|^2) so it need not be unit."""
    x, y, z, w = q_xyzw
    n = jnp.dot(q_xyzw, q_xyzw)
    s = 2.0 / jnp.where(n > 0, n, 1.0)
    xx, yy, zz = s * x * x, s * y * y, s * z * z
    xy, xz, yz = s * x * y, s * x * z, s * y * z
    wx, wy, wz = s * w * x, s * w * y, s * w * z
    return jnp.array(
        [
            [1.0 - yy - zz, xy - wz, xz + wy],
            [xy + wz, 1.0 - xx - zz, yz - wx],
            [xz - wy, yz + wx, 1.0 - xx - yy],
        ]
    )


def rotation_angle(R: Float[Array, "3 3"]) -> Float[Array, ""]:
    """|log(R)| in radians, in [0, pi]: atan2 of the sine (antisymmetric part) and cosine (trace),
    accurate at both 0 and pi and finite for every input."""
    axis = jnp.array([R[2, 1] - R[1, 2], R[0, 2] - R[2, 0], R[1, 0] - R[0, 1]])
    sin = 0.5 * jnp.sqrt(jnp.dot(axis, axis))
    cos = 0.5 * (jnp.trace(R) - 1.0)
    return jnp.arctan2(sin, cos)
