"""Kinematics and rigid-body dynamics of one robot state in JAX, through MJX (jit/vmap/grad-able).

Conventions (MuJoCo's). qpos (nq,): free joint [p_world_base (m), quat_world_base (w, x, y, z)] then
joint angles (rad). qvel (nv,): free joint [v_world_base (m/s, world frame), omega_base (rad/s,
*base* frame)] then joint rates (rad/s). "Base" is the body carrying the free joint; base-frame
quantities are relative to that body's origin and expressed in its axes. Joint torques `tau` (nu,)
are in `Robot.joint_names` order (N m). Equations of motion with ground-reaction forces f acting on
the feet:

    M(q) vdot + C(q, v) v + g(q) = S^T tau + J(q)^T f,

where M includes joint armature, h = C v + g is MuJoCo's `qfrc_bias`, S^T scatters joint torques to
their dofs, and C is the Christoffel-consistent Coriolis matrix, so Mdot = C + C^T. Passive forces
(joint damping, frictionloss) are not part of h; a caller that wants them adds them to S^T tau.

Functions take one state; `jax.vmap` over states (and over `m` for per-robot model variations) at
the call site. `m` is an `mjx.Model` (traced: masses and inertias may be swept without recompiling);
`robot` is the static structure from `jaxquad.robots.load` (foot sites, joint addresses).
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
from jaxtyping import Array, Float
from mujoco import mjx

from jaxquad.robots import Robot

__all__ = [
    "bias_forces",
    "coriolis_transpose_v",
    "foot_jacobians_base",
    "foot_jacobians_world",
    "gravity_forces",
    "integrate_pos",
    "mass_matrix",
    "momentum_terms",
    "p_base_foot",
    "p_world_foot",
    "v_base_foot",
]


def _position_data(m: mjx.Model, qpos: Array, qvel: Array | None = None) -> mjx.Data:
    """Forward kinematics and composite inertias for one configuration."""
    d = mjx.make_data(m)
    d = d.replace(qpos=qpos) if qvel is None else d.replace(qpos=qpos, qvel=qvel)
    d = mjx.kinematics(m, d)
    return mjx.com_pos(m, d)


def mass_matrix(m: mjx.Model, qpos: Float[Array, "nq"]) -> Float[Array, "nv nv"]:
    """Joint-space inertia M(q) (nv, nv), armature included, as MuJoCo's `mj_fullM` (kg, kg m, kg m^2)."""
    d = mjx.crb(m, _position_data(m, qpos))
    return mjx.full_m(m, d)


def bias_forces(m: mjx.Model, qpos: Float[Array, "nq"], qvel: Float[Array, "nv"]) -> Float[Array, "nv"]:
    """h = C(q, v) v + g(q) (nv,), MuJoCo's `qfrc_bias` (N, N m)."""
    d = mjx.com_vel(m, _position_data(m, qpos, qvel))
    return mjx.rne(m, d).qfrc_bias


def gravity_forces(m: mjx.Model, qpos: Float[Array, "nq"]) -> Float[Array, "nv"]:
    """g(q) (nv,): generalized gravity force, the bias at zero velocity (N, N m)."""
    return bias_forces(m, qpos, jnp.zeros(m.nv, qpos.dtype))


def integrate_pos(
    m: mjx.Model, qpos: Float[Array, "nq"], qvel: Float[Array, "nv"], t: Float[Array, ""]
) -> Float[Array, "nq"]:
    """q(t) for constant velocity qvel, as MuJoCo's `mj_integratePos` with step t (s).

    Free joint: position += t v_world; quat <- quat * exp(t omega_base) (body-frame angular velocity,
    right multiplication). Ball joints likewise; hinge/slide joints add t qvel. Values and derivatives
    stay finite at t = 0 and at zero angular velocity (series branch of the exponential map).
    """
    parts = []
    for j, jtype in enumerate(np.asarray(m.jnt_type)):
        qa, va = int(m.jnt_qposadr[j]), int(m.jnt_dofadr[j])
        if jtype == mujoco.mjtJoint.mjJNT_FREE:
            parts.append(qpos[qa : qa + 3] + t * qvel[va : va + 3])
            parts.append(_quat_mul(qpos[qa + 3 : qa + 7], _quat_exp(t * qvel[va + 3 : va + 6])))
        elif jtype == mujoco.mjtJoint.mjJNT_BALL:
            parts.append(_quat_mul(qpos[qa : qa + 4], _quat_exp(t * qvel[va : va + 3])))
        else:
            parts.append(qpos[qa : qa + 1] + t * qvel[va : va + 1])
    return jnp.concatenate(parts)


def coriolis_transpose_v(
    m: mjx.Model, qpos: Float[Array, "nq"], qvel: Float[Array, "nv"]
) -> Float[Array, "nv"]:
    """C(q, v)^T v (nv,) for the Christoffel-consistent C: Mdot v - C v (N, N m).

    Mdot = d/dt M(q(t)) at t = 0 along q(t) = integrate_pos(q, v, t), by one forward-mode JVP, so
    the free joint's quaternion moves along its body-frame angular velocity exactly as MuJoCo's.
    """
    path = lambda t: mass_matrix(m, integrate_pos(m, qpos, qvel, t)) @ qvel
    _, mdot_v = jax.jvp(path, (jnp.zeros((), qpos.dtype),), (jnp.ones((), qpos.dtype),))
    c_v = bias_forces(m, qpos, qvel) - gravity_forces(m, qpos)
    return mdot_v - c_v


def momentum_terms(
    robot: Robot,
    qpos: Float[Array, "nq"],
    qvel: Float[Array, "nv"],
    tau: Float[Array, "nu"],
    m: mjx.Model | None = None,
) -> tuple[Float[Array, "nv"], Float[Array, "nv"], Float[Array, "4 nv"]]:
    """Inputs of the generalized-momentum contact observer: (p, tau_bar, J_z).

    p = M v (nv,); tau_bar = S^T tau + C^T v - g (nv,), so that dp/dt = tau_bar + J^T f with f the
    ground-reaction forces on the feet (convention of the module docstring); J_z (4, nv) = world-z
    rows of the foot point Jacobians (m per unit of qvel), feet in `robot.foot_names` order.
    `m` defaults to `robot.mjx_model`.
    """
    m = robot.mjx_model if m is None else m
    p = mass_matrix(m, qpos) @ qvel
    s_tau = jnp.zeros(m.nv, tau.dtype).at[robot.dof_adr].add(tau)
    tau_bar = s_tau + coriolis_transpose_v(m, qpos, qvel) - gravity_forces(m, qpos)
    j_z = foot_jacobians_world(robot, qpos, m)[:, 2, :]
    return p, tau_bar, j_z


def p_world_foot(robot: Robot, qpos: Float[Array, "nq"], m: mjx.Model | None = None) -> Float[Array, "4 3"]:
    """Foot site positions in the world frame (4, 3), m."""
    m = robot.mjx_model if m is None else m
    return _position_data(m, qpos).site_xpos[robot.foot_site_ids]


def _foot_jac_world(robot: Robot, m: mjx.Model, d: mjx.Data) -> Array:
    sites = robot.foot_site_ids
    body = jnp.asarray(np.asarray(m.site_bodyid)[sites])
    jacp = jax.vmap(lambda x, b: mjx.jac(m, d, x, b)[0])(d.site_xpos[sites], body)
    return jnp.swapaxes(jacp, 1, 2)


def p_base_foot(robot: Robot, qpos: Float[Array, "nq"], m: mjx.Model | None = None) -> Float[Array, "4 3"]:
    """Foot site positions relative to the base body origin, in base axes (4, 3), m."""
    m = robot.mjx_model if m is None else m
    d = _position_data(m, qpos)
    b = robot.base_body_id
    return (d.site_xpos[robot.foot_site_ids] - d.xpos[b]) @ d.xmat[b]


def foot_jacobians_world(
    robot: Robot, qpos: Float[Array, "nq"], m: mjx.Model | None = None
) -> Float[Array, "4 3 nv"]:
    """World-frame point Jacobians of the foot sites (4, 3, nv): v_world_foot = J qvel (m/s).

    Columns follow qvel's convention (free-joint angular columns act on the base-frame rate), as
    MuJoCo's `mj_jacSite`."""
    m = robot.mjx_model if m is None else m
    return _foot_jac_world(robot, m, _position_data(m, qpos))


def foot_jacobians_base(
    robot: Robot, qpos: Float[Array, "nq"], m: mjx.Model | None = None
) -> Float[Array, "4 3 nu"]:
    """d p_base_foot / d q_joints (4, 3, nu): base-frame foot Jacobians w.r.t. the actuated joints
    (robot.joint_names order; rad -> m). Rear feet of a spined robot have a nonzero spine column."""
    m = robot.mjx_model if m is None else m
    d = _position_data(m, qpos)
    jac_world = _foot_jac_world(robot, m, d)[:, :, robot.dof_adr]
    # The base does not move with the joints, so only the rotation into base axes remains.
    return jnp.einsum("ji,fjk->fik", d.xmat[robot.base_body_id], jac_world)


def v_base_foot(
    robot: Robot, qpos: Float[Array, "nq"], qvel: Float[Array, "nv"], m: mjx.Model | None = None
) -> Float[Array, "4 3"]:
    """Foot velocity relative to the base from joint motion only, J_base_foot qdot (4, 3), m/s in
    base axes: the v_foot of leg odometry, v_base = -omega x p_base_foot - v_base_foot per stance foot."""
    return foot_jacobians_base(robot, qpos, m) @ qvel[robot.dof_adr]


def _quat_mul(a: Array, b: Array) -> Array:
    w1, v1, w2, v2 = a[0], a[1:], b[0], b[1:]
    return jnp.concatenate([(w1 * w2 - v1 @ v2)[None], w1 * v2 + w2 * v1 + jnp.cross(v1, v2)])


def _quat_exp(rotvec: Array) -> Array:
    """Unit quaternion of a rotation vector (rad); series branch near zero keeps gradients finite."""
    half = 0.5 * rotvec
    x2 = half @ half
    small = x2 < 1e-8
    x2s = jnp.where(small, 1.0, x2)
    x = jnp.sqrt(x2s)
    cos = jnp.where(small, 1.0 - x2 / 2.0 + x2 * x2 / 24.0, jnp.cos(x))
    sinc = jnp.where(small, 1.0 - x2 / 6.0 + x2 * x2 / 120.0, jnp.sin(x) / x)
    return jnp.concatenate([cos[None], sinc * half])
