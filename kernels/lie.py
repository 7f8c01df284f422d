"""The project's one Lie-group module: SO(2), SE(2), SO(3), SE(3) from jaxlie, plus the few helpers
jaxlie leaves out. Quaternions are (w, x, y, z) everywhere in jaxquad, as in jaxlie.

jaxlie (pytree dataclasses around one parameter array; exp/log/adjoint/jlog with Taylor branches so
values and gradients stay finite at zero angle) is used directly: `SO3(wxyz) @ SO3(...)`,
`SE2.from_xy_theta(x, y, theta)`, `SO3.exp(phi).as_matrix()`. Leading batch axes and `vmap` both work.
"""

from __future__ import annotations

import jax.numpy as jnp
from jaxlie import SE2, SE3, SO2, SO3
from jaxtyping import Array, Float

__all__ = [
    "SE2", "SE3", "SO2", "SO3", "skew", "rotation_matrix", "quat_from_rpy", "roll_pitch",
    "wrap_angle", "yaw_of",
]  # fmt: skip


def skew(w: Float[Array, "3"]) -> Float[Array, "3 3"]:
    """Matrix S(w) with S(w) x = w x x."""
    zero = jnp.zeros_like(w[0])
    return jnp.array([[zero, -w[2], w[1]], [w[2], zero, -w[0]], [-w[1], w[0], zero]], dtype=w.dtype)


def rotation_matrix(q_wxyz: Float[Array, "4"]) -> Float[Array, "3 3"]:
    """Rotation matrix of a quaternion normalized first, so that small drift of a filter is harmless."""
    return SO3(q_wxyz / jnp.linalg.norm(q_wxyz)).as_matrix()


def quat_from_rpy(roll: Float[Array, ""], pitch: Float[Array, ""], yaw: Float[Array, ""]) -> Float[Array, "4"]:
    """q = Rz(yaw) Ry(pitch) Rx(roll), (w, x, y, z): the IMU's ZYX Euler convention."""
    return SO3.from_rpy_radians(roll, pitch, yaw).wxyz


def roll_pitch(q_wxyz: Float[Array, "4"]) -> tuple[Float[Array, ""], Float[Array, ""]]:
    """ZYX-Euler roll and pitch (rad) of world-from-base q, read from the world z axis in the base frame.

    Uses only R[2, :], so it is exact for any yaw and needs no normalization of q beyond a scale.
    """
    w, x, y, z = q_wxyz / jnp.linalg.norm(q_wxyz)
    r20 = 2.0 * (x * z - w * y)
    r21 = 2.0 * (y * z + w * x)
    r22 = 1.0 - 2.0 * (x * x + y * y)
    pitch = jnp.arcsin(jnp.clip(-r20, -1.0, 1.0))
    roll = jnp.arctan2(r21, r22)
    return roll, pitch


def yaw_of(q_wxyz: Float[Array, "4"]) -> Float[Array, ""]:
    """ZYX-Euler yaw (rad) of world-from-base q."""
    w, x, y, z = q_wxyz
    return jnp.arctan2(2.0 * (w * z + x * y), 1.0 - 2.0 * (y * y + z * z))


def wrap_angle(a: Float[Array, "*batch"]) -> Float[Array, "*batch"]:
    """Angle wrapped to [-pi, pi)."""
    return (a + jnp.pi) % (2.0 * jnp.pi) - jnp.pi
