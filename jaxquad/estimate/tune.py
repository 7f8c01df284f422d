"""Tuning of the contact observer's numbers over a fleet log: grid search and gradient descent.

Structure. Contact quality depends on the observer alone, so the observer inputs (p, tau_bar, J_z
per robot and sample; as in the pipeline's default, tau_bar includes the model's joint damping and
friction, J_z holds the x, y and z Jacobian rows of each foot, of which only the z forces are
post-processed and scored, and only the actuated joints' coordinates are kept) are computed once per log (`observer_inputs`: MJX `momentum_terms` under
jit/vmap) and each configuration then runs only the observer's `lax.scan`: configurations on one
vmap axis, robots on another, configurations in fixed-size chunks to bound memory.

Observer inputs from a log follow the pipeline (jaxquad.estimate.pipeline, step 3): joints q and qd
from the log, base orientation from quat_wxyz (gt_pose's when absent), base angular velocity = the
gyro in the base frame. The base linear velocity is the backward difference of gt_pose's positions
(world frame): the pipeline takes it from its own leg odometry, which depends on the contacts being
estimated, so tuning takes it from ground truth and every configuration sees the same inputs (the
half-sample lag of the backward difference is close to the pipeline's use of the previous twist).
On the joint rows (the default) the base velocity enters only through the legs' inertial coupling;
on the full rows the odometry's velocity errors dominate the pipeline's forces, which tuning on the
true velocity does not see.
As in the pipeline, the first sample and the samples after a gap (dt > max_gap_s) restart p_hat at
p, and a step with a saturated or non-finite torque is skipped (state held).

Ground truth: gt_contact and the z component of gt_force; samples where the log's `valid` is False
(a fleet robot after its fall) are not scored.

Scores (`fleet_scores`) are pooled over robots, feet and valid samples: contact precision, recall
and F1 from the summed counts; touchdown and lift-off delays (ms, scores.detection_delays per robot)
averaged over all matched events; force RMSE (N) of the filtered force against gt_force z.

Grid objective: pooled F1, counted inside the scan. Among the `top_k` configurations of highest F1
that lie within `f1_tolerance` of the best, the one with the smallest delay cost wins (exact
delays from a full re-run): mean |touchdown delay| + mean |lift-off delay| in ms, every missed edge
counting as max_delay_s; remaining ties go to the lower index.

Gradient objective (a differentiable surrogate through the scanned observer):
    loss = mean BCE(contact_soft, gt_contact) + force_weight mean((f_filt - clip(f_true, 0, f_max))^2) / force_scale^2
over valid samples and feet of the training robots, with contact_soft = sigmoid((f_filt - threshold)
/ temperature). Parameters are unconstrained (`Unconstrained`): bandwidth = exp(u), alpha =
sigmoid(u) per foot, threshold_on = softplus(u) per foot, threshold_off = threshold_on sigmoid(u)
per foot (so 0 < off <= on). Adam (optax); stops after `steps` or when the loss has not improved by
a relative `tolerance` for `patience` steps; returns the parameters of the lowest loss.
"""

from __future__ import annotations

import dataclasses
import functools
import json
import math
import os
import time
from pathlib import Path
from typing import Callable, Literal

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Bool, Float, Int

from jaxquad.estimate import scores
from jaxquad.estimate.pipeline import observer_params_for_axes, vertical_estimate
from jaxquad.kernels import ContactEstimate, ContactObserver, ObserverParams

# Keys of a params file, as jaxquad.estimate.run.load_params reads them.
PARAM_KEYS = ("mode", "bandwidth", "alpha", "threshold_on", "threshold_off", "f_max", "sharpness")


class ObserverInputs(eqx.Module):
    """Observer inputs of one robot per sample (a fleet adds a leading robot axis N)."""

    p: Float[Array, "T n"]  # generalized momentum M v (n = nv, or nu for the joint rows)
    tau_bar: Float[Array, "T n"]  # S^T tau + C^T v - g (+ passive joint forces)
    J_z: Float[Array, "T R n"]  # world rows of the foot Jacobians (m per unit of qvel), `axes` per foot
    dt: Float[Array, "T"]  # s; NaN where the step is skipped (first sample, gap, bad torque)
    restart: Bool[Array, "T"]  # p_hat restarts at p (first sample, after a gap)
    axes: str = eqx.field(static=True, default="z")  # "z" (R = F) or "xyz" (R = 3 F, row 3 f + a)

    @property
    def n_feet(self) -> int:
        return self.J_z.shape[-2] // (3 if self.axes == "xyz" else 1)


class ContactTruth(eqx.Module):
    """Ground truth of one robot per sample (a fleet adds a leading robot axis N)."""

    contact: Bool[Array, "T F"]
    force_z: Float[Array, "T F"]  # N, world z on each foot
    valid: Bool[Array, "T"]  # scored samples


class Counts(eqx.Module):
    """Per-foot sums over valid samples: contact confusion counts and squared force error (N^2)."""

    tp: Int[Array, "F"]
    fp: Int[Array, "F"]
    fn: Int[Array, "F"]
    force_sq: Float[Array, "F"]
    samples: Int[Array, ""]


# ---------------------------------------------------------------- observer inputs from a log


def _R_base_imu(robot) -> np.ndarray:
    """Rotation of the IMU site in the base frame at the home configuration (MuJoCo C)."""
    import mujoco

    m = robot.mj_model
    d = mujoco.MjData(m)
    d.qpos[:] = robot.qpos_home
    mujoco.mj_kinematics(m, d)
    return d.xmat[robot.base_body_id].reshape(3, 3).T @ d.site_xmat[robot.imu_site_id].reshape(3, 3)


@functools.lru_cache(maxsize=4)
def _momentum_fn(robot, axes: str, passive: bool):
    from jaxquad import dynamics

    return jax.jit(jax.vmap(functools.partial(dynamics.momentum_terms, robot, axes=axes, passive=passive)))


def observer_inputs(
    robot, log: dict, max_gap_s: float = 0.05, torque_saturation: float = 0.99, chunk: int = 4096,
    axes: str = "xyz", passive: bool = True, rows: str = "joints",
) -> tuple[ObserverInputs, ContactTruth, np.ndarray]:
    """Observer inputs and ground truth of every robot of a log (leading axis N; a single log is a
    fleet of one), and the sample times t (T,) in s. Samples go through MJX in chunks of `chunk`.
    axes: force rows per foot, "xyz" (full foot forces, the default) or "z"; passive: tau_bar with
    the model's joint damping and friction; rows: the observer's generalized coordinates, "joints"
    (the actuated joints) or "full" (floating base included). All three as the pipeline's
    PipelineConfig.observer_axes / observer_passive / observer_rows, whose defaults they share."""
    if axes not in ("z", "xyz"):
        raise ValueError(f"axes must be 'z' or 'xyz', got {axes!r}")
    if rows not in ("joints", "full"):
        raise ValueError(f"rows must be 'joints' or 'full', got {rows!r}")
    need = [k for k in ("tau", "qd", "gt_pose", "gt_contact", "gt_force") if k not in log]
    if need:
        raise ValueError(f"tuning needs {need} in the log (joint torques, joint velocities and ground truth)")
    fleet = "fallen" in log
    lead = (lambda a: np.asarray(a)) if fleet else (lambda a: np.asarray(a)[None])
    names = [str(n) for n in np.asarray(log["joint_names"])]
    missing = [j for j in robot.joint_names if j not in names]
    if missing:
        raise ValueError(f"log has no joint(s) {missing} of robot {robot.name!r}")
    order = np.array([names.index(j) for j in robot.joint_names])
    t = np.asarray(log["t"], np.float64)
    q, qd, tau = (lead(log[k])[..., order].astype(np.float64) for k in ("q", "qd", "tau"))
    gt_pose = lead(log["gt_pose"]).astype(np.float64)
    n, T = q.shape[:2]
    if T < 2:
        raise ValueError(f"tuning needs at least 2 samples, the log has {T}")
    quat = lead(log["quat_wxyz"]).astype(np.float64) if "quat_wxyz" in log else gt_pose[..., 3:]
    quat = quat / np.linalg.norm(quat, axis=-1, keepdims=True)
    gyro = lead(log["gyro"]).astype(np.float64) @ _R_base_imu(robot).T

    dt = np.diff(t, prepend=t[0])
    v_world = np.diff(gt_pose[..., :3], axis=1) / dt[1:, None]
    v_world = np.concatenate([v_world[:, :1], v_world], axis=1)  # sample 0 restarts the observer anyway
    qpos = np.broadcast_to(np.asarray(robot.qpos_home, np.float64), (n, T, robot.nq)).copy()
    qpos[..., robot.base_qpos_adr : robot.base_qpos_adr + 3] = gt_pose[..., :3]
    qpos[..., robot.base_qpos_adr + 3 : robot.base_qpos_adr + 7] = quat
    qpos[..., np.asarray(robot.qpos_adr)] = q
    qvel = np.zeros((n, T, robot.nv))
    qvel[..., robot.base_dof_adr : robot.base_dof_adr + 3] = v_world
    qvel[..., robot.base_dof_adr + 3 : robot.base_dof_adr + 6] = gyro
    qvel[..., np.asarray(robot.dof_adr)] = qd
    limit = np.where(np.isfinite(robot.torque_limit), robot.torque_limit, np.inf)
    tau_ok = np.all(np.isfinite(tau) & (np.abs(tau) < torque_saturation * limit), axis=-1)
    tau = np.where(tau_ok[..., None], tau, 0.0)

    flat = [a.reshape(n * T, -1).astype(np.float32) for a in (qpos, qvel, tau)]
    fn, total = _momentum_fn(robot, axes, passive), n * T
    chunk = max(1, min(chunk, total))
    parts = []
    for start in range(0, total, chunk):
        piece = [a[start : start + chunk] for a in flat]
        pad = chunk - piece[0].shape[0]
        piece = [np.pad(a, ((0, pad), (0, 0)), mode="edge") for a in piece]  # one compiled size
        parts.append(jax.tree.map(lambda a: np.asarray(a)[: chunk - pad], fn(*piece)))
    p, tau_bar, J_z = (np.concatenate(x).reshape(n, T, *x[0].shape[1:]) for x in zip(*parts))
    if rows == "joints":
        dofs = np.asarray(robot.dof_adr)
        p, tau_bar, J_z = p[..., dofs], tau_bar[..., dofs], J_z[..., dofs]

    first = np.arange(T) == 0
    gap = ~first & ~((dt > 0) & (dt <= max_gap_s))
    step_dt = np.where(tau_ok & ~(first | gap)[None], dt[None], np.nan)
    inputs = ObserverInputs(
        p=jnp.asarray(p), tau_bar=jnp.asarray(tau_bar), J_z=jnp.asarray(J_z),
        dt=jnp.asarray(step_dt, jnp.float32), restart=jnp.asarray(np.broadcast_to(first | gap, (n, T))), axes=axes,
    )  # fmt: skip
    valid = np.asarray(log["valid"], bool) if fleet else np.ones((1, T), bool)
    truth = ContactTruth(
        contact=jnp.asarray(lead(log["gt_contact"]).astype(bool)),
        force_z=jnp.asarray(lead(log["gt_force"])[..., 2], jnp.float32),
        valid=jnp.asarray(valid),
    )
    return inputs, truth, t


def select_robots(tree, index):
    """Robots `index` (array of indices) of a fleet pytree (ObserverInputs or ContactTruth)."""
    index = jnp.asarray(index)
    return jax.tree.map(lambda a: a[index], tree)


# ---------------------------------------------------------------- the observer over one robot


def _observer_scan(params: ObserverParams, inputs: ObserverInputs, carry0, reduce, truth: ContactTruth | None):
    """lax.scan of the observer; reduce(carry, estimate, truth_k) -> (carry, output)."""
    observer = ContactObserver()
    row_params = observer_params_for_axes(params, inputs.axes)
    state0 = observer.init(row_params, inputs.p[0], inputs.J_z.shape[-2])

    def step(c, x):
        state, acc = c
        (p, tau_bar, J_z, dt, restart), truth_k = x
        state = eqx.tree_at(lambda s: s.p_hat, state, jnp.where(restart, p, state.p_hat))
        state, est = observer.step(row_params, state, p, tau_bar, J_z, dt)
        acc, out = reduce(acc, vertical_estimate(est, inputs.axes), truth_k)
        return (state, acc), out

    xs = ((inputs.p, inputs.tau_bar, inputs.J_z, inputs.dt, inputs.restart), truth)
    (_, acc), out = jax.lax.scan(step, (state0, carry0), xs)
    return acc, out


def run_observer(params: ObserverParams, inputs: ObserverInputs) -> ContactEstimate:
    """The observer over one robot's inputs; per-sample estimates with a leading axis T."""
    return _observer_scan(params, inputs, None, lambda acc, est, _: (acc, est), None)[1]


def observer_counts(params: ObserverParams, inputs: ObserverInputs, truth: ContactTruth) -> Counts:
    """Contact confusion counts and squared force error of one robot, accumulated inside the scan."""
    n_feet = inputs.n_feet
    zeros = jnp.zeros(n_feet, jnp.int32)
    acc0 = Counts(tp=zeros, fp=zeros, fn=zeros, force_sq=jnp.zeros(n_feet, jnp.float32), samples=jnp.zeros((), jnp.int32))

    def reduce(acc: Counts, est: ContactEstimate, truth_k):
        contact, force_z, valid = truth_k
        hit, true = est.contact & valid, contact & valid
        err = jnp.where(valid, est.force_z_filtered - force_z, 0.0)
        return Counts(
            tp=acc.tp + (hit & true), fp=acc.fp + (hit & ~true), fn=acc.fn + (~hit & true),
            force_sq=acc.force_sq + err * err, samples=acc.samples + valid,
        ), None  # fmt: skip

    return _observer_scan(params, inputs, acc0, reduce, (truth.contact, truth.force_z, truth.valid))[0]


def f1_of(counts: Counts) -> Float[Array, "..."]:
    """Pooled F1 over feet of (possibly batched) counts; 0 where nothing was detected or true."""
    tp, fp, fn = (jnp.sum(x, axis=-1).astype(jnp.float32) for x in (counts.tp, counts.fp, counts.fn))
    return jnp.where(tp > 0, 2 * tp / jnp.maximum(2 * tp + fp + fn, 1.0), 0.0)


@jax.jit
def _fleet_estimates(params: ObserverParams, inputs: ObserverInputs) -> ContactEstimate:
    return jax.vmap(run_observer, in_axes=(None, 0))(params, inputs)


def fleet_scores(
    params: ObserverParams, inputs: ObserverInputs, truth: ContactTruth, t, max_delay_s: float = 0.1
) -> dict:
    """Exact scores of one configuration over a fleet (pooled; see the module docstring)."""
    est = jax.tree.map(np.asarray, _fleet_estimates(params, inputs))
    contact, force_true, valid = (np.asarray(x) for x in (truth.contact, truth.force_z, truth.valid))
    n, T, F = contact.shape
    c = scores.contact_scores(est.contact.reshape(n * T, F), contact.reshape(n * T, F), valid.reshape(n * T))
    out = {"f1": c["f1"], "precision": c["precision"], "recall": c["recall"]}
    for kind in ("touchdown", "liftoff"):
        rows = [scores.detection_delays(t, est.contact[i], contact[i], valid[i], max_delay_s)[kind] for i in range(n)]
        matched = sum(r["matched"] for r in rows)
        out[f"{kind}_mean_ms"] = sum(r["mean_ms"] * r["matched"] for r in rows) / matched if matched else 0.0
        out[f"{kind}_mean_abs_ms"] = sum(r["mean_abs_ms"] * r["matched"] for r in rows) / matched if matched else 0.0
        out[f"{kind}_matched"] = matched
        out[f"{kind}_missed"] = sum(r["missed"] for r in rows)
    out["force_rmse_n"] = scores.force_rmse(
        est.force_z_filtered.reshape(n * T, F), force_true.reshape(n * T, F), valid.reshape(n * T)
    )["rmse_n"]
    return out


def delay_cost(s: dict, max_delay_s: float = 0.1) -> float:
    """Mean |touchdown delay| + mean |lift-off delay| (ms), a missed edge counting as max_delay_s."""
    cost = 0.0
    for kind in ("touchdown", "liftoff"):
        matched, missed = s[f"{kind}_matched"], s[f"{kind}_missed"]
        events = matched + missed
        cost += (s[f"{kind}_mean_abs_ms"] * matched + 1e3 * max_delay_s * missed) / events if events else 0.0
    return cost


# ---------------------------------------------------------------- grid search


@dataclasses.dataclass(frozen=True)
class GridSpec:
    """Values of each grid axis; the grid is their Cartesian product (bandwidth slowest). Thresholds
    (N) are shared by all feet; threshold_off = threshold_on * off_ratio; alpha per front/rear pair."""

    bandwidth: tuple[float, ...]
    alpha_front: tuple[float, ...]
    alpha_rear: tuple[float, ...]
    threshold_on: tuple[float, ...]
    off_ratio: tuple[float, ...]

    @classmethod
    def default(cls, size: int | tuple[int, int, int, int, int] = 4) -> GridSpec:
        """`size` points per axis (or five sizes): bandwidth 10-150 rad/s and alpha 0.05-1 and
        threshold_on 1-40 N log-spaced, off_ratio 0.3-1 evenly spaced."""
        sizes = (size,) * 5 if isinstance(size, int) else tuple(size)
        if len(sizes) != 5 or min(sizes) < 1:
            raise ValueError(f"grid size must be one positive integer or five, got {size}")
        geo = lambda lo, hi, k: tuple(float(x) for x in (np.geomspace(lo, hi, k) if k > 1 else [math.sqrt(lo * hi)]))  # noqa: E731
        lin = tuple(float(x) for x in (np.linspace(0.3, 1.0, sizes[4]) if sizes[4] > 1 else [1.0]))
        return cls(geo(10.0, 150.0, sizes[0]), geo(0.05, 1.0, sizes[1]), geo(0.05, 1.0, sizes[2]),
                   geo(1.0, 40.0, sizes[3]), lin)  # fmt: skip

    def __post_init__(self):
        for name in ("bandwidth", "alpha_front", "alpha_rear", "threshold_on", "off_ratio"):
            v = np.asarray(getattr(self, name), float)
            if v.ndim != 1 or v.size == 0 or not np.all(np.isfinite(v)) or np.any(v <= 0):
                raise ValueError(f"grid axis {name} needs positive finite values, got {getattr(self, name)}")
        if max(self.alpha_front + self.alpha_rear) > 1 or max(self.off_ratio) > 1:
            raise ValueError("grid alpha and off_ratio values must lie in (0, 1]")

    @property
    def size(self) -> int:
        return math.prod(len(getattr(self, f.name)) for f in dataclasses.fields(self))

    def params(self, base: ObserverParams) -> ObserverParams:
        """Every configuration as one ObserverParams with a leading axis C (other numbers from base)."""
        b, af, ar, on, ratio = (a.ravel() for a in np.meshgrid(
            self.bandwidth, self.alpha_front, self.alpha_rear, self.threshold_on, self.off_ratio, indexing="ij"))  # fmt: skip
        n_feet = base.alpha.shape[0]
        half = n_feet // 2
        alpha = np.concatenate([np.repeat(af[:, None], half, 1), np.repeat(ar[:, None], n_feet - half, 1)], 1)
        c = b.size
        tile = lambda x: jnp.broadcast_to(x, (c,) + x.shape)  # noqa: E731
        batched = jax.tree.map(tile, base)
        return dataclasses.replace(
            batched, bandwidth=jnp.asarray(b, jnp.float32), alpha=jnp.asarray(alpha, jnp.float32),
            threshold_on=jnp.asarray(np.repeat(on[:, None], n_feet, 1), jnp.float32),
            threshold_off=jnp.asarray(np.repeat((on * ratio)[:, None], n_feet, 1), jnp.float32),
        )  # fmt: skip


@jax.jit
def _grid_counts(params: ObserverParams, inputs: ObserverInputs, truth: ContactTruth) -> Counts:
    """Counts summed over robots for a batch of configurations (leading axis C)."""
    per_robot = jax.vmap(observer_counts, in_axes=(None, 0, 0))
    counts = jax.vmap(per_robot, in_axes=(0, None, None))(params, inputs, truth)
    return jax.tree.map(lambda a: a.sum(axis=1), counts)


def grid_counts(
    params: ObserverParams, inputs: ObserverInputs, truth: ContactTruth, chunk: int = 256,
    progress: Callable[[int, int], None] | None = None,
) -> Counts:
    """`observer_counts` of C configurations (leading axis C) summed over the fleet, `chunk`
    configurations per vmapped call (the last chunk padded, so one compilation serves all)."""
    c = params.bandwidth.shape[0]
    chunk = max(1, min(chunk, c))
    parts = []
    for start in range(0, c, chunk):
        index = np.minimum(np.arange(start, start + chunk), c - 1)
        out = _grid_counts(jax.tree.map(lambda a: a[index], params), inputs, truth)
        parts.append(jax.tree.map(lambda a: np.asarray(a)[: min(chunk, c - start)], out))
        if progress is not None:
            progress(min(start + chunk, c), c)
    return jax.tree.map(lambda *a: np.concatenate(a), *parts)


def pick_best(f1: np.ndarray, exact: Callable[[int], dict], f1_tolerance: float = 0.005, top_k: int = 8,
              max_delay_s: float = 0.1) -> tuple[int, dict]:
    """Index of the winning configuration by the grid rule of the module docstring, and its scores;
    `exact(i)` returns fleet_scores of configuration i."""
    order = np.argsort(-np.asarray(f1), kind="stable")
    best = float(f1[order[0]])
    candidates = [int(i) for i in order[:top_k] if f1[i] >= best - f1_tolerance]
    scored = [(delay_cost(s := exact(i), max_delay_s), i, s) for i in candidates]
    cost, i, s = min(scored, key=lambda x: (x[0], x[1]))
    return i, s


@dataclasses.dataclass(frozen=True)
class GridResult:
    best: ObserverParams
    index: int
    f1: np.ndarray  # (C,) pooled F1 of every configuration
    force_rmse_n: np.ndarray  # (C,)
    scores: dict  # exact scores of the winner on the tuning robots
    wall_s: float


def grid_search(
    spec: GridSpec, base: ObserverParams, inputs: ObserverInputs, truth: ContactTruth, t,
    chunk: int = 256, f1_tolerance: float = 0.005, top_k: int = 8, max_delay_s: float = 0.1,
    progress: Callable[[int, int], None] | None = None,
) -> GridResult:
    """Best configuration of the grid on the given robots (see the module docstring for the rule)."""
    start = time.perf_counter()
    params = spec.params(base)
    counts = grid_counts(params, inputs, truth, chunk, progress)
    f1 = np.asarray(f1_of(counts))
    rmse = np.sqrt(counts.force_sq.sum(-1) / np.maximum(counts.samples * counts.force_sq.shape[-1], 1))
    take = lambda i: jax.tree.map(lambda a: a[i], params)  # noqa: E731
    i, s = pick_best(f1, lambda i: fleet_scores(take(i), inputs, truth, t, max_delay_s), f1_tolerance, top_k, max_delay_s)
    return GridResult(best=take(i), index=i, f1=f1, force_rmse_n=rmse, scores=s, wall_s=time.perf_counter() - start)


# ---------------------------------------------------------------- gradient tuning


def _softplus_inv(x):
    return x + jnp.log(-jnp.expm1(-x))


class Unconstrained(eqx.Module):
    """Unconstrained coordinates of the tuned observer numbers (see the module docstring)."""

    log_bandwidth: Float[Array, ""]
    logit_alpha: Float[Array, "F"]
    raw_threshold_on: Float[Array, "F"]
    logit_off_ratio: Float[Array, "F"]

    @classmethod
    def from_params(cls, params: ObserverParams, eps: float = 1e-4) -> Unconstrained:
        ratio = params.threshold_off / params.threshold_on
        return cls(
            log_bandwidth=jnp.log(params.bandwidth),
            logit_alpha=jax.scipy.special.logit(jnp.clip(params.alpha, eps, 1 - eps)),
            raw_threshold_on=_softplus_inv(jnp.maximum(params.threshold_on, eps)),
            logit_off_ratio=jax.scipy.special.logit(jnp.clip(ratio, eps, 1 - eps)),
        )

    def params(self, base: ObserverParams) -> ObserverParams:
        on = jax.nn.softplus(self.raw_threshold_on)
        return dataclasses.replace(
            base, bandwidth=jnp.exp(self.log_bandwidth), alpha=jax.nn.sigmoid(self.logit_alpha),
            threshold_on=on, threshold_off=on * jax.nn.sigmoid(self.logit_off_ratio),
        )  # fmt: skip


class LossTerms(eqx.Module):
    bce_sum: Float[Array, ""]
    force_sq_sum: Float[Array, ""]  # N^2
    count: Float[Array, ""]  # valid sample-feet


def _loss_terms(params: ObserverParams, inputs: ObserverInputs, truth: ContactTruth) -> LossTerms:
    zero = jnp.zeros((), jnp.float32)

    def reduce(acc: LossTerms, est: ContactEstimate, truth_k):
        contact, force_z, valid = truth_k
        soft = jnp.clip(est.contact_soft, 1e-6, 1 - 1e-6)
        bce = -jnp.where(contact, jnp.log(soft), jnp.log1p(-soft))
        err = est.force_z_filtered - jnp.clip(force_z, 0.0, params.f_max)
        w = valid.astype(jnp.float32)
        return LossTerms(acc.bce_sum + w * bce.sum(), acc.force_sq_sum + w * (err * err).sum(),
                         acc.count + w * contact.shape[-1]), None  # fmt: skip

    # Rematerialise each step's internals in the backward pass: memory grows with the carry only.
    reduce = jax.checkpoint(reduce)
    return _observer_scan(params, inputs, LossTerms(zero, zero, zero), reduce, (truth.contact, truth.force_z, truth.valid))[0]


def surrogate_loss(
    u: Unconstrained, base: ObserverParams, inputs: ObserverInputs, truth: ContactTruth,
    force_weight: float = 0.1, force_scale: float = 50.0, temperature: float = 2.0,
) -> Float[Array, ""]:
    """The gradient objective over a fleet (inputs with a leading robot axis)."""
    params = dataclasses.replace(u.params(base), soft_temperature=jnp.asarray(temperature, jnp.float32))
    terms = jax.vmap(_loss_terms, in_axes=(None, 0, 0))(params, inputs, truth)
    count = jnp.maximum(terms.count.sum(), 1.0)
    return terms.bce_sum.sum() / count + force_weight * terms.force_sq_sum.sum() / count / force_scale**2


@dataclasses.dataclass(frozen=True)
class GradientResult:
    best: ObserverParams
    loss: np.ndarray  # per step, at the parameters before that step's update
    best_step: int
    stopped: str  # "plateau" or "max_steps"
    wall_s: float


def gradient_tune(
    start: ObserverParams, inputs: ObserverInputs, truth: ContactTruth, steps: int = 200,
    learning_rate: float = 0.05, patience: int = 25, tolerance: float = 1e-4, force_weight: float = 0.1,
    force_scale: float = 50.0, temperature: float = 2.0, progress: Callable[[int, float], None] | None = None,
) -> GradientResult:
    """Adam on the surrogate loss from `start` (see the module docstring); the returned parameters
    are those of the lowest loss seen."""
    import optax

    if steps < 1:
        raise ValueError(f"steps must be >= 1, got {steps}")
    t0 = time.perf_counter()
    opt = optax.adam(learning_rate)
    u = Unconstrained.from_params(start)
    loss_fn = functools.partial(surrogate_loss, force_weight=force_weight, force_scale=force_scale,
                                temperature=temperature)  # fmt: skip

    @jax.jit
    def update(u, opt_state, inputs, truth):
        loss, grad = jax.value_and_grad(loss_fn)(u, start, inputs, truth)
        grad = jax.tree.map(lambda g: jnp.where(jnp.isfinite(g), g, 0.0), grad)
        upd, opt_state = opt.update(grad, opt_state, u)
        return optax.apply_updates(u, upd), opt_state, loss

    opt_state = opt.init(u)
    history, best_u, best_loss, best_step, stopped = [], u, np.inf, 0, "max_steps"
    for k in range(steps):
        new_u, opt_state, loss = update(u, opt_state, inputs, truth)
        loss = float(loss)
        if not np.isfinite(loss):
            raise ValueError(f"gradient tuning: the loss became {loss} at step {k}")
        history.append(loss)
        if loss < best_loss * (1 - tolerance):
            best_u, best_loss, best_step = u, loss, k
        if progress is not None:
            progress(k + 1, loss)
        if k - best_step >= patience:
            stopped = "plateau"
            break
        u = new_u
    best = best_u.params(start)
    return GradientResult(best=best, loss=np.asarray(history), best_step=best_step, stopped=stopped,
                          wall_s=time.perf_counter() - t0)  # fmt: skip


# ---------------------------------------------------------------- params files


def params_dict(params: ObserverParams) -> dict:
    """The keys `load_params` reads (floats; per-foot lists)."""
    scalar = lambda x: float(np.asarray(x))  # noqa: E731
    vector = lambda x: [float(v) for v in np.asarray(x)]  # noqa: E731
    return {
        "mode": params.mode, "bandwidth": scalar(params.bandwidth), "alpha": vector(params.alpha),
        "threshold_on": vector(params.threshold_on), "threshold_off": vector(params.threshold_off),
        "f_max": scalar(params.f_max), "sharpness": scalar(params.sharpness),
    }  # fmt: skip


def save_params(path: str | os.PathLike, params: ObserverParams, header: str = "") -> Path:
    """Write params for `jaxquad estimate --params`: JSON for .json, else YAML (with `header` as
    comment lines). Written atomically."""
    import yaml

    path = Path(path)
    data = params_dict(params)
    if path.suffix.lower() == ".json":
        text = json.dumps(data, indent=2) + "\n"
    elif path.suffix.lower() in (".yaml", ".yml"):
        comments = "".join(f"# {line}\n" for line in header.splitlines())
        text = comments + yaml.safe_dump(data, sort_keys=False)
    else:
        raise ValueError(f"params file must end in .json, .yaml or .yml, got {path.name}")
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f".{path.name}.tmp")
    tmp.write_text(text)
    os.replace(tmp, path)
    return path


def observer_params_from_file(path, n_feet: int = 4) -> ObserverParams:
    """The ObserverParams `jaxquad estimate --params path` will use."""
    from jaxquad.estimate.run import load_params

    return load_params(path, n_feet, "mixed").observer


# ---------------------------------------------------------------- the whole tuning run


def split_robots(n: int, holdout: float) -> tuple[np.ndarray, np.ndarray]:
    """Training and held-out robot indices: the last round(n * holdout) robots (>= 1 when holdout
    > 0) are held out; at least one robot trains."""
    if not 0 <= holdout < 1:
        raise ValueError(f"holdout must lie in [0, 1), got {holdout}")
    k = 0 if holdout == 0 else max(1, round(n * holdout))
    if n - k < 1:
        raise ValueError(f"a held-out fraction of {holdout} leaves no training robot among {n}")
    return np.arange(n - k), np.arange(n - k, n)


def tune_fleet(
    method: Literal["grid", "gradient"], inputs: ObserverInputs, truth: ContactTruth, t,
    mode: Literal["plain", "mixed"] = "mixed", holdout: float = 0.25, spec: GridSpec | None = None,
    chunk: int = 256, steps: int = 200, start: ObserverParams | None = None, progress=None, **options,
) -> tuple[ObserverParams, dict]:
    """Tune on the training robots; return the best params and a JSON-ready summary with scores of
    the paper's defaults and of the result on the training and held-out robots, and wall times."""
    n = inputs.p.shape[0]
    train, held = split_robots(n, holdout)
    tr_in, tr_truth = select_robots(inputs, train), select_robots(truth, train)
    paper = ObserverParams.paper(inputs.n_feet, mode)
    summary: dict = {"method": method, "mode": mode, "robots_train": int(train.size), "robots_heldout": int(held.size),
                     "samples": int(t.size), "duration_s": float(t[-1] - t[0])}  # fmt: skip
    if method == "grid":
        spec = GridSpec.default() if spec is None else spec
        res = grid_search(spec, paper, tr_in, tr_truth, t, chunk, progress=progress, **options)
        best = res.best
        summary.update(configurations=spec.size, chunk=chunk, best_index=res.index, wall_s=res.wall_s,
                       grid={f.name: list(getattr(spec, f.name)) for f in dataclasses.fields(spec)})  # fmt: skip
    elif method == "gradient":
        res = gradient_tune(paper if start is None else start, tr_in, tr_truth, steps, progress=progress, **options)
        best = res.best
        summary.update(steps=int(res.loss.size), best_step=res.best_step, stopped=res.stopped, wall_s=res.wall_s,
                       loss=[float(x) for x in res.loss])  # fmt: skip
    else:
        raise ValueError(f"method must be grid or gradient, got {method!r}")
    summary["params"] = params_dict(best)
    parts = {"train": train} | ({"heldout": held} if held.size else {})
    for name, idx in parts.items():
        sub_in, sub_truth = select_robots(inputs, idx), select_robots(truth, idx)
        summary[f"paper_{name}"] = fleet_scores(paper, sub_in, sub_truth, t)
        summary[f"tuned_{name}"] = fleet_scores(best, sub_in, sub_truth, t)
    return best, summary
