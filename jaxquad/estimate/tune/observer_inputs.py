"""Observer inputs and contact ground truth of a fleet log, for tuning.

Contact quality depends on the observer alone, so the observer inputs (p, tau_bar, J_z per robot and
sample) are computed once per log and each configuration then runs only the observer's scan. They
come from the pipeline's own parsing of the log (`jaxquad.estimate.inputs.robot_inputs`) and the same
MJX state assembly (`inputs.full_state`), with one difference by design: the base linear velocity is
the backward difference of gt_pose's positions (world frame). The pipeline takes it from its own leg
odometry, which depends on the contacts being estimated, so tuning takes it from ground truth and
every configuration sees the same inputs (the half-sample lag of the backward difference is close to
the pipeline's use of the previous twist). On the joint rows (the default) the base velocity enters
only through the legs' inertial coupling; on the full rows the odometry's velocity errors dominate
the pipeline's forces, which tuning on the true velocity does not see. Base orientation is the log's
quat_wxyz (gt_pose's when absent); base angular velocity the gyro in the base frame. As in the
pipeline, the first sample and the samples after a gap restart p_hat at p, and a step with a
saturated or non-finite torque is skipped (state held).

Ground truth: gt_contact and the z component of gt_force; samples where the log's `valid` is False
(a fleet robot after its fall) are not scored.
"""

from __future__ import annotations

import functools

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Bool, Float

from jaxquad.estimate.inputs import R_base_imu, full_state, gaps, observer_rows, robot_inputs, torque_ok


class ObserverInputs(eqx.Module):
    """Observer inputs of one robot per sample (a fleet adds a leading robot axis N)."""

    p: Float[Array, "*N T n"]  # generalized momentum M v (n: the observer's rows, `inputs.observer_rows`)
    tau_bar: Float[Array, "*N T n"]  # S^T tau + C^T v - g (+ passive joint forces)
    J_z: Float[Array, "*N T R n"]  # world rows of the foot Jacobians (m per unit of qvel), `axes` per foot
    dt: Float[Array, "*N T"]  # s; NaN where the step is skipped (first sample, gap, bad torque)
    restart: Bool[Array, "*N T"]  # p_hat restarts at p (first sample, after a gap)
    axes: str = eqx.field(static=True, default="z")  # "z" (R = F) or "xyz" (R = 3 F, row 3 f + a)

    @property
    def n_feet(self) -> int:
        return self.J_z.shape[-2] // (3 if self.axes == "xyz" else 1)


class ContactTruth(eqx.Module):
    """Ground truth of one robot per sample (a fleet adds a leading robot axis N)."""

    contact: Bool[Array, "*N T F"]
    force_z: Float[Array, "*N T F"]  # N, world z on each foot
    valid: Bool[Array, "*N T"]  # scored samples


@functools.lru_cache(maxsize=4)
def _momentum_fn(robot, axes: str, passive: bool):
    from jaxquad import dynamics

    def one(p_world_base, q_world_base, q, v_world_base, omega_base, qd, tau):
        qpos, qvel = full_state(robot, p_world_base, q_world_base, q, v_world_base, omega_base, qd)
        return dynamics.momentum_terms(robot, qpos, qvel, tau, axes=axes, passive=passive)

    return jax.jit(jax.vmap(one))


def observer_inputs(
    robot,
    log,
    max_gap_s: float = 0.05,
    torque_saturation: float = 0.99,
    chunk: int = 4096,
    axes: str = "xyz",
    passive: bool = True,
    rows: str = "legs",
) -> tuple[ObserverInputs, ContactTruth, np.ndarray]:
    """Observer inputs and ground truth of every robot of a log (leading axis N; a single log is a
    fleet of one), and the sample times t (T,) in s. Samples go through MJX in chunks of `chunk`.
    axes: force rows per foot, "xyz" (full foot forces, the default) or "z"; passive: tau_bar with
    the model's joint damping and friction; rows: the observer's generalized coordinates, "legs"
    (the legs' own joints), "joints" (every actuated joint, a spine's too) or "full" (floating base
    included; `inputs.observer_rows`). All three as the pipeline's
    PipelineConfig.observer_axes / observer_passive / observer_rows, whose defaults they share."""
    if axes not in ("z", "xyz"):
        raise ValueError(f"axes must be 'z' or 'xyz', got {axes!r}")
    row_index = observer_rows(robot, rows)
    need = [k for k in ("tau", "qd", "gt_pose", "gt_contact", "gt_force") if k not in log]
    if need:
        raise ValueError(f"tuning needs {need} in the log (joint torques, joint velocities and ground truth)")
    inputs = robot_inputs(robot, log, "truth")
    fleet = "fallen" in log
    lead = (lambda a: np.asarray(a)) if fleet else (lambda a: np.asarray(a)[None])  # noqa: E731
    t = np.asarray(log["t"], np.float64)
    n, T = inputs.q.shape[:2]
    if T < 2:
        raise ValueError(f"tuning needs at least 2 samples, the log has {T}")
    gt_pose = lead(log["gt_pose"]).astype(np.float64)
    quat = np.asarray(inputs.quat_wxyz, np.float64) if "quat_wxyz" in log else gt_pose[..., 3:]
    quat = quat / np.linalg.norm(quat, axis=-1, keepdims=True)
    gyro = np.asarray(inputs.gyro, np.float64) @ R_base_imu(robot).T
    dt = np.diff(t, prepend=t[0])
    v_world = np.diff(gt_pose[..., :3], axis=1) / dt[1:, None]
    v_world = np.concatenate([v_world[:, :1], v_world], axis=1)  # sample 0 restarts the observer anyway
    tau_ok = np.asarray(torque_ok(robot, inputs.tau, jnp.float32(torque_saturation)))
    tau = np.where(tau_ok[..., None], np.asarray(inputs.tau), 0.0)

    f32 = lambda a: np.ascontiguousarray(a, np.float32).reshape(n * T, -1)  # noqa: E731
    flat = [f32(a) for a in (gt_pose[..., :3], quat, inputs.q, v_world, gyro, inputs.qd, tau)]
    fn, total = _momentum_fn(robot, axes, passive), n * T
    chunk = max(1, min(chunk, total))
    parts = []
    for start in range(0, total, chunk):
        piece = [a[start : start + chunk] for a in flat]
        pad = chunk - piece[0].shape[0]
        piece = [np.pad(a, ((0, pad), (0, 0)), mode="edge") for a in piece]  # one compiled size
        parts.append(jax.tree.map(lambda a, n=chunk - pad: np.asarray(a)[:n], fn(*piece)))
    p, tau_bar, J_z = (np.concatenate(x).reshape(n, T, *x[0].shape[1:]) for x in zip(*parts))
    p, tau_bar, J_z = p[..., row_index], tau_bar[..., row_index], J_z[..., row_index]

    first, gap = (np.asarray(x) for x in gaps(jnp.asarray(dt), jnp.float32(max_gap_s)))
    step_dt = np.where(tau_ok & ~(first | gap)[None], dt[None], np.nan)
    obs_inputs = ObserverInputs(
        p=jnp.asarray(p),
        tau_bar=jnp.asarray(tau_bar),
        J_z=jnp.asarray(J_z),
        dt=jnp.asarray(step_dt, jnp.float32),
        restart=jnp.asarray(np.broadcast_to(first | gap, (n, T))),
        axes=axes,
    )
    truth = ContactTruth(
        contact=jnp.asarray(lead(log["gt_contact"]).astype(bool)),
        force_z=jnp.asarray(lead(log["gt_force"])[..., 2], jnp.float32),
        valid=inputs.valid,
    )
    return obs_inputs, truth, t


def select_robots(tree, index):
    """Robots `index` (array of indices) of a fleet pytree (ObserverInputs or ContactTruth)."""
    index = jnp.asarray(index)
    return jax.tree.map(lambda a: a[index], tree)
