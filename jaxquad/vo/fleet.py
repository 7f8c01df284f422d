"""Visual odometry over a log: the library calls behind `jaxquad vo`.

`vo_inputs(log, p_leg, q_leg)` builds the per-frame inputs (depth, the gyro's rotation between frames
in the camera frame, the leg-odometry pose at each frame: the last IMU sample at or before the
frame's stamp); `visual_odometry(log, p_leg, q_leg, coupling)` runs the odometry over every robot
(jit + vmap over robots, lax.scan over frames) and returns a `VoResult` in memory;
`run_vo(log, out_dir, coupling)` runs the estimator for the leg odometry, then the odometry, scores
against the log's ground truth and writes `<robot>.tum` per robot and `summary.json`.
"""

from __future__ import annotations

import dataclasses
import functools
from collections.abc import Mapping

import jax
import jax.numpy as jnp
import numpy as np

from jaxquad.estimate.scans import frame_samples
from jaxquad.kernels.lie import SE3, SO3
from jaxquad.vo.odometry import VoInputs, VoOutput, VoParams, run

SUMMARY_KIND = "jaxquad vo"


@dataclasses.dataclass
class VoResult:
    """Odometry of N robots over F frames (NumPy, leading robot axis)."""

    t: np.ndarray  # (F,) frame stamps, s
    coupling: str
    p_world_base: np.ndarray  # (N, F, 3) m
    q_world_base: np.ndarray  # (N, F, 4) w x y z
    output: VoOutput  # per-frame information, inliers, conditioning, residual, flags: (N, F, ...)


@jax.jit
def _gyro_rotations(t, gyro, idx, R_imu_cam):
    """Camera rotation between consecutive frames, from the gyro integrated over the samples between
    them (sample k covers (t_{k-1}, t_k]; non-finite readings count as no rotation)."""
    dt = jnp.diff(t, prepend=t[:1])

    def one(g):
        g = jnp.where(jnp.isfinite(g), g, 0.0)

        def body(R, x):
            R = R @ SO3.exp(x[0] * x[1])
            return R, R.wxyz

        _, q = jax.lax.scan(body, SO3.identity(), (g, dt))
        R_world_imu = jax.vmap(lambda w: SO3(w).as_matrix())(q[idx])
        R_prev = jnp.concatenate([R_world_imu[:1], R_world_imu[:-1]])
        return R_imu_cam.T @ jnp.swapaxes(R_prev, -1, -2) @ R_world_imu @ R_imu_cam

    return jax.vmap(one)(gyro)


def vo_inputs(log: Mapping, p_leg: np.ndarray, q_leg: np.ndarray, R_base_imu: np.ndarray) -> VoInputs:
    """Inputs with a leading robot axis (N, F, ...); p_leg (N, T, 3), q_leg (N, T, 4) w x y z."""
    for key in ("depth", "depth_t", "K", "T_base_camera"):
        if key not in log:
            raise ValueError(f"log has no {key!r}: visual odometry needs depth images")
    t = np.asarray(log["t"], np.float64)
    depth = np.asarray(log["depth"], np.float32)
    gyro = np.asarray(log["gyro"], np.float32)
    if depth.ndim == 3:
        depth, gyro = depth[None], gyro[None]
    if not (np.shape(p_leg)[:1] == np.shape(q_leg)[:1] == depth.shape[:1]):
        raise ValueError(f"leg odometry for {np.shape(p_leg)[0]} robots, depth for {depth.shape[0]}")
    idx = frame_samples(t, np.asarray(log["depth_t"], np.float64))
    T_bc = np.asarray(log["T_base_camera"], np.float64)
    R_imu_cam = np.asarray(R_base_imu, np.float64).T @ T_bc[:3, :3]
    R = _gyro_rotations(
        jnp.asarray(t - t[0], jnp.float32), jnp.asarray(gyro), jnp.asarray(idx), jnp.asarray(R_imu_cam, jnp.float32)
    )
    q = jnp.asarray(np.asarray(q_leg, np.float32)[:, idx])
    p = jnp.asarray(np.asarray(p_leg, np.float32)[:, idx])
    T_leg = jax.vmap(jax.vmap(lambda q, p: SE3.from_rotation_and_translation(SO3(q), p).as_matrix()))(q, p)
    return VoInputs(depth=jnp.asarray(depth), R_prev_cur_gyro=R, T_world_base_leg=T_leg)


def _take(x, rows):
    return x[rows]


def _head(x, count):
    return np.asarray(x)[:count]


@functools.cache
def _fleet_fn():
    return jax.jit(jax.vmap(run, in_axes=(None, 0)))


def visual_odometry(
    log: Mapping,
    p_leg: np.ndarray,
    q_leg: np.ndarray,
    R_base_imu: np.ndarray,
    coupling: str = "guess+restart",
    params: VoParams | None = None,
    chunk: int = 64,
    progress=None,
) -> VoResult:
    """Depth odometry of every robot of `log`, guided by the leg odometry (p_leg (N, T, 3) m,
    q_leg (N, T, 4) w x y z at the log's samples). Robots run `chunk` at a time (one compile)."""
    if params is None:
        params = VoParams.default(np.asarray(log["K"]), np.asarray(log["T_base_camera"]), coupling)
    inputs = vo_inputs(log, p_leg, q_leg, R_base_imu)
    n = inputs.depth.shape[0]
    outs = []
    size = min(chunk, n)
    for start in range(0, n, size):
        # Every chunk has one shape (one compile): the last one is padded with its last robot.
        rows = np.minimum(np.arange(start, start + size), n - 1)
        part = jax.tree.map(functools.partial(_take, rows=rows), inputs)
        out = jax.tree.map(
            functools.partial(_head, count=min(size, n - start)),
            _fleet_fn()(params, part),
        )
        outs.append(out)
        if progress is not None:
            progress(min(start + size, n), n)
    out = jax.tree.map(lambda *x: np.concatenate(x), *outs)
    T = out.T_world_base
    q = np.asarray(jax.vmap(jax.vmap(lambda R: SO3.from_matrix(R).wxyz))(jnp.asarray(T[..., :3, :3])))
    return VoResult(
        t=np.asarray(log["depth_t"], np.float64),
        coupling=params.coupling,
        p_world_base=T[..., :3, 3],
        q_world_base=q,
        output=out,
    )


def _scores(result: VoResult, i: int, gt: np.ndarray, idx: np.ndarray, p_leg, q_leg) -> dict:
    from jaxquad.estimate.run import trajectory_metrics
    from jaxquad.estimate.scores import odometry_scores

    valid = np.ones(idx.size, bool)
    est = {
        "p_world_base": result.p_world_base[i],
        "q_world_base": result.q_world_base[i],
    }
    leg = {
        "p_world_base": np.asarray(p_leg)[i, idx],
        "q_world_base": np.asarray(q_leg)[i, idx],
    }
    return {
        "vo": {
            "trajectory": trajectory_metrics(result.t, est, gt, valid),
            "drift": odometry_scores(est["p_world_base"], est["q_world_base"], gt, valid),
        },
        "leg_odometry": {
            "trajectory": trajectory_metrics(result.t, leg, gt, valid),
            "drift": odometry_scores(leg["p_world_base"], leg["q_world_base"], gt, valid),
        },
    }


def score_vo(log: Mapping, result: VoResult, p_leg: np.ndarray, q_leg: np.ndarray) -> list[dict]:
    """Per robot: tracking losses, keyframes, alignment statistics and, when the log has ground
    truth, ATE/ARE/RPE (evo's definitions, SE(3)-aligned) and end-point drift of the visual and of
    the leg odometry, both at the frame stamps."""
    fleet = "fallen" in log
    idx = frame_samples(np.asarray(log["t"], np.float64), result.t)
    out = result.output
    robots = []
    for i in range(result.p_world_base.shape[0]):
        lost = np.asarray(out.tracking_lost[i])
        entry = {
            "name": f"robot_{i:03d}" if fleet else "robot",
            "tracking_losses": int(lost.sum()),
            "loss_rate": float(lost.mean()),
            "keyframes": int(np.asarray(out.new_keyframe[i]).sum()),
            "median_inliers": float(np.median(out.n_inliers[i])),
            "median_min_eig": float(np.median(out.min_eig[i])),
            "median_rmse_m": float(np.median(out.rmse[i])),
        }
        if "gt_pose" in log:
            gt = np.asarray(log["gt_pose"])[i] if fleet else np.asarray(log["gt_pose"])
            entry["scores"] = _scores(result, i, gt[idx], idx, p_leg, q_leg)
        robots.append(entry)
    return robots


def run_vo(
    log,
    out_dir,
    coupling: str = "guess+restart",
    contacts: str = "mixed",
    progress=None,
) -> dict:
    """Leg odometry by the estimator, then visual odometry; write `<robot>.tum` per robot and
    `summary.json` into `out_dir` (checked first, replaced whole when complete); return the summary."""
    from jaxquad.estimate import estimate_log
    from jaxquad.estimate.inputs import R_base_imu, check_log
    from jaxquad.io import (
        TumTrajectory,
        atomic_dir,
        check_output_dir,
        load_log,
        write_tum,
    )
    from jaxquad.io.jsonfile import write_json
    from jaxquad.robots import load

    check_output_dir(out_dir, kind=SUMMARY_KIND)
    source = None
    if not isinstance(log, Mapping):
        source, log = str(log), load_log(log)
    if "depth" not in log:
        raise ValueError(f"{source or 'log'}: log has no 'depth' images")
    robot = load(str(np.asarray(log["robot"])))
    check_log(robot, log, contacts)
    if progress is not None:
        progress(0, np.asarray(log["fallen"]).shape[0] if "fallen" in log else 1)  # inputs checked
    robot, _, est = estimate_log(log, contacts, robot=robot)
    result = visual_odometry(
        log,
        est.p_world_base,
        est.q_world_base,
        R_base_imu(robot),
        coupling,
        progress=progress,
    )
    summary = {
        "kind": SUMMARY_KIND,
        "log": source,
        "robot": robot.name,
        "coupling": coupling,
        "contacts": contacts,
        "frames": int(result.t.size),
        "robots": score_vo(log, result, est.p_world_base, est.q_world_base),
    }
    with atomic_dir(out_dir) as tmp:
        for i, entry in enumerate(summary["robots"]):
            traj = TumTrajectory(
                result.t,
                result.p_world_base[i],
                result.q_world_base[i][:, [1, 2, 3, 0]],
            )
            write_tum(tmp / f"{entry['name']}.tum", traj)
        write_json(tmp / "summary.json", summary)
    return summary
