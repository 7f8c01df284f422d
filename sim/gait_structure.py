"""The trot controller's static structure, read from a robot's MuJoCo model: leg chains, the home pose,
the spine, torque limits (`Gait`). The controller itself is `jaxquad.sim.locomotion`."""

from __future__ import annotations

import equinox as eqx
import jax.numpy as jnp
import mujoco
import numpy as np
from jaxtyping import Array, Float

from .leg_ik import LegGeometry, knee_branch, leg_fk


class Gait(eqx.Module):
    """Static structure of one robot's controller, read from its MuJoCo model.

    Leg geometry is in the trunk that carries each leg at zero joint angles (rear legs of a
    spined robot: the rear trunk at zero spine angle, in base coordinates).
    """

    legs: LegGeometry
    p_base_foot_home: Float[Array, "4 3"]  # foot centres at the home pose, base frame (m)
    p_base_spine: Float[Array, " 3"]  # spine joint anchor, base frame (m); zeros without spine
    spine_sign: Float[Array, ""]  # +1 when the spine turns about +y
    tau_limit: Float[Array, " nu"]  # actuator torque limits (N m)
    mass: Float[Array, ""]  # total mass (kg)
    foot_radius: Float[Array, ""]  # m
    body_height: Float[Array, ""]  # base height of the home pose on flat ground (m)
    leg_qpos: tuple[tuple[int, ...], ...] = eqx.field(static=True)  # (4, 3) qpos addresses
    leg_dof: tuple[tuple[int, ...], ...] = eqx.field(static=True)  # (4, 3) qvel addresses
    leg_act: tuple[tuple[int, ...], ...] = eqx.field(static=True)  # (4, 3) actuator indices
    on_spine: tuple[bool, ...] = eqx.field(static=True)  # legs carried by the rear trunk
    spine_qpos: int = eqx.field(static=True)  # -1 without spine
    spine_dof: int = eqx.field(static=True)
    spine_act: int = eqx.field(static=True)
    nu: int = eqx.field(static=True)

    @property
    def has_spine(self) -> bool:
        return self.spine_act >= 0

    @classmethod
    def from_model(
        cls,
        model: mujoco.MjModel,
        leg_joint_names: tuple[tuple[str, str, str], ...],
        foot_site_names: tuple[str, ...],
        spine_joint_name: str | None = None,
        home_key: str = "home",
    ) -> "Gait":
        """Read the leg chains (abduction, thigh, knee joints; foot sites FL FR RL RR).

        The home pose (keyframe `home_key`, else qpos0) fixes the knee branch and the nominal
        footholds; `tau_limit` comes from the actuators' ctrl/force ranges and gears.
        """
        if len(leg_joint_names) != 4 or len(foot_site_names) != 4:
            raise ValueError("Gait.from_model: expected 4 legs (FL FR RL RR) of 3 joints and 4 foot sites")
        if model.jnt_type[0] != mujoco.mjtJoint.mjJNT_FREE:
            raise ValueError("Gait.from_model: the model's first joint must be the free base joint")

        def jid(name: str) -> int:
            i = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_JOINT, name)
            if i < 0:
                raise ValueError(f"Gait.from_model: no joint named {name!r}")
            return i

        act_of_joint = {int(model.actuator_trnid[a, 0]): a for a in range(model.nu)}
        leg_jnt = np.array([[jid(n) for n in leg] for leg in leg_joint_names])
        spine_jnt = jid(spine_joint_name) if spine_joint_name is not None else -1
        for j in [*leg_jnt.ravel(), *([spine_jnt] if spine_jnt >= 0 else [])]:
            if j not in act_of_joint:
                raise ValueError(f"Gait.from_model: joint {model.joint(j).name!r} has no actuator")

        # Zero joint angles, base at the origin with identity attitude.
        data = mujoco.MjData(model)
        data.qpos[:] = 0.0
        data.qpos[3] = 1.0
        mujoco.mj_kinematics(model, data)
        anchor = data.xanchor[leg_jnt]  # (4, 3, 3): leg, joint, xyz
        axis = data.xaxis[leg_jnt]
        expected = np.array([[1.0, 0, 0], [0, 1.0, 0], [0, 1.0, 0]])
        sign = np.sum(axis * expected, -1)
        if not np.allclose(np.abs(sign), 1.0, atol=1e-6):
            raise ValueError("Gait.from_model: leg joints must turn about the trunk's x, y, y axes")
        site = [mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_SITE, n) for n in foot_site_names]
        if min(site) < 0:
            raise ValueError(f"Gait.from_model: missing foot site among {foot_site_names}")
        p_foot = data.site_xpos[site]
        foot_geom = [mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_GEOM, n) for n in foot_site_names]
        radius = float(model.geom_size[foot_geom[0], 0]) if min(foot_geom) >= 0 else float(model.site_size[site[0], 0])

        on_spine = np.zeros(4, bool)
        p_spine = np.zeros(3)
        spine_sign = 1.0
        if spine_jnt >= 0:
            spine_body = model.jnt_bodyid[spine_jnt]
            for leg in range(4):
                b = model.jnt_bodyid[leg_jnt[leg, 0]]
                while b > 0 and b != spine_body:
                    b = model.body_parentid[b]
                on_spine[leg] = b == spine_body
            p_spine = data.xanchor[spine_jnt].copy()
            spine_sign = float(np.sign(data.xaxis[spine_jnt, 1]))

        key = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_KEY, home_key)
        q_home_full = model.key_qpos[key] if key >= 0 else model.qpos0
        q_home = q_home_full[model.jnt_qposadr[leg_jnt]]
        lo, hi = model.jnt_range[leg_jnt, 0], model.jnt_range[leg_jnt, 1]
        limited = model.jnt_limited[leg_jnt].astype(bool)
        d1 = anchor[:, 1] - anchor[:, 0]
        d2 = anchor[:, 2] - anchor[:, 1]
        d3 = p_foot - anchor[:, 2]
        legs = LegGeometry(
            p_trunk_hip=jnp.asarray(anchor[:, 0], jnp.float32),
            d_hip_thigh=jnp.asarray(d1, jnp.float32),
            d_thigh_knee=jnp.asarray(d2, jnp.float32),
            d_knee_foot=jnp.asarray(d3, jnp.float32),
            axis_sign=jnp.asarray(sign, jnp.float32),
            knee_bend=jnp.asarray(knee_branch(d2, d3, sign, q_home), jnp.float32),
            q_min=jnp.asarray(np.where(limited, lo, -np.pi), jnp.float32),
            q_max=jnp.asarray(np.where(limited, hi, np.pi), jnp.float32),
        )
        # Home pose with the spine straight, as seen from the base.
        p_home = np.asarray(leg_fk(legs, jnp.asarray(q_home, jnp.float32)))
        body_height = -float(np.min(p_home[:, 2])) + radius

        gear = model.actuator_gear[:, 0]
        ctrl_lim = np.where(model.actuator_ctrllimited.astype(bool), np.abs(model.actuator_ctrlrange).max(1), np.inf)
        force_lim = np.where(model.actuator_forcelimited.astype(bool), np.abs(model.actuator_forcerange).max(1), np.inf)
        tau_limit = np.minimum(ctrl_lim * np.abs(gear), force_lim)
        return cls(
            legs=legs,
            p_base_foot_home=jnp.asarray(p_home, jnp.float32),
            p_base_spine=jnp.asarray(p_spine, jnp.float32),
            spine_sign=jnp.asarray(spine_sign, jnp.float32),
            tau_limit=jnp.asarray(tau_limit, jnp.float32),
            mass=jnp.asarray(float(np.sum(model.body_mass)), jnp.float32),
            foot_radius=jnp.asarray(radius, jnp.float32),
            body_height=jnp.asarray(body_height, jnp.float32),
            leg_qpos=tuple(tuple(int(model.jnt_qposadr[j]) for j in leg) for leg in leg_jnt),
            leg_dof=tuple(tuple(int(model.jnt_dofadr[j]) for j in leg) for leg in leg_jnt),
            leg_act=tuple(tuple(act_of_joint[int(j)] for j in leg) for leg in leg_jnt),
            on_spine=tuple(bool(x) for x in on_spine),
            spine_qpos=int(model.jnt_qposadr[spine_jnt]) if spine_jnt >= 0 else -1,
            spine_dof=int(model.jnt_dofadr[spine_jnt]) if spine_jnt >= 0 else -1,
            spine_act=act_of_joint[spine_jnt] if spine_jnt >= 0 else -1,
            nu=int(model.nu),
        )

    @classmethod
    def for_robot(cls, robot) -> "Gait":
        """Controller structure for a `jaxquad.robots.Robot`."""
        names = robot.joint_names
        legs = tuple(tuple(names[int(i)] for i in leg) for leg in np.asarray(robot.leg_joints))
        return cls.from_model(robot.mj_model, legs, tuple(robot.foot_names), robot.spine_joint)
