"""The project's one Lie-group module: SO(2), SE(2), SO(3), SE(3) from jaxlie, plus the few helpers
jaxlie leaves out. Quaternions are (w, x, y, z) everywhere in jaxquad, as in jaxlie.

jaxlie (pytree dataclasses around one parameter array; exp/log/adjoint/jlog with Taylor branches so
values and gradients stay finite at zero angle) is used directly: `SO3(wxyz) @ SO3(...)`,
`SE2.from_xy_theta(x, y, theta)`, `SO3.exp(phi).as_matrix()`. Leading batch axes and `vmap` both work.

One exception, measured: jaxlie's `SE3.exp` replaces V(phi) by R(phi) below its small-angle threshold,
so the derivative of the translation w.r.t. the rotation at phi = 0 comes out 1 instead of 1/2
(integrating a body twist and differentiating through it is what tuning does). `se3_exp` here keeps
the proper series of V and returns a jaxlie `SE3`.
"""

from __future__ import annotations

import jax.numpy as jnp
from jaxlie import SE2, SE3, SO2, SO3
from jaxtyping import Array, ArrayLike, Float

# Below this squared angle the closed forms of V(phi) divide by ~0; their Taylor series take over.
_SMALL_ANGLE_SQ = 1e-6

__all__ = [
    "SE2",
    "SE3",
    "SO2",
    "SO3",
    "R_level_base",
    "se2",
    "se3_exp",
    "skew",
    "rotation_matrix",
    "quat_from_rpy",
    "roll_pitch",
    "wrap_angle",
    "xy_theta",
    "yaw_of",
]


def skew(w: Float[ArrayLike, "3"]) -> Float[Array, "3 3"]:
    """Matrix S(w) with S(w) x = w x x."""
    w = jnp.asarray(w)
    zero = jnp.zeros_like(w[0])
    return jnp.array([[zero, -w[2], w[1]], [w[2], zero, -w[0]], [-w[1], w[0], zero]], dtype=w.dtype)


def se3_exp(v: Float[Array, "3"], phi: Float[Array, "3"]) -> SE3:
    """exp of the twist (v, phi) (m, rad): translation V(phi) v, rotation exp(phi); finite values
    and exact first derivatives at phi = 0."""
    theta_sq = phi @ phi
    small = theta_sq < _SMALL_ANGLE_SQ
    t2 = jnp.where(small, 1.0, theta_sq)
    t = jnp.sqrt(t2)
    b = jnp.where(small, 0.5 - theta_sq / 24.0, (1.0 - jnp.cos(t)) / t2)  # (1 - cos t) / t^2
    c = jnp.where(small, 1.0 / 6.0 - theta_sq / 120.0, (t - jnp.sin(t)) / (t2 * t))  # (t - sin t) / t^3
    s = skew(phi)
    p = v + b * (s @ v) + c * (s @ (s @ v))
    return SE3.from_rotation_and_translation(SO3.exp(phi), p)


def rotation_matrix(q_wxyz: Float[ArrayLike, "4"]) -> Float[Array, "3 3"]:
    """Rotation matrix of a quaternion normalized first, so that small drift of a filter is harmless."""
    q_wxyz = jnp.asarray(q_wxyz)
    return SO3(q_wxyz / jnp.linalg.norm(q_wxyz)).as_matrix()


def quat_from_rpy(
    roll: Float[ArrayLike, ""], pitch: Float[ArrayLike, ""], yaw: Float[ArrayLike, ""]
) -> Float[Array, "4"]:
    """q = Rz(yaw) Ry(pitch) Rx(roll), (w, x, y, z): the IMU's ZYX Euler convention."""
    return SO3.from_rpy_radians(roll, pitch, yaw).wxyz


def roll_pitch(q_wxyz: Float[ArrayLike, "*B 4"]) -> tuple[Float[Array, "*B"], Float[Array, "*B"]]:
    """ZYX-Euler roll and pitch (rad) of world-from-base q, read from the world z axis in the base frame.

    Uses only R[2, :], so it is exact for any yaw; q may carry any scale and leading batch axes.
    """
    q_wxyz = jnp.asarray(q_wxyz)
    w, x, y, z = jnp.moveaxis(q_wxyz / jnp.linalg.norm(q_wxyz, axis=-1, keepdims=True), -1, 0)
    r20 = 2.0 * (x * z - w * y)
    r21 = 2.0 * (y * z + w * x)
    r22 = 1.0 - 2.0 * (x * x + y * y)
    pitch = jnp.arcsin(jnp.clip(-r20, -1.0, 1.0))
    roll = jnp.arctan2(r21, r22)
    return roll, pitch


def yaw_of(q_wxyz: Float[ArrayLike, "*B 4"]) -> Float[Array, "*B"]:
    """ZYX-Euler yaw (rad) of world-from-base q (any scale, leading batch axes)."""
    w, x, y, z = jnp.moveaxis(jnp.asarray(q_wxyz), -1, 0)
    return jnp.arctan2(2.0 * (w * z + x * y), 1.0 - 2.0 * (y * y + z * z))


def R_level_base(roll: Float[ArrayLike, ""], pitch: Float[ArrayLike, ""]) -> Float[Array, "3 3"]:
    """R_y(pitch) R_x(roll): base frame -> the gravity-levelled frame that shares the base's heading."""
    return (SO3.from_y_radians(pitch) @ SO3.from_x_radians(roll)).as_matrix()


def R2(theta: Float[ArrayLike, "*B"]) -> Float[Array, "*B 2 2"]:
    """Planar rotation matrices [[c, -s], [s, c]] (a child frame's axes in its parent's)."""
    c, s = jnp.cos(theta), jnp.sin(theta)
    return jnp.stack([jnp.stack([c, -s], -1), jnp.stack([s, c], -1)], -2)


def wrap_angle(a: Float[ArrayLike, "*batch"]) -> Float[Array, "*batch"]:
    """Angle wrapped to [-pi, pi)."""
    return (jnp.asarray(a) + jnp.pi) % (2.0 * jnp.pi) - jnp.pi


def se2(xy_theta: Float[Array, "*B 3"]) -> SE2:
    """SE(2) of (x, y, theta) rows (m, m, rad)."""
    return SE2.from_xy_theta(xy_theta[..., 0], xy_theta[..., 1], xy_theta[..., 2])


def xy_theta(T: SE2) -> Float[Array, "*B 3"]:
    """(x, y, theta) rows of SE(2) elements, theta in (-pi, pi]."""
    return jnp.concatenate([T.translation(), T.rotation().as_radians()[..., None]], axis=-1)
