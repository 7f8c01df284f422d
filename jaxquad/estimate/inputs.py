"""One path from a robot log to the estimators' inputs, shared by the pipeline and the tuner.

`robot_inputs` parses and reorders a log once (joints by name into the model's order, a single
log as a fleet of one, contact weights from the chosen source, initial pose); `full_state` assembles
the MJX state (qpos, qvel) that the momentum observer needs from a base pose and velocity; `step_dt`
says which samples the observer integrates. The pipeline feeds `full_state` its own leg-odometry
velocity, the tuner the ground truth's; everything else both read from the same `RobotInputs`.
"""

from __future__ import annotations

import functools
from collections.abc import Mapping

import equinox as eqx
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Bool, Float

from jaxquad.kernels.lie import yaw_of

CONTACT_SOURCES = ("truth", "sensor", "observer", "mixed")
OBSERVER_ROWS = ("legs", "joints", "full")


class RobotInputs(eqx.Module):
    """One robot's log, in the robot model's joint and foot order (a fleet adds a leading axis N)."""

    dt: Float[Array, "*N T"]  # s since the previous sample (0 at sample 0), from float64 stamps
    q: Float[Array, "*N T nu"]  # rad
    qd: Float[Array, "*N T nu"]  # rad/s (NaN when the log has none)
    tau: Float[Array, "*N T nu"]  # N m (NaN when the log has none)
    gyro: Float[Array, "*N T 3"]  # rad/s, IMU frame
    acc: Float[Array, "*N T 3"]  # m/s^2, IMU frame
    quat_wxyz: Float[Array, "*N T 4"]  # world-from-base (identity when the log has none)
    contact_weight: Float[Array, "*N T F"]  # in [0, 1] (truth/sensor contacts)
    valid: Bool[Array, "*N T"]  # False where the log marks the robot invalid
    p0_world_base: Float[Array, "*N 3"]  # initial position, m
    yaw0: Float[Array, "*N"]  # initial heading (rad) when the attitude comes from the filter


@functools.lru_cache(maxsize=16)
def R_base_imu(robot) -> np.ndarray:
    """Rotation of the IMU site in the base frame, at the home configuration (MuJoCo C)."""
    import mujoco

    m = robot.mj_model
    d = mujoco.MjData(m)
    d.qpos[:] = robot.qpos_home
    mujoco.mj_kinematics(m, d)
    R_world_base = d.xmat[robot.base_body_id].reshape(3, 3)
    R_world_imu = d.site_xmat[robot.imu_site_id].reshape(3, 3)
    return R_world_base.T @ R_world_imu


def _joint_order(robot, log: Mapping) -> np.ndarray:
    names = [str(n) for n in np.asarray(log["joint_names"])]
    missing = [j for j in robot.joint_names if j not in names]
    if missing:
        raise ValueError(f"log has no joint(s) {missing} of robot {robot.name!r}")
    return np.array([names.index(j) for j in robot.joint_names])


def check_log(robot, log: Mapping, contacts: str = "truth") -> None:
    """Raise `robot_inputs`' one-line errors (an unknown contact source, joints of the robot missing
    from the log, keys the source needs) without building its arrays: a check before heavy work."""
    if contacts not in CONTACT_SOURCES:
        raise ValueError(f"contacts must be one of {', '.join(CONTACT_SOURCES)}, got {contacts!r}")
    _joint_order(robot, log)
    if contacts == "truth" and "gt_contact" not in log:
        raise ValueError("contacts='truth' needs 'gt_contact' in the log")
    if contacts == "sensor" and "contact" not in log and "foot_force" not in log:
        raise ValueError("contacts='sensor' needs 'contact' or 'foot_force' in the log")
    if contacts in ("observer", "mixed") and "tau" not in log:
        raise ValueError(f"contacts={contacts!r} needs joint torques ('tau') in the log")


def _contact_weight(log: Mapping, lead, contacts: str, shape: tuple[int, int, int]) -> np.ndarray:
    if contacts == "truth":
        return lead(log["gt_contact"]).astype(float)
    if contacts == "sensor":
        if "contact" in log:
            return lead(log["contact"]).astype(float)
        f = lead(log["foot_force"]).astype(float)
        lo, hi = np.nanpercentile(f, 5, axis=1), np.nanpercentile(f, 95, axis=1)
        return np.where(np.isfinite(f), (f > 0.5 * (lo + hi)[:, None]).astype(float), np.nan)
    return np.zeros(shape)


def robot_inputs(robot, log: Mapping, contacts: str = "truth") -> RobotInputs:
    """RobotInputs with a leading robot axis (a single log becomes a fleet of one).

    contacts: "truth" (gt_contact), "sensor" (the log's contact flags, else foot_force above the
    midpoint of its per-foot 5th and 95th percentiles), "observer" (plain) or "mixed" (need tau).
    The initial position and heading come from gt_pose when the log has it, else the origin.
    """
    check_log(robot, log, contacts)
    fleet = "fallen" in log
    lead = (lambda a: np.asarray(a)) if fleet else (lambda a: np.asarray(a)[None])
    t = np.asarray(log["t"], np.float64)
    order = _joint_order(robot, log)
    q = lead(log["q"])[..., order]
    n, T = q.shape[0], t.shape[0]
    nan = np.full(q.shape, np.nan)
    qd = lead(log["qd"])[..., order] if "qd" in log else nan
    tau = lead(log["tau"])[..., order] if "tau" in log else nan
    weight = _contact_weight(log, lead, contacts, (n, T, len(robot.foot_names)))
    quat = lead(log["quat_wxyz"]) if "quat_wxyz" in log else np.tile([1.0, 0, 0, 0], (n, T, 1))
    valid = np.asarray(log["valid"], bool) if fleet else np.ones((1, T), bool)
    if "gt_pose" in log:
        gt = lead(log["gt_pose"])[:, 0].astype(np.float64)
        p0, yaw0 = gt[:, :3], np.asarray(yaw_of(jnp.asarray(gt[:, 3:])))
    else:
        p0, yaw0 = np.zeros((n, 3)), np.zeros(n)
    f32 = lambda a: jnp.asarray(a, jnp.float32)  # noqa: E731
    return RobotInputs(
        dt=f32(np.broadcast_to(np.diff(t, prepend=t[0]), (n, T))),
        q=f32(q),
        qd=f32(qd),
        tau=f32(tau),
        gyro=f32(lead(log["gyro"])),
        acc=f32(lead(log["acc"])),
        quat_wxyz=f32(quat),
        contact_weight=f32(weight),
        valid=jnp.asarray(valid),
        p0_world_base=f32(p0),
        yaw0=f32(yaw0),
    )


def torque_ok(robot, tau: Float[Array, "*B nu"], saturation: Float[Array, ""]) -> Bool[Array, "*B"]:
    """Torques usable by the observer: finite and below `saturation` times the model's limits."""
    limit = jnp.asarray(np.where(np.isfinite(robot.torque_limit), robot.torque_limit, np.inf), tau.dtype)
    return jnp.all(jnp.isfinite(tau), axis=-1) & jnp.all(jnp.abs(tau) < saturation * limit, axis=-1)


def observer_rows(robot, rows: str) -> np.ndarray:
    """qvel indices of the momentum observer's generalized coordinates: "legs" = each leg's own
    joints (a joint shared by a leg pair, the Badger's spine, left out), "joints" = every actuated
    joint, "full" = every coordinate, floating base included. Legs and joints differ only on a
    spined robot: the spine row's momentum couples to the base velocity 4-5 times more than any
    leg row's (at home, 0.51 kg m against <= 0.11 on the Badger), so the leg-odometry velocity
    errors that the observer is fed read as spine torque, which the force least squares spreads
    over the rear feet; the legs' rows alone still determine every foot force."""
    if rows not in OBSERVER_ROWS:
        raise ValueError(f"observer rows must be one of {OBSERVER_ROWS}, got {rows!r}")
    if rows == "full":
        return np.arange(robot.nv)
    dofs = np.asarray(robot.dof_adr)
    return dofs[np.sort(np.asarray(robot.leg_joints).ravel())] if rows == "legs" else dofs


def gaps(dt: Float[Array, "*B"], max_gap_s: Float[Array, ""]) -> tuple[Bool[Array, "*B"], Bool[Array, "*B"]]:
    """(first, gap): the first sample (dt == 0) and steps not integrated (dt <= 0 or > max_gap_s)."""
    first = dt == 0
    return first, ~first & ~((dt > 0) & (dt <= max_gap_s))


def full_state(
    robot,
    p_world_base: Float[Array, "3"],
    q_world_base: Float[Array, "4"],
    q: Float[Array, "nu"],
    v_world_base: Float[Array, "3"],
    omega_base: Float[Array, "3"],
    qd: Float[Array, "nu"],
) -> tuple[Float[Array, "nq"], Float[Array, "nv"]]:
    """MJX (qpos, qvel) of the robot: free joint (world position, wxyz; world linear, body angular
    velocity) and the actuated joints in the model's order; other coordinates at home / zero."""
    a, d = robot.base_qpos_adr, robot.base_dof_adr
    qpos = jnp.asarray(robot.qpos_home, q.dtype)
    qpos = qpos.at[a : a + 3].set(p_world_base).at[a + 3 : a + 7].set(q_world_base)
    qpos = qpos.at[jnp.asarray(robot.qpos_adr)].set(q)
    qvel = jnp.zeros(robot.nv, q.dtype)
    qvel = qvel.at[d : d + 3].set(v_world_base).at[d + 3 : d + 6].set(omega_base)
    qvel = qvel.at[jnp.asarray(robot.dof_adr)].set(qd)
    return qpos, qvel
