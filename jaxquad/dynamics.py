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
(joint springs and damping, MuJoCo's `qfrc_passive`) and joint friction loss are not part of h;
`passive_forces` models them and `momentum_terms` adds them to the observer's tau_bar by default.

Functions take one state; `jax.vmap` over states (and over `m` for per-robot model variations) at
the call site. `m` is an `mjx.Model` (traced: masses and inertias may be swept without recompiling);
`robot` is the static structure from `jaxquad.robots.load` (foot sites, joint addresses).
"""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
import mujoco
import numpy as np
from jaxtyping import Array, ArrayLike, Float

from jaxquad._mjx import mjx
from jaxquad.kernels.lie import SO3
from jaxquad.robots import Robot

__all__ = [
    "LegKinematics",
    "bias_forces",
    "coriolis_transpose_v",
    "foot_jacobians_base",
    "foot_jacobians_world",
    "gravity_forces",
    "integrate_pos",
    "leg_kinematics",
    "mass_matrix",
    "momentum_terms",
    "p_base_foot",
    "passive_forces",
    "v_base_foot",
]


def _position_data(m: mjx.Model, qpos: Array) -> mjx.Data:
    """Forward kinematics and body inertias/motion axes (com_pos) for one configuration."""
    d = mjx.make_data(m).replace(qpos=qpos)
    return mjx.com_pos(m, mjx.kinematics(m, d))


def mass_matrix(m: mjx.Model, qpos: Float[Array, "nq"]) -> Float[Array, "nv nv"]:
    """Joint-space inertia M(q) (nv, nv), armature included, as MuJoCo's `mj_fullM` (kg, kg m, kg m^2)."""
    return mjx.full_m(m, mjx.crb(m, _position_data(m, qpos)))


def bias_forces(m: mjx.Model, qpos: Float[Array, "nq"], qvel: Float[Array, "nv"]) -> Float[Array, "nv"]:
    """h = C(q, v) v + g(q) (nv,), MuJoCo's `qfrc_bias` (N, N m)."""
    return _bias(m, _position_data(m, qpos), qvel)


def gravity_forces(m: mjx.Model, qpos: Float[Array, "nq"]) -> Float[Array, "nv"]:
    """g(q) (nv,): generalized gravity force, the bias at zero velocity (N, N m)."""
    return _bias(m, _position_data(m, qpos), jnp.zeros(m.nv, qpos.dtype))


def _bias(m: mjx.Model, d: mjx.Data, qvel: Array) -> Array:
    """Recursive Newton-Euler bias at d's configuration and velocity qvel."""
    return mjx.rne(m, mjx.com_vel(m, d.replace(qvel=qvel))).qfrc_bias


def _momentum_and_rate(m: mjx.Model, qpos: Array, qvel: Array) -> tuple[Array, Array, mjx.Data]:
    """(M v, Mdot v, data at qpos): one kinematics pass under a forward-mode JVP along
    q(t) = integrate_pos(q, v, t) at t = 0, so the free joint's quaternion moves along its
    body-frame angular velocity exactly as in MuJoCo."""

    def path(t):
        d = _position_data(m, integrate_pos(m, qpos, qvel, t))
        return mjx.full_m(m, mjx.crb(m, d)) @ qvel, d

    zero, one = jnp.zeros((), qpos.dtype), jnp.ones((), qpos.dtype)
    p, mdot_v, d = jax.jvp(path, (zero,), (one,), has_aux=True)
    return p, mdot_v, d


def integrate_pos(
    m: mjx.Model, qpos: Float[Array, "nq"], qvel: Float[Array, "nv"], t: Float[ArrayLike, ""]
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
            parts.append((SO3(qpos[qa + 3 : qa + 7]) @ SO3.exp(t * qvel[va + 3 : va + 6])).wxyz)
        elif jtype == mujoco.mjtJoint.mjJNT_BALL:
            parts.append((SO3(qpos[qa : qa + 4]) @ SO3.exp(t * qvel[va : va + 3])).wxyz)
        else:
            parts.append(qpos[qa : qa + 1] + t * qvel[va : va + 1])
    return jnp.concatenate(parts)


def coriolis_transpose_v(m: mjx.Model, qpos: Float[Array, "nq"], qvel: Float[Array, "nv"]) -> Float[Array, "nv"]:
    """C(q, v)^T v (nv,) for the Christoffel-consistent C: Mdot v - C v (N, N m).

    Mdot = d/dt M(q(t)) at t = 0 along q(t) = integrate_pos(q, v, t), by a forward-mode JVP; C v is
    the bias minus gravity.
    """
    _, mdot_v, d = _momentum_and_rate(m, qpos, qvel)
    return mdot_v - _bias(m, d, qvel) + _bias(m, d, jnp.zeros_like(qvel))


def passive_forces(
    m: mjx.Model,
    qpos: Float[Array, "nq"],
    qvel: Float[Array, "nv"],
    friction_velocity: float | Float[Array, ""] = 0.5,
) -> Float[Array, "nv"]:
    """Joint forces the model knows besides actuators, gravity and contacts (nv,), N or N m:
    MuJoCo's `qfrc_passive` (joint springs, damping -damping * qvel, gravity compensation) plus
    a smooth model of joint friction loss, -frictionloss * tanh(qvel / friction_velocity).

    MuJoCo applies friction loss as a constraint: a force of magnitude up to `frictionloss` opposing
    the velocity at the end of the step, any value in between while the joint sticks. The tanh is its
    smooth stand-in (rad/s or m/s, > 0); it reaches 76% of the friction level at `friction_velocity`.
    The default 0.5 rad/s follows the mean constraint force against joint speed of the built-in
    models at their 4 ms step (about 40% of the level at 0.2 rad/s, 80% at 0.6 rad/s).
    """
    return _passive(m, _position_data(m, qpos), qvel, friction_velocity)


def _passive(m: mjx.Model, d: mjx.Data, qvel: Array, friction_velocity) -> Array:
    spring_damper = mjx.passive(m, d.replace(qvel=qvel)).qfrc_passive
    return spring_damper - m.dof_frictionloss * jnp.tanh(qvel / friction_velocity)


def momentum_terms(
    robot: Robot,
    qpos: Float[Array, "nq"],
    qvel: Float[Array, "nv"],
    tau: Float[Array, "nu"],
    m: mjx.Model | None = None,
    *,
    passive: bool = True,
    friction_velocity: float | Float[Array, ""] = 0.5,
    axes: str = "z",
) -> tuple[Float[Array, "nv"], Float[Array, "nv"], Float[Array, "R nv"]]:
    """Inputs of the generalized-momentum contact observer: (p, tau_bar, J_rows).

    p = M v (nv,); tau_bar = S^T tau + C^T v - g + passive = S^T tau + Mdot v - h + passive (nv,),
    so that dp/dt = tau_bar + J^T f with f the ground-reaction forces on the feet (convention of
    the module docstring). `passive` adds `passive_forces` (joint damping, springs, smooth friction
    loss with `friction_velocity`); without it tau_bar is the rigid-body part only. `tau` are joint
    torques in `robot.joint_names` order (N m). `m` defaults to `robot.mjx_model`.

    J_rows are rows of the foot point Jacobians in world axes (m per unit of qvel), feet in
    `robot.foot_names` order: axes="z" gives the z rows (4, nv); axes="xyz" all three per foot
    (12, nv), row 3 f + a for foot f and axis a, for an observer of full foot forces (the tangential
    friction forces of stance feet otherwise leak into the z estimates of the other feet).
    """
    if axes not in ("z", "xyz"):
        raise ValueError(f"axes must be 'z' or 'xyz', got {axes!r}")
    m = robot.mjx_model if m is None else m
    p, mdot_v, d = _momentum_and_rate(m, qpos, qvel)
    s_tau = jnp.zeros(m.nv, tau.dtype).at[robot.dof_adr].add(tau)
    tau_bar = s_tau + mdot_v - _bias(m, d, qvel)
    if passive:
        tau_bar = tau_bar + _passive(m, d, qvel, friction_velocity)
    jac = _foot_jac_world(robot, m, d)
    rows = jac[:, 2, :] if axes == "z" else jac.reshape(-1, m.nv)
    return p, tau_bar, rows


class LegKinematics(eqx.Module):
    """Foot kinematics of one state, feet in `robot.foot_names` order, joints in `robot.joint_names`
    order. Base-frame quantities are relative to the base body origin, in base axes."""

    p_world_foot: Float[Array, "4 3"]  # m
    p_base_foot: Float[Array, "4 3"]  # m
    v_base_foot: Float[Array, "4 3"]  # m/s, from joint motion only: J_base_foot qdot
    J_base_foot: Float[Array, "4 3 nu"]  # d p_base_foot / d q_joints, m/rad
    J_world_foot: Float[Array, "4 3 nv"]  # v_world_foot = J_world_foot qvel (as mj_jacSite)
    # rad/s: angular velocity of each foot's body relative to the base from joint motion, base axes
    # (the rolling of a round foot: `kernels.rolling_contact`)
    omega_base_foot: Float[Array, "4 3"]


def leg_kinematics(
    robot: Robot, qpos: Float[Array, "nq"], qvel: Float[Array, "nv"], m: mjx.Model | None = None
) -> LegKinematics:
    """All foot kinematics from one kinematics pass (what leg odometry and the simulator's sensors use).

    v_base_foot is the v_foot of leg odometry (v_base = -omega x p_base_foot - v_base_foot per stance
    foot). For a spined robot the rear feet's base-frame quantities include the spine joint (one of
    the actuated joints). `m` defaults to `robot.mjx_model`.
    """
    m = robot.mjx_model if m is None else m
    d = _position_data(m, qpos)
    b = robot.base_body_id
    R_world_base = d.xmat[b]
    p_world_foot = d.site_xpos[robot.foot_site_ids]
    J_world_foot, J_rot_world_foot = _foot_jac_world(robot, m, d, rotation=True)
    # The base does not move with the joints, so only the rotation into base axes remains.
    J_base_foot = jnp.einsum("ji,fjk->fik", R_world_base, J_world_foot[:, :, robot.dof_adr])
    J_rot_base_foot = jnp.einsum("ji,fjk->fik", R_world_base, J_rot_world_foot[:, :, robot.dof_adr])
    return LegKinematics(
        p_world_foot=p_world_foot,
        p_base_foot=(p_world_foot - d.xpos[b]) @ R_world_base,
        v_base_foot=J_base_foot @ qvel[robot.dof_adr],
        J_base_foot=J_base_foot,
        J_world_foot=J_world_foot,
        omega_base_foot=J_rot_base_foot @ qvel[robot.dof_adr],
    )


def _foot_jac_world(robot: Robot, m: mjx.Model, d: mjx.Data, rotation: bool = False):
    """(4, 3, nv) world-frame point Jacobians of the foot sites at d's configuration; with
    `rotation` also the (4, 3, nv) rotational Jacobians of the foot bodies."""
    sites = robot.foot_site_ids
    body = jnp.asarray(np.asarray(m.site_bodyid)[sites])
    jacp, jacr = jax.vmap(lambda x, b: mjx.jac(m, d, x, b))(d.site_xpos[sites], body)
    if rotation:
        return jnp.swapaxes(jacp, 1, 2), jnp.swapaxes(jacr, 1, 2)
    return jnp.swapaxes(jacp, 1, 2)


def p_base_foot(robot: Robot, qpos: Float[Array, "nq"], m: mjx.Model | None = None) -> Float[Array, "4 3"]:
    """Foot site positions relative to the base body origin, in base axes (4, 3), m."""
    return leg_kinematics(robot, qpos, jnp.zeros(robot.nv, qpos.dtype), m).p_base_foot


def v_base_foot(
    robot: Robot, qpos: Float[Array, "nq"], qvel: Float[Array, "nv"], m: mjx.Model | None = None
) -> Float[Array, "4 3"]:
    """Foot velocity relative to the base from joint motion only, J_base_foot qdot (4, 3), m/s."""
    return leg_kinematics(robot, qpos, qvel, m).v_base_foot


def foot_jacobians_base(robot: Robot, qpos: Float[Array, "nq"], m: mjx.Model | None = None) -> Float[Array, "4 3 nu"]:
    """d p_base_foot / d q_joints (4, 3, nu), w.r.t. the actuated joints (m/rad)."""
    return leg_kinematics(robot, qpos, jnp.zeros(robot.nv, qpos.dtype), m).J_base_foot


def foot_jacobians_world(robot: Robot, qpos: Float[Array, "nq"], m: mjx.Model | None = None) -> Float[Array, "4 3 nv"]:
    """World-frame point Jacobians of the foot sites (4, 3, nv), as MuJoCo's `mj_jacSite`: columns
    follow qvel's convention (free-joint angular columns act on the base-frame rate)."""
    return leg_kinematics(robot, qpos, jnp.zeros(robot.nv, qpos.dtype), m).J_world_foot
