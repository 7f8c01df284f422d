"""Leg-inertial odometry: integrate the base twist on SE(3) with the exponential map.

Over a step of dt seconds with body-frame twist (v, omega), the pose moves by
exp([v dt, omega dt]): rotation exp(omega dt) and translation V(omega dt) v dt with
V(phi) = I + B S(phi) + C S(phi)^2, B = (1 - cos t)/t^2, C = (t - sin t)/t^3, t = |phi|
(Barfoot, State Estimation for Robotics, eq. 7.86). When an attitude is known (from the log
or the attitude filter) it replaces the integrated rotation, the leg-inertial variant: the
legs give the translation, the IMU the orientation.
"""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
from jaxtyping import Array, Bool, Float

from jaxquad.kernels import lie
from jaxquad.kernels.lie import SO3, rotation_matrix


class Pose(eqx.Module):
    """World-from-base pose; leaves gain a leading time axis in trajectories."""

    p_world_base: Float[Array, "*T 3"]  # m
    q_world_base: Float[Array, "*T 4"]  # w x y z


def se3_exp(v: Float[Array, "3"], phi: Float[Array, "3"]) -> tuple[Float[Array, "3"], Float[Array, "4"]]:
    """Exponential of the twist (v, phi) (m, rad): the translation V(phi) v and quaternion exp(phi)."""
    T = lie.se3_exp(v, phi)
    return T.translation(), T.rotation().wxyz


def odometry_step(
    pose: Pose,
    v_base: Float[Array, "3"],
    omega_base: Float[Array, "3"],
    dt: Float[Array, ""],
    q_world_base_next: Float[Array, "4"] | None = None,
) -> Pose:
    """Move `pose` by the body twist (m/s, rad/s) held for dt seconds.

    With `q_world_base_next` the orientation is taken from it instead of being integrated.
    A non-finite or negative dt or twist leaves the pose unchanged.
    """
    ok = jnp.isfinite(dt) & (dt >= 0) & jnp.all(jnp.isfinite(v_base)) & jnp.all(jnp.isfinite(omega_base))
    h = jnp.where(ok, dt, 0.0)
    dp_base, dq = se3_exp(jnp.where(ok, v_base, 0.0) * h, jnp.where(ok, omega_base, 0.0) * h)
    p = pose.p_world_base + rotation_matrix(pose.q_world_base) @ dp_base
    if q_world_base_next is None:
        q = (SO3(pose.q_world_base) @ SO3(dq)).wxyz
    else:
        q_ok = jnp.all(jnp.isfinite(q_world_base_next))
        q = jnp.where(q_ok, q_world_base_next, (SO3(pose.q_world_base) @ SO3(dq)).wxyz)
    return Pose(p_world_base=p, q_world_base=q / jnp.linalg.norm(q))


def integrate_twist(
    pose0: Pose,
    t: Float[Array, "T"],
    v_base: Float[Array, "T 3"],
    omega_base: Float[Array, "T 3"],
    q_world_base: Float[Array, "T 4"] | None = None,
    valid: Bool[Array, "T"] | None = None,
) -> Pose:
    """Trajectory (leaves (T, 3) and (T, 4)) of one robot from pose0 at t[0].

    Sample k applies the twist of sample k-1 over t[k] - t[k-1]. With `q_world_base`, the
    orientation follows it (and pose0's orientation is replaced by q_world_base[0]). Where
    `valid` is False the twist of that sample is not applied (the pose is held).
    """
    dt = jnp.diff(t)
    ok = jnp.ones(t.shape, bool) if valid is None else valid
    hold = jnp.where(ok[:-1], dt, 0.0)
    if q_world_base is not None:
        pose0 = Pose(p_world_base=pose0.p_world_base, q_world_base=q_world_base[0])
        xs = (v_base[:-1], omega_base[:-1], hold, q_world_base[1:])
    else:
        xs = (v_base[:-1], omega_base[:-1], hold, None)

    def body(pose, x):
        v, w, h, q_next = x
        pose = odometry_step(pose, v, w, h, q_next)
        return pose, pose

    _, traj = jax.lax.scan(body, pose0, xs)
    return jax.tree.map(lambda a, b: jnp.concatenate([a[None], b]), pose0, traj)
