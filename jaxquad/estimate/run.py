"""Estimate over a log (in memory or a file) and write the results: the library calls behind
`jaxquad estimate`.

`estimate_and_score(log, ...)` runs the pipeline, slices the scans of logs with depth and scores
everything against the log's ground truth, returning an `EstimateRun` in memory;
`write_run(run, out_dir)` writes it; `run_estimate(log or path, out_dir, ...)` does both after checking
the output folder. The folder, per robot i (`robot_000`, ... for a fleet, `robot` for a single log):
  <name>.tum        leg-inertial odometry, `t x y z qx qy qz qw` at every sample (log time, s)
  <name>.npz        t, p_world_base, q_world_base (wxyz), v_base, omega_base, contact,
                    contact_soft, force_z, force_z_filtered (N), qd, cov_v_base (T, 3, 3) (m/s)^2,
                    slip (T, 4) bool (stance feet the robust twist rejected), and one bool (T,) array per flag
                    (flag_bad_joints, flag_bad_imu, flag_bad_torque, flag_gap, flag_no_stance,
                    flag_fallen)
  <name>_scans.npz  when the log has depth: depth_t, ranges_stabilized and ranges_baseline (F, W) m
                    (+inf = no reading), bearings (W,) rad, roll and pitch (F,) rad used per frame
  summary.json      configuration, every parameter used (`params`: all of PipelineParams; the
                    observer's also as a --params file holds them), per-robot flag counts and, where
                    the log has ground truth, scores (contact F1 and delays, force RMSE, drift,
                    ATE/RPE)
The folder is built beside `out_dir` and renamed into place when complete.
"""

from __future__ import annotations

import dataclasses
import os
from collections.abc import Mapping
from pathlib import Path

import numpy as np

from jaxquad.estimate import scores

_FLAGS = ("bad_joints", "bad_imu", "bad_torque", "gap", "no_stance", "fallen")
_FIELDS = (
    "p_world_base",
    "q_world_base",
    "v_base",
    "omega_base",
    "contact",
    "contact_soft",
    "force_z",
    "force_z_filtered",
    "qd",
    "cov_v_base",
    "twist_weight",
    "slip",
)
SUMMARY_KIND = "jaxquad estimate"


def load_params(path: str | os.PathLike | None, n_feet: int = 4, contacts: str = "mixed"):
    """PipelineParams with the observer numbers of a params file (`jaxquad.io.read_observer_params`),
    else the paper's defaults."""
    import equinox as eqx

    from jaxquad.estimate.pipeline import PipelineParams
    from jaxquad.io.params import read_observer_params

    mode = "plain" if contacts == "observer" else "mixed"
    params = PipelineParams.default(n_feet, mode)
    if path is None:
        return params
    return eqx.tree_at(lambda p: p.observer, params, read_observer_params(path, n_feet, mode))


def estimate_log(
    log: Mapping,
    contacts: str = "truth",
    params=None,
    robot=None,
    odometry: dict | None = None,
    devices: int | None = None,
):
    """Run the pipeline over a log (a dict, a loaded `.npz` or a `jaxquad.sim.FleetLog`); returns
    (robot, config, Estimate as NumPy with a leading robot axis). odometry: leg-odometry choices of
    `PipelineConfig` (rolling, robust, robust_iters, robust_prior, floor, settle) to override; devices: how
    many devices the robots are split over (default all)."""
    from jaxquad import parallel
    from jaxquad.estimate import pipeline
    from jaxquad.robots import load

    robot = load(str(np.asarray(log["robot"]))) if robot is None else robot
    inputs, config = pipeline.inputs_from_log(robot, log, contacts)
    config = dataclasses.replace(config, **(odometry or {}))
    params = load_params(None, len(robot.foot_names), contacts) if params is None else params
    out = pipeline.estimate_fleet(robot, config, params, inputs, devices=devices)
    return robot, config, parallel.gather(out)


@dataclasses.dataclass
class EstimateRun:
    """Everything one estimation run produced, in memory (leading robot axis N on arrays)."""

    t: np.ndarray  # (T,) s
    names: list[str]  # per robot: robot_000, ... (or "robot" for a single log)
    estimate: object  # pipeline.Estimate of NumPy arrays
    scans: list | None  # per robot LogScans, when the log has depth
    depth_t: np.ndarray | None
    summary: dict


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
        res["drift"] = scores.odometry_scores(est["p_world_base"], est["q_world_base"], gt, valid)
        res["trajectory"] = trajectory_metrics(t, est, gt, valid)
    return res


def trajectory_metrics(t, est, gt, valid) -> dict:
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


def estimate_and_score(
    log: Mapping,
    contacts: str = "truth",
    params=None,
    progress=None,
    band_height: int = 5,
    range_min: float = 0.2,
    range_max: float = 8.0,
    source: str | None = None,
    odometry: dict | None = None,
    devices: int | None = None,
    band_reduce: str = "median",
) -> EstimateRun:
    """Estimate over `log`, slice its depth frames into scans, score against its ground truth.

    params: PipelineParams (the paper's defaults if None); band_height (px), range_min/range_max (m)
    and band_reduce (`jaxquad.kernels.scan`) configure the scans; source: where the log came from, for
    the summary; odometry and devices as `estimate_log`."""
    from jaxquad.estimate.inputs import check_log
    from jaxquad.io.jsonfile import json_ready
    from jaxquad.io.params import observer_params_dict
    from jaxquad.robots import load

    robot = load(str(np.asarray(log["robot"])))
    check_log(robot, log, contacts)
    if params is None:
        params = load_params(None, len(robot.foot_names), contacts)
    if progress is not None:
        progress(0, np.asarray(log["fallen"]).shape[0] if "fallen" in log else 1)  # inputs checked
    robot, config, out = estimate_log(log, contacts, params, robot, odometry, devices)
    t = np.asarray(log["t"], np.float64)
    fleet = "fallen" in log
    n = out.p_world_base.shape[0]
    summary = {
        "kind": SUMMARY_KIND,
        "log": source,
        "robot": robot.name,
        "contacts": contacts,
        "config": dataclasses.asdict(config),
        "samples": int(t.size),
        "duration_s": float(t[-1] - t[0]),
        "scans": {
            "band_height_px": band_height,
            "band_reduce": band_reduce,
            "range_min_m": range_min,
            "range_max_m": range_max,
        },
        "params": json_ready(params),
        "robots": [],
    }
    if contacts in ("observer", "mixed"):
        summary["observer_params"] = observer_params_dict(params.observer)  # as a --params file holds them
    names, scans = [], [] if "depth" in log else None
    for i in range(n):
        names.append(f"robot_{i:03d}" if fleet else "robot")
        est = {k: getattr(out, k)[i] for k in _FIELDS}
        flags = {f: getattr(out.flags, f)[i] for f in _FLAGS}
        if scans is not None:
            from jaxquad.estimate.scans import log_scans

            depth = np.asarray(log["depth"])[i] if fleet else np.asarray(log["depth"])
            scans.append(
                log_scans(
                    depth,
                    np.asarray(log["depth_t"]),
                    np.asarray(log["K"]),
                    t,
                    est["q_world_base"],
                    band_height,
                    range_min,
                    range_max,
                    band_reduce=band_reduce,
                )
            )
        log_i = {k: (np.asarray(v)[i] if fleet else v) for k, v in log.items() if k.startswith("gt_")}
        valid = ~flags["fallen"]
        summary["robots"].append(
            {
                "name": names[-1],
                "flag_counts": {k: int(v.sum()) for k, v in flags.items()},
                "fallen": bool(flags["fallen"].any()),
                "scores": _scores_one(t, est, log_i, valid, float(params.observer.f_max)),
            }
        )
        if progress is not None:
            progress(i + 1, n)
    depth_t = np.asarray(log["depth_t"]) if scans is not None else None
    return EstimateRun(t=t, names=names, estimate=out, scans=scans, depth_t=depth_t, summary=summary)


def write_run(run: EstimateRun, folder: str | os.PathLike) -> None:
    """Write an EstimateRun's files into an existing folder (see the module docstring)."""
    from jaxquad.io import TumTrajectory, atomic_open, write_tum
    from jaxquad.io.jsonfile import write_json

    folder = Path(folder)
    out = run.estimate
    for i, name in enumerate(run.names):
        est = {k: getattr(out, k)[i] for k in _FIELDS}
        flags = {f"flag_{f}": getattr(out.flags, f)[i] for f in _FLAGS}
        write_tum(
            folder / f"{name}.tum", TumTrajectory(run.t, est["p_world_base"], est["q_world_base"][:, [1, 2, 3, 0]])
        )
        with atomic_open(folder / f"{name}.npz") as f:
            np.savez(f, t=run.t, **est, **flags)
        if run.scans is not None:
            sc = run.scans[i]
            with atomic_open(folder / f"{name}_scans.npz") as f:
                np.savez(
                    f,
                    depth_t=run.depth_t,
                    **{
                        k: np.asarray(getattr(sc, k))
                        for k in ("ranges_stabilized", "ranges_baseline", "bearings", "roll", "pitch")
                    },
                )
    write_json(folder / "summary.json", run.summary)


def run_estimate(
    log,
    out_dir,
    contacts: str = "truth",
    params_path=None,
    progress=None,
    band_height: int = 5,
    range_min: float = 0.2,
    range_max: float = 8.0,
    odometry: dict | None = None,
    devices: int | None = None,
    band_reduce: str = "median",
) -> dict:
    """Estimate over `log` (a path to a `.npz`, or a log mapping such as a `jaxquad.sim.FleetLog`),
    write the output folder `out_dir` (checked first; replaced whole when complete, if it holds an
    earlier estimate), return the summary dict. The robots are split over `devices` devices (default
    all); in a multi-process run every process estimates and process 0 writes."""
    from jaxquad import parallel
    from jaxquad.io import atomic_dir, check_output_dir, load_log
    from jaxquad.robots import load

    check_output_dir(out_dir, kind=SUMMARY_KIND)
    source = None
    if not isinstance(log, Mapping):
        source, log = str(log), load_log(log)
    robot = load(str(np.asarray(log["robot"])))
    params = load_params(params_path, len(robot.foot_names), contacts)
    run = estimate_and_score(
        log, contacts, params, progress, band_height, range_min, range_max, source, odometry, devices, band_reduce
    )
    if params_path is not None:
        run.summary["params_file"] = str(params_path)
    if parallel.is_main():
        with atomic_dir(out_dir) as tmp:
            write_run(run, tmp)
    return run.summary
