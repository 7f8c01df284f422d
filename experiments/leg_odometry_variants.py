"""Leg-odometry error with and without each of its corrections, on simulated fleet logs.

Runs the estimation pipeline over each log for every variant:
  point     point feet, plain least squares, integrated height (the model before these corrections)
  rolling   contact points of the rolling feet
  robust    + Huber reweighting of the stance feet
  floor     + base height from the floor under the stance feet
  prior     + the feet also weighed against the previous sample's velocity
  settle    + each foot's weight ramped up over its first 32 ms of stance (every correction: the default)
and prints one Markdown row per (log, contacts, variant) of means over the robots that did not fall:
segment drift (`drift_pct`: KITTI t_rel over 2, 5 and 10 m segments), end-point drift in % of the
horizontal distance, path-length ratio (estimated over true horizontal path, both sampled every 1 s:
`path_ratio`, the scale; every sample: `path_ratio_raw`, lengthened by the per-sample velocity noise,
see `jaxquad.estimate.scores.path_ratio`), the mean forward-velocity error in % of the mean forward
speed (`fwd_bias_pct`, base x, observed samples), segment drift (RMSE of the relative translation
error over 5 m segments, evo's RPE, in % of
5 m), ATE (m, SE(3)-aligned), |height error| at the end (m), and the NEES of the twist's linear
velocity against the true base velocity (finite differences of gt_pose, base frame; its expected
value is 3 for a consistent covariance), with the fraction of samples inside the 95% chi-square(3)
bound (7.81).

    python experiments/leg_odometry_variants.py LOG.npz [LOG.npz ...] [--contacts truth mixed]
        [--params tuned.yaml] [--variants point rolling robust floor] [--sigma-prior 0.04 0.06]
        [--settle-ms 24 32 48] [--json out.json]

`--sigma-prior` sweeps the prior noise level of the twist covariance (a row per value): the NEES
column shows which value makes the covariance consistent for a gait. `--settle-ms` sweeps the time
over which a touching-down foot's weight ramps up (a "settle" row per value).
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import math
import os
import sys

import numpy as np

VARIANTS = {
    "point": dict(rolling=False, robust="none", robust_prior=False, floor=False, settle=False),
    "rolling": dict(rolling=True, robust="none", robust_prior=False, floor=False, settle=False),
    "robust": dict(rolling=True, robust="huber", robust_prior=False, floor=False, settle=False),
    "floor": dict(rolling=True, robust="huber", robust_prior=False, floor=True, settle=False),
    "prior": dict(rolling=True, robust="huber", robust_prior=True, floor=True, settle=False),
    "settle": dict(rolling=True, robust="huber", robust_prior=True, floor=True, settle=True),
}
_CHI2_3_95 = 7.815


def _true_v_base(gt_pose: np.ndarray, t: np.ndarray) -> np.ndarray:
    """Base velocity in base axes (T, 3) from gt positions (central differences) and orientations."""
    from scipy.spatial.transform import Rotation

    v_world = np.gradient(gt_pose[:, :3], t, axis=0)
    R = Rotation.from_quat(gt_pose[:, [4, 5, 6, 3]]).as_matrix()
    return np.einsum("tji,tj->ti", R, v_world)


def score_robot(t, est: dict, gt_pose: np.ndarray, valid: np.ndarray) -> dict:
    from jaxquad.estimate import scores
    from jaxquad.estimate.run import trajectory_metrics

    m = valid
    p_est, p_true = est["p_world_base"][m], gt_pose[m, :3]
    drift = scores.odometry_scores(p_est, est["q_world_base"][m], gt_pose[m])
    traj = trajectory_metrics(t, est, gt_pose, m)
    ate = traj.get("ate", {}).get("rmse", np.nan)
    seg = traj.get("rpe_5m", {}).get("rmse", np.nan)  # 5 m segments (NaN on walks shorter than 10 m)
    # NEES over observed samples away from the ends (central differences there are one-sided).
    err = est["v_base"] - _true_v_base(gt_pose, t)
    obs = m & ~est["no_stance"]
    obs[:5] = obs[-5:] = False
    cov = est["cov_v_base"][obs]
    nees = np.einsum("ti,tij,tj->t", err[obs], np.linalg.inv(cov), err[obs])
    v_fwd = _true_v_base(gt_pose, t)[obs, 0]
    return {
        "drift_pct": drift["drift_pct"]["mean"],  # segments of 2, 5 and 10 m
        "endpoint_drift_pct": drift["endpoint_drift_horizontal_pct"],
        **scores.path_ratio(t[m], p_est, p_true),
        "fwd_bias_pct": float(100.0 * err[obs, 0].mean() / v_fwd.mean()),
        "ate_m": float(ate),
        "seg5m_pct": float(100.0 * seg / 5.0),
        "height_err_end_m": float(abs(p_est[-1, 2] - p_true[-1, 2])),
        "nees_mean": float(nees.mean()),
        "nees_in_95": float((nees < _CHI2_3_95).mean()),
        "v_rmse": float(np.sqrt((err[obs] ** 2).sum(-1).mean())),
    }


def run(
    log_path: str,
    contacts: str,
    variant: str,
    params_path: str | None,
    sigma_prior: float | None = None,
    settle_ms: float | None = None,
) -> dict:
    import jax

    from jaxquad.estimate import pipeline
    from jaxquad.estimate.run import load_params
    from jaxquad.io import load_log
    from jaxquad.robots import load

    log = load_log(log_path)
    robot = load(str(np.asarray(log["robot"])))
    inputs, config = pipeline.inputs_from_log(robot, log, contacts)
    config = dataclasses.replace(config, **VARIANTS[variant])
    params = load_params(params_path, len(robot.foot_names), contacts)
    if sigma_prior is not None:
        params = dataclasses.replace(params, sigma_prior=np.float32(sigma_prior))
    if settle_ms is not None:
        params = dataclasses.replace(params, settle_s=np.float32(settle_ms / 1000.0))
    out = jax.tree.map(np.asarray, pipeline.estimate_fleet(robot, config, params, inputs))
    t = np.asarray(log["t"], np.float64)
    rows = []
    for i in range(out.p_world_base.shape[0]):
        if bool(np.asarray(log["fallen"])[i]):
            continue
        est = {k: getattr(out, k)[i] for k in ("p_world_base", "q_world_base", "v_base", "cov_v_base")}
        est["no_stance"] = out.flags.no_stance[i]
        valid = ~out.flags.fallen[i]
        rows.append(score_robot(t, est, np.asarray(log["gt_pose"])[i], valid))
    mean = {k: float(np.mean([r[k] for r in rows])) for k in rows[0]}
    return {
        "log": log_path,
        "robot": robot.name,
        "contacts": contacts,
        "variant": variant,
        "robots": len(rows),
    } | mean


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("logs", nargs="+", help="fleet logs (.npz) with gt_pose")
    ap.add_argument(
        "--contacts",
        nargs="+",
        default=["truth"],
        help="contact sources (default truth)",
    )
    ap.add_argument(
        "--params",
        default=None,
        help="observer parameter file for observer contacts (default: paper)",
    )
    ap.add_argument(
        "--variants",
        nargs="+",
        default=list(VARIANTS),
        choices=list(VARIANTS),
        help="default: all",
    )
    ap.add_argument(
        "--sigma-prior",
        nargs="+",
        type=float,
        default=[None],
        metavar="M_PER_S",
        help="prior foot-velocity noise of the twist covariance, m/s; several values sweep it "
        "(default: the pipeline's, PipelineParams.default().sigma_prior)",
    )
    ap.add_argument(
        "--settle-ms",
        nargs="+",
        type=float,
        default=[None],
        metavar="MS",
        help="time over which a touching-down foot's twist weight ramps from 0 to 1, ms; several values sweep "
        "it (default: the pipeline's, PipelineParams.default().settle_s)",
    )
    ap.add_argument("--json", default=None, help="also write the rows to this JSON file")
    args = ap.parse_args(argv)
    # One-line errors before any simulation or compile.
    missing = [log for log in args.logs if not os.path.isfile(log)]
    if missing:
        ap.error(f"log file(s) not found: {', '.join(missing)}")
    bad = [s for s in args.sigma_prior if s is not None and not (math.isfinite(s) and s > 0)]
    if bad:
        ap.error(f"--sigma-prior values must be positive, got {bad}")
    bad = [s for s in args.settle_ms if s is not None and not (math.isfinite(s) and s >= 0)]
    if bad:
        ap.error(f"--settle-ms values must be >= 0, got {bad}")
    if args.json:
        from jaxquad.io.atomic import check_output_file

        try:
            check_output_file(args.json, "--json")
        except ValueError as e:
            ap.error(str(e))
    import platform
    import shlex

    import jax

    print(f"command: python {shlex.join(sys.argv)}")
    print(
        f"machine: {platform.node()} {platform.processor() or platform.machine()}, jax {jax.__version__} on "
        f"{jax.devices()[0].platform}\n"
    )
    keys = (
        "drift_pct",
        "endpoint_drift_pct",
        "seg5m_pct",
        "path_ratio",
        "path_ratio_raw",
        "fwd_bias_pct",
        "ate_m",
        "height_err_end_m",
        "nees_mean",
        "nees_in_95",
        "v_rmse",
    )
    print("| log | robot | contacts | variant | n | " + " | ".join(keys) + " |")
    print("|---|---|---|---|---:|" + "---:|" * len(keys))
    rows = []
    for log in args.logs:
        for contacts in args.contacts:
            for variant in args.variants:
                for sigma in args.sigma_prior:
                    for settle in args.settle_ms if variant == "settle" else [None]:  # only it ramps
                        r = run(log, contacts, variant, args.params, sigma, settle)
                        r |= {"sigma_prior": sigma, "settle_ms": settle}
                        rows.append(r)
                        vals = " | ".join(f"{r[k]:.3f}" for k in keys)
                        label = variant + ("" if sigma is None else f", sigma_prior {sigma:g}")
                        label += "" if settle is None else f", settle {settle:g} ms"
                        print(f"| {log} | {r['robot']} | {contacts} | {label} | {r['robots']} | {vals} |", flush=True)
    if args.json:
        from jaxquad.io.atomic import atomic_write_text

        atomic_write_text(args.json, json.dumps(rows, indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())
