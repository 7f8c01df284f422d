"""Estimate over a log file and write the results: the library call behind `jaxquad estimate`.

Output folder, per robot i (`robot_000`, ... for a fleet, `robot` for a single log):
  <name>.tum        leg-inertial odometry, `t x y z qx qy qz qw` at every sample (log time, s)
  <name>.npz        t, p_world_base, q_world_base (wxyz), v_base, omega_base, contact,
                    contact_soft, force_z, force_z_filtered (N), qd, cov_v_base (T, 3, 3) (m/s)^2,
                    slip (T, 4) bool (stance feet the robust twist rejected), and one bool (T,) array per flag
                    (flag_bad_joints, flag_bad_imu, flag_bad_torque, flag_gap, flag_no_stance,
                    flag_fallen)
  <name>_scans.npz  when the log has depth: depth_t, ranges_stabilized and ranges_baseline (F, W) m
                    (+inf = no reading), bearings (W,) rad, roll and pitch (F,) rad used per frame
  summary.json      configuration, per-robot flag counts and, where the log has ground truth,
                    scores (contact F1 and delays, force RMSE, drift, ATE/RPE)
"""

from __future__ import annotations

import json
import os
from pathlib import Path

import numpy as np

from jaxquad.estimate import scores

_FLAGS = ("bad_joints", "bad_imu", "bad_torque", "gap", "no_stance", "fallen")


def load_params(path: str | os.PathLike | None, n_feet: int = 4, contacts: str = "mixed"):
    """PipelineParams from a YAML or JSON file (keys: bandwidth, mode, alpha, threshold_on,
    threshold_off, f_max, sharpness; scalars or per-foot lists), else the paper's defaults."""
    import jax.numpy as jnp

    from jaxquad.estimate.pipeline import PipelineParams

    mode = "plain" if contacts == "observer" else "mixed"
    if path is None:
        return PipelineParams.default(n_feet, mode)
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"params file not found: {path}")
    import yaml

    raw = yaml.safe_load(path.read_text()) or {}
    if not isinstance(raw, dict):
        raise ValueError(f"params file {path}: expected a mapping of observer parameters")
    raw = raw.get("observer", raw)
    mode = raw.pop("mode", mode)
    params = PipelineParams.default(n_feet, mode)
    known = ("bandwidth", "alpha", "threshold_on", "threshold_off", "f_max", "sharpness")
    unknown = sorted(set(raw) - set(known))
    if unknown:
        raise ValueError(f"params file {path}: unknown key(s) {unknown}; known: {list(known) + ['mode']}")
    obs = params.observer
    for key, value in raw.items():
        old = getattr(obs, key)
        new = jnp.broadcast_to(jnp.asarray(value, jnp.float32), old.shape)
        if not bool(jnp.all(jnp.isfinite(new))):
            raise ValueError(f"params file {path}: {key} is not finite")
        obs = eqx_replace(obs, key, new)
    return eqx_replace(params, "observer", obs)


def eqx_replace(module, name: str, value):
    import equinox as eqx

    return eqx.tree_at(lambda m: getattr(m, name), module, value)


def estimate_log(log: dict, contacts: str = "truth", params=None, robot=None, odometry: dict | None = None):
    """Run the pipeline over a log dict; returns (robot, config, Estimate as NumPy, N robots).

    odometry: leg-odometry choices of `PipelineConfig` (rolling, robust, robust_iters, floor) to override."""
    import dataclasses

    import jax

    from jaxquad.estimate import pipeline
    from jaxquad.robots import load

    robot = load(str(np.asarray(log["robot"]))) if robot is None else robot
    inputs, config = pipeline.inputs_from_log(robot, log, contacts)
    config = dataclasses.replace(config, **(odometry or {}))
    params = load_params(None, len(robot.foot_names), contacts) if params is None else params
    out = pipeline.estimate_fleet(robot, config, params, inputs)
    return robot, config, jax.tree.map(np.asarray, out)


def _scores_one(t, est, log_i: dict, valid, f_max: float) -> dict:
    res = {}
    if "gt_contact" in log_i:
        res["contacts"] = scores.contact_scores(est["contact"], log_i["gt_contact"], valid)
        res["delays"] = scores.detection_delays(t, est["contact"], log_i["gt_contact"], valid)
    if "gt_force" in log_i and np.any(est["force_z"]):
        true_fz = np.asarray(log_i["gt_force"])[..., 2]
        res["force"] = scores.force_rmse(est["force_z_filtered"], true_fz, valid)
        res["force_clipped"] = scores.force_rmse(est["force_z_filtered"], true_fz, valid, f_max)
    if "gt_pose" in log_i:
        gt = np.asarray(log_i["gt_pose"])
        res["drift"] = scores.odometry_drift(est["p_world_base"], gt[:, :3], valid)
        res["trajectory"] = _trajectory_metrics(t, est, gt, valid)
    return res


def _trajectory_metrics(t, est, gt, valid) -> dict:
    from jaxquad.io import TumTrajectory
    from jaxquad.metrics import evaluate

    m = np.asarray(valid, bool)
    ref = TumTrajectory(t[m], gt[m, :3], gt[m][:, [4, 5, 6, 3]])
    q = est["q_world_base"][m]
    traj = TumTrajectory(t[m], est["p_world_base"][m], q[:, [1, 2, 3, 0]])
    length = float(np.linalg.norm(np.diff(gt[m, :3], axis=0), axis=1).sum())
    deltas = [d for d in (2.0, 5.0, 10.0) if d < 0.5 * length] or [max(length / 4, 1e-3)]
    try:
        return evaluate(ref, traj, align="se3", deltas=deltas).to_dict()
    except ValueError as e:  # too short or degenerate to align: reported, not fatal
        return {"error": str(e)}


def run_estimate(
    log_path, out_dir, contacts: str = "truth", params_path=None, progress=None,
    band_height: int = 5, range_min: float = 0.2, range_max: float = 8.0, odometry: dict | None = None,
) -> dict:  # fmt: skip
    """Estimate over the log at `log_path`, write the output folder, return the summary dict.

    band_height (px) and range_min/range_max (m) configure the scans of logs with depth; odometry as
    `estimate_log`."""
    from jaxquad.io import TumTrajectory, load_log, write_tum
    from jaxquad.robots import load

    log = load_log(log_path)
    robot = load(str(np.asarray(log["robot"])))
    params = load_params(params_path, len(robot.foot_names), contacts)
    _, config, out = estimate_log(log, contacts, params, robot, odometry)
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    t = np.asarray(log["t"], np.float64)
    fleet = "fallen" in log
    n = out.p_world_base.shape[0]
    summary = {"log": str(log_path), "robot": robot.name, "contacts": contacts, "config": vars(config) | {},
               "samples": int(t.size), "duration_s": float(t[-1] - t[0]), "robots": []}  # fmt: skip
    for i in range(n):
        name = f"robot_{i:03d}" if fleet else "robot"
        est = {k: getattr(out, k)[i] for k in ("p_world_base", "q_world_base", "v_base", "omega_base", "contact",
                                               "contact_soft", "force_z", "force_z_filtered", "qd",
                                               "cov_v_base", "slip")}  # fmt: skip
        flags = {f: getattr(out.flags, f)[i] for f in _FLAGS}
        q = est["q_world_base"]
        write_tum(out_dir / f"{name}.tum", TumTrajectory(t, est["p_world_base"], q[:, [1, 2, 3, 0]]))
        np.savez(out_dir / f"{name}.npz", t=t, **est, **{f"flag_{k}": v for k, v in flags.items()})
        if "depth" in log:
            from jaxquad.estimate.scans import log_scans

            depth = np.asarray(log["depth"])[i] if fleet else np.asarray(log["depth"])
            sc = log_scans(depth, np.asarray(log["depth_t"]), np.asarray(log["K"]), t, q, band_height,
                           range_min, range_max)  # fmt: skip
            np.savez(out_dir / f"{name}_scans.npz", depth_t=np.asarray(log["depth_t"]),
                     **{k: np.asarray(getattr(sc, k)) for k in ("ranges_stabilized", "ranges_baseline",
                                                                "bearings", "roll", "pitch")})  # fmt: skip
        valid = ~flags["fallen"]
        log_i = {k: (np.asarray(v)[i] if fleet else v) for k, v in log.items()
                 if k.startswith("gt_")}  # fmt: skip
        entry = {"name": name, "flag_counts": {k: int(v.sum()) for k, v in flags.items()},
                 "fallen": bool(flags["fallen"].any()), "scores": _scores_one(t, est, log_i, valid, float(params.observer.f_max))}  # fmt: skip
        summary["robots"].append(entry)
        if progress is not None:
            progress(i + 1, n)
    (out_dir / "summary.json").write_text(json.dumps(summary, indent=2))
    return summary
