"""Model-based trot controller for the simulated quadrupeds (no learning).

One robot per call: `gait_step` maps the ground-truth base and joint state plus a body velocity
command to joint torques. It tracks foot targets kept in the *level frame* (base origin, yaw of the
base, z up): stance feet slide backwards with the commanded body motion, swing feet fly to a
Raibert foothold; the targets are turned into the trunk frame through the commanded body roll and
pitch (so the stance legs hold height and attitude), solved by analytic leg IK and tracked by joint
PD plus a gravity share J^T f on the stance legs. On robots with a spine (badger) the spine swings
with the trot and the rear legs' targets are expressed in the rear trunk through the measured
spine angle.

Static structure (`Gait`) comes from the MuJoCo model; every tunable number (`GaitParams`) is a
traced leaf, so a fleet can randomize gains and styles under `jax.vmap` without recompiling.
"""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
import mujoco
import numpy as np
from jaxtyping import Array, Bool, Float

from jaxquad.kernels.lie import SO3, R_level_base, roll_pitch, rotation_matrix, yaw_of

from .gait import TROT_OFFSETS, leg_phases, raibert_foothold, swing_position
from .leg_ik import LegGeometry, knee_branch, leg_fk, leg_ik

_GRAVITY = 9.81
_QD_MAX = 20.0  # rad/s: bound on differenced joint target velocities


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


def _f32(x) -> Array:
    return jnp.asarray(x, jnp.float32)


class GaitParams(eqx.Module):
    """Per-robot tunable numbers (all traced; shapes fixed so vmapped fleets never recompile)."""

    step_freq: Float[Array, ""]  # gait cycles per second (Hz)
    duty: Float[Array, ""]  # stance share of a cycle
    swing_height: Float[Array, ""]  # m
    body_height: Float[Array, ""]  # desired base height above the floor (m)
    kp: Float[Array, " 3"]  # joint stiffness for abduction, thigh, knee (N m / rad)
    kd: Float[Array, " 3"]  # joint damping (N m s / rad)
    kp_spine: Float[Array, ""]
    kd_spine: Float[Array, ""]
    spine_amp: Float[Array, ""]  # spine swing amplitude (rad), in phase with the trot
    k_raibert: Float[Array, ""]  # foothold feedback on velocity error (s)
    k_velocity: Float[Array, ""]  # stance feet slide faster by this share of the velocity shortfall
    max_step: Float[Array, ""]  # largest foothold offset from the home foot position (m)
    v_max: Float[Array, " 3"]  # command limits vx, vy (m/s), yaw rate (rad/s)
    acc_max: Float[Array, " 3"]  # command rate limits (m/s^2, m/s^2, rad/s^2)
    roll_amp: Float[Array, ""]  # deliberate body roll oscillation amplitude (rad)
    pitch_amp: Float[Array, ""]  # deliberate body pitch oscillation amplitude (rad)
    attitude_freq: Float[Array, ""]  # Hz; pitch leads roll by a quarter period
    k_attitude: Float[Array, ""]  # extra attitude correction per rad of error
    k_height: Float[Array, ""]  # extra leg extension per m of height error
    stop_go_period: Float[Array, ""]  # s; the command is zeroed for (1 - stop_go_duty) of it
    stop_go_duty: Float[Array, ""]  # 1 = never stop
    weight_ff: Float[Array, ""]  # share of the body weight fed forward through the stance legs
    time_offset: Float[Array, ""]  # s added to `t` for the attitude and stop-and-go patterns

    @classmethod
    def calm(cls, gait: Gait, **overrides) -> "GaitParams":
        """Smooth walking around 0.3-0.5 m/s, level body."""
        values = dict(
            step_freq=2.5,
            duty=0.5,
            swing_height=0.07,
            body_height=float(gait.body_height),
            kp=_stiffness(gait),
            kd=(1.0, 1.0, 1.0),
            kp_spine=60.0,
            kd_spine=2.0,
            spine_amp=0.05 if gait.has_spine else 0.0,
            k_raibert=0.15,
            k_velocity=0.5,
            max_step=0.15,
            v_max=(0.5, 0.3, 0.8),
            acc_max=(0.5, 0.5, 1.0),
            roll_amp=0.0,
            pitch_amp=0.0,
            attitude_freq=0.5,
            k_attitude=0.3,
            k_height=0.5,
            stop_go_period=4.0,
            stop_go_duty=1.0,
            weight_ff=1.0,
            time_offset=0.0,
        )
        values.update(overrides)
        return cls(**{k: _f32(v) for k, v in values.items()})

    @classmethod
    def aggressive(cls, gait: Gait, **overrides) -> "GaitParams":
        """Fast steps up to 1 m/s, abrupt command changes, stop-and-go, swinging body attitude."""
        values = dict(
            step_freq=3.0,
            swing_height=0.08,
            spine_amp=0.1 if gait.has_spine else 0.0,
            k_raibert=0.15,
            max_step=0.2,
            v_max=(1.0, 0.5, 1.5),
            acc_max=(3.0, 2.0, 4.0),
            roll_amp=0.15,
            pitch_amp=0.15,
            attitude_freq=0.8,
            k_attitude=1.0,
            stop_go_period=3.0,
            stop_go_duty=0.7,
        )
        values.update(overrides)
        return cls.calm(gait, **values)


def _stiffness(gait: Gait) -> tuple[float, float, float]:
    # Stiffness scaled with the weaker leg motor so a 0.5 rad error saturates it (go2: ~47, badger: 32).
    tau = float(np.min(np.asarray(gait.tau_limit)[np.asarray(gait.leg_act)]))
    k = 2.0 * tau
    return (k, k, k)


class GaitState(eqx.Module):
    phase: Float[Array, ""]  # gait cycles since start
    cmd: Float[Array, " 3"]  # rate-limited command vx, vy, yaw rate (body frame)
    p_level_foot: Float[Array, "4 3"]  # foot centre targets in the level frame (m)
    p_level_lift: Float[Array, "4 3"]  # where each foot last lifted off, level frame (m)
    stance: Bool[Array, " 4"]
    q_des: Float[Array, "4 3"]  # last joint targets (rad), differenced into target velocities
    ok: Bool[Array, ""]  # False once a non-finite input was seen (torques then stay zero)


def gait_init(gait: Gait, params: GaitParams) -> GaitState:
    p0 = _home_level(gait, params)
    stance, _ = leg_phases(jnp.zeros(()), _f32(TROT_OFFSETS), params.duty)
    return GaitState(
        phase=jnp.zeros(()),
        cmd=jnp.zeros(3),
        p_level_foot=p0,
        p_level_lift=p0,
        stance=stance,
        q_des=leg_ik(gait.legs, gait.p_base_foot_home)[0],
        ok=jnp.ones((), bool),
    )


def _home_level(gait: Gait, params: GaitParams) -> Float[Array, "4 3"]:
    z = -params.body_height + gait.foot_radius
    return gait.p_base_foot_home.at[:, 2].set(z)


def base_to_leg_trunk(gait: Gait, p_base_foot: Float[Array, "4 3"], q_spine: Float[Array, ""]) -> Float[Array, "4 3"]:
    """Foot points from the base frame into the frame of the trunk carrying each leg (m).

    Legs on the rear trunk of a spined robot see the point rotated back by the spine angle (rad)
    about the spine anchor; the other legs' trunk is the base itself.
    """
    R_spine = SO3.from_y_radians(gait.spine_sign * q_spine).as_matrix()
    p_rear = gait.p_base_spine + (p_base_foot - gait.p_base_spine) @ R_spine  # rows: R^T p
    return jnp.where(jnp.array(gait.on_spine)[:, None], p_rear, p_base_foot)


def gait_step(
    gait: Gait,
    params: GaitParams,
    state: GaitState,
    qpos: Float[Array, " nq"],
    qvel: Float[Array, " nv"],
    command: Float[Array, " 3"],
    t: Float[Array, ""],
    dt: Float[Array, ""],
) -> tuple[GaitState, Float[Array, " nu"]]:
    """New state and joint torques (nu,) for one control period `dt` (s) at time `t` (s).

    `command` is (vx, vy, yaw rate) in the body frame (m/s, rad/s); it is clipped to `v_max`,
    gated by the stop-and-go pattern and rate limited by `acc_max`. Non-finite inputs zero the
    torques and latch `state.ok` to False, so one bad robot cannot poison a batch.
    """
    ok = state.ok & jnp.all(jnp.isfinite(qpos)) & jnp.all(jnp.isfinite(qvel)) & jnp.all(jnp.isfinite(command))
    qpos = jnp.where(ok, qpos, 0.0).at[3].set(jnp.where(ok, qpos[3], 1.0))
    qvel = jnp.where(ok, qvel, 0.0)
    command = jnp.where(ok, command, 0.0)

    # Base state (free joint: world position, wxyz quaternion; world linear, body angular velocity).
    R_world_base = rotation_matrix(qpos[3:7])
    roll, pitch = roll_pitch(qpos[3:7])
    yaw = yaw_of(qpos[3:7])
    cy, sy = jnp.cos(yaw), jnp.sin(yaw)
    v_level = jnp.array([cy * qvel[0] + sy * qvel[1], -sy * qvel[0] + cy * qvel[1]])

    # Command: limits, stop-and-go, rate limits.
    t = t + params.time_offset  # desynchronizes the patterns of a fleet
    go = jnp.mod(t, params.stop_go_period) < params.stop_go_duty * params.stop_go_period
    target = jnp.where(go, jnp.clip(command, -params.v_max, params.v_max), 0.0)
    step = params.acc_max * dt
    cmd = state.cmd + jnp.clip(target - state.cmd, -step, step)

    # Gait clock and foot targets in the level frame.
    phase = state.phase + params.step_freq * dt
    stance, progress = leg_phases(phase, _f32(TROT_OFFSETS), params.duty)
    lifted = state.stance & ~stance
    p_lift = jnp.where(lifted[:, None], state.p_level_foot, state.p_level_lift)

    home = _home_level(gait, params)
    z_ground = home[:, 2] - params.k_height * (params.body_height - qpos[2])
    p_prev = state.p_level_foot
    # Stance feet carry the body at the command, plus a push where the body lags behind it.
    yaw_rate = (R_world_base @ qvel[3:6])[2]
    v_slide = cmd[:2] + params.k_velocity * jnp.clip(cmd[:2] - v_level, -0.5, 0.5)
    w_slide = cmd[2] + params.k_velocity * jnp.clip(cmd[2] - yaw_rate, -0.5, 0.5)
    slide = v_slide + w_slide * jnp.stack([-p_prev[:, 1], p_prev[:, 0]], -1)
    p_stance = jnp.concatenate([p_prev[:, :2] - slide * dt, z_ground[:, None]], -1)

    t_stance = params.duty / params.step_freq
    land_xy = raibert_foothold(home[:, :2], v_level, cmd[:2], cmd[2], t_stance, params.k_raibert)
    offset = land_xy - home[:, :2]
    offset = offset * jnp.minimum(1.0, params.max_step / jnp.maximum(jnp.linalg.norm(offset, axis=-1), 1e-9))[:, None]
    p_land = jnp.concatenate([home[:, :2] + offset, z_ground[:, None]], -1)
    p_swing = swing_position(p_lift, p_land, progress, params.swing_height)
    p_level = jnp.where(stance[:, None], p_stance, p_swing)

    # Level frame -> trunk frame through the commanded roll and pitch (with feedback).
    w = 2.0 * jnp.pi * params.attitude_freq * t
    roll_des = params.roll_amp * jnp.sin(w)
    pitch_des = params.pitch_amp * jnp.cos(w)
    roll_cmd = roll_des + params.k_attitude * (roll_des - roll)
    pitch_cmd = pitch_des + params.k_attitude * (pitch_des - pitch)
    p_base_foot = p_level @ R_level_base(roll_cmd, pitch_cmd)  # rows: R^T p

    # Spine: swing with the trot; rear feet expressed in the rear trunk via the measured angle.
    on_spine = jnp.array(gait.on_spine)[:, None]
    q_spine = qpos[gait.spine_qpos] if gait.has_spine else jnp.zeros(())
    R_spine = SO3.from_y_radians(gait.spine_sign * q_spine).as_matrix()
    p_trunk_foot = base_to_leg_trunk(gait, p_base_foot, q_spine)

    q_des, _ = leg_ik(gait.legs, p_trunk_foot)
    idx_q, idx_v = np.asarray(gait.leg_qpos), np.asarray(gait.leg_dof)
    q, qd = qpos[idx_q], qvel[idx_v]
    qd_des = jnp.clip((q_des - state.q_des) / dt, -_QD_MAX, _QD_MAX)
    tau_pd = params.kp * (q_des - q) + params.kd * (qd_des - qd)

    # Gravity share through the stance legs: tau = J^T f, f the push of the foot on the ground.
    n_stance = jnp.maximum(jnp.sum(stance), 1).astype(jnp.float32)
    f_world = jnp.array([0.0, 0.0, -1.0]) * (params.weight_ff * gait.mass * _GRAVITY / n_stance)
    f_base = R_world_base.T @ f_world
    f_trunk = jnp.where(stance[:, None], jnp.where(on_spine, f_base @ R_spine, f_base), 0.0)
    jac = jax.vmap(jax.jacfwd(leg_fk, argnums=1))(gait.legs, q)  # (4, 3 xyz, 3 joints)
    tau_ff = jnp.einsum("lij,li->lj", jac, f_trunk)

    tau = jnp.zeros(gait.nu).at[np.asarray(gait.leg_act)].set(tau_pd + tau_ff)
    if gait.has_spine:
        q_spine_des = params.spine_amp * jnp.sin(2.0 * jnp.pi * phase)
        tau_spine = params.kp_spine * (q_spine_des - q_spine) - params.kd_spine * qvel[gait.spine_dof]
        tau = tau.at[gait.spine_act].set(tau_spine)
    tau = jnp.where(ok, jnp.clip(tau, -gait.tau_limit, gait.tau_limit), 0.0)

    new_state = GaitState(
        phase=jnp.mod(phase, 1.0),
        cmd=cmd,
        p_level_foot=p_level,
        p_level_lift=p_lift,
        stance=stance,
        q_des=q_des,
        ok=ok,
    )
    return new_state, tau
