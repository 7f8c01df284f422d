"""Localization over a robot log on a saved map: the library calls behind `jaxquad localize`.

The estimator (jaxquad.estimate) gives the leg-inertial odometry and the IMU-stabilized scans of the
log's depth frames; the AMCL kernels (jaxquad.kernels.amcl_step) run over the scans with the
odometry pose (x, y, yaw) at each frame, in one `lax.scan` per chunk of frames, `vmap`ped over the
robots of a fleet. Output folder:

  <robot>.tum     the localization pose at every depth frame, `t x y 0 qx qy qz qw` (z = 0)
  <robot>.npz     t, pose (F, 3), cov (F, 3, 3), n_eff, updated, resampled, p_random and, with
                  ground truth, gt_pose (F, 3) and error_xy (F,) m
  summary.json    the parameters used (and their file), and per robot: updates, final pose and
                  spread, and with ground truth the position error (median, p99, rmse, max, m),
                  the heading error (median, rad), the error of the odometry alone started at the
                  true first pose (median, p99, m) and, for global localization, the convergence time
"""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np

from jaxquad.estimate.laser import laser_inputs
from jaxquad.kernels import AmclInputs, AmclParams, LikelihoodField, amcl_init, amcl_step, likelihood_field
from jaxquad.kernels.lie import SE2
from jaxquad.localize.params import DEFAULTS_FILE, LocalizeParams, load_params

# Scans per jitted call: long enough to amortize dispatch, short enough for a live progress bar.
_CHUNK = 128
SUMMARY_KIND = "jaxquad localize"
# Global localization has converged from the first frame after which the error stays below this (m).
CONVERGED_M = 0.5


@jax.jit
def _run_chunk(params: AmclParams, field: LikelihoodField, states, inputs: AmclInputs):
    def one(state, inp):
        return jax.lax.scan(lambda s, x: amcl_step(params, field, s, x), state, inp)

    return jax.vmap(one)(states, inputs)


def field_of_map(occ, max_dist: float, surfaces: bool = False) -> LikelihoodField:
    """The likelihood field of an `OccupancyMap` (whose yaw must be 0); `surfaces`: see `likelihood_field`."""
    if abs(occ.origin[2]) > 1e-9:
        raise ValueError(f"map origin yaw must be 0 for localization, got {occ.origin[2]}")
    return likelihood_field(occ.grid, occ.resolution, occ.origin[:2], max_dist, surfaces)


def localize_scans(
    params: AmclParams,
    field: LikelihoodField,
    odom: np.ndarray,
    ranges: np.ndarray,
    bearings: np.ndarray,
    n_particles: int,
    initial_pose: np.ndarray | None,
    seed: int = 0,
    progress=None,
):
    """AMCL over N robots' F scans: odom (N, F, 3) x y yaw, ranges (N, F, W) m, bearings (W,) rad;
    initial_pose (N, 3) or None for global localization. Returns the AmclOutput (N, F, ...) as NumPy."""
    n, f = odom.shape[:2]
    key_init, key_run = jax.random.split(jax.random.PRNGKey(seed))
    keys_init = jax.random.split(key_init, n)
    if initial_pose is None:
        states = jax.vmap(lambda k: amcl_init(params, field, None, k, n_particles))(keys_init)
    else:
        init = jax.vmap(lambda p, k: amcl_init(params, field, p, k, n_particles))
        states = init(jnp.asarray(initial_pose, jnp.float32), keys_init)
    keys = jax.random.split(key_run, (n, f))
    outs = []
    for start in range(0, f, _CHUNK):
        stop = min(start + _CHUNK, f)
        pad = _CHUNK - (stop - start)
        # Padding frames carry NaN odometry, which the filter skips.
        o = np.pad(odom[:, start:stop], ((0, 0), (0, pad), (0, 0)), constant_values=np.nan)
        r = np.pad(ranges[:, start:stop], ((0, 0), (0, pad), (0, 0)), constant_values=np.inf)
        k = jnp.concatenate([keys[:, start:stop], jnp.broadcast_to(keys[:, :1], (n, pad) + keys.shape[2:])], 1)
        b = np.broadcast_to(bearings, r.shape)
        inputs = AmclInputs(jnp.asarray(o, jnp.float32), jnp.asarray(r, jnp.float32), jnp.asarray(b, jnp.float32), k)
        states, out = _run_chunk(params, field, states, inputs)
        outs.append(jax.tree.map(lambda x, n=stop - start: np.asarray(x)[:, :n], out))
        if progress is not None:
            progress(stop, f)
    return jax.tree.map(lambda *xs: np.concatenate(xs, 1), *outs)


def _anchored(odom: np.ndarray, start: np.ndarray) -> np.ndarray:
    """Odometry poses (F, 3) moved rigidly so that the first one sits at `start` (x, y, yaw)."""
    T = SE2.from_xy_theta(*jnp.asarray(start, jnp.float32)) @ SE2.from_xy_theta(*jnp.asarray(odom[0])).inverse()
    P = T @ SE2.from_xy_theta(*jnp.asarray(odom, jnp.float32).T)
    return np.column_stack([np.asarray(P.translation()), np.asarray(P.rotation().as_radians())])


def _scores(t: np.ndarray, pose: np.ndarray, gt: np.ndarray, valid: np.ndarray, global_: bool) -> dict:
    err = np.hypot(*(pose[:, :2] - gt[:, :2]).T)
    yaw = np.abs((pose[:, 2] - gt[:, 2] + np.pi) % (2 * np.pi) - np.pi)
    e, y = err[valid], yaw[valid]
    res = {
        "position_error_median_m": float(np.median(e)),
        "position_error_p99_m": float(np.percentile(e, 99)),
        "position_error_rmse_m": float(np.sqrt(np.mean(e**2))),
        "position_error_max_m": float(e.max()),
        "heading_error_median_rad": float(np.median(y)),
    }
    if global_:
        above = np.flatnonzero(~(err < CONVERGED_M) & valid)
        first = 0 if above.size == 0 else above[-1] + 1
        res["converged_after_s"] = float(t[first] - t[0]) if first < t.size else None
        res["converged_threshold_m"] = CONVERGED_M
    return res


def log_inputs(
    log: dict,
    lp: LocalizeParams,
    contacts: str = "mixed",
    band_height: int = 5,
    observer_params=None,
    progress=None,
    band_reduce: str = "median",
) -> dict:
    """What the filter reads from a loaded log (`jaxquad.estimate.laser.laser_inputs` with the
    stabilized scans cut to the filter's laser range limits); `progress(0, F)` once the log is checked."""
    return laser_inputs(
        log,
        "stabilized",
        contacts,
        band_height,
        lp.laser_min_range,
        lp.laser_max_range,
        observer_params,
        progress=progress,
        band_reduce=band_reduce,
    )


def localize_log(
    log: dict,
    occ,
    lp: LocalizeParams,
    initial: str | tuple[float, float, float] = "global",
    contacts: str = "mixed",
    band_height: int = 5,
    progress=None,
    observer_params=None,
    band_reduce: str = "median",
) -> list[dict]:
    """Localize every robot of a loaded log on `occ` (an OccupancyMap). `initial`: "global", "gt"
    (the log's ground truth at the first frame) or an (x, y, theta) pose. One dict per robot."""
    if initial == "gt" and "gt_pose" not in log:
        raise ValueError("--initial-pose-gt needs a log with gt_pose")
    field = field_of_map(occ, lp.laser_likelihood_max_dist)
    x = log_inputs(log, lp, contacts, band_height, observer_params, progress, band_reduce)
    n = x["odom"].shape[0]
    gt = x.get("gt")
    if initial == "global":
        init = None
    elif initial == "gt":
        init = gt[:, 0]
    else:
        init = np.broadcast_to(np.asarray(initial, np.float64), (n, 3))
    params = lp.amcl(T_base_laser=tuple(float(v) for v in x["T_base_laser"]))
    out = localize_scans(
        params, field, x["odom"], x["ranges"], x["bearings"], lp.max_particles, init, lp.seed, progress
    )
    fleet = "fallen" in log
    robots = []
    for i in range(n):
        r = {
            "name": f"robot_{i:03d}" if fleet else "robot",
            "t": x["t"],
            "pose": out.pose[i],
            "cov": out.cov[i],
            "n_eff": out.n_eff[i],
            "updated": out.updated[i],
            "resampled": out.resampled[i],
            "p_random": out.p_random[i],
        }
        if gt is not None:
            r["gt_pose"] = gt[i]
            r["error_xy"] = np.hypot(*(out.pose[i, :, :2] - gt[i, :, :2]).T)
            r["scores"] = _scores(x["t"], out.pose[i], gt[i], x["valid"][i], initial == "global")
            # For comparison: the odometry alone, started at the true first pose.
            e_odom = np.hypot(*(_anchored(x["odom"][i], gt[i, 0])[:, :2] - gt[i, :, :2]).T)[x["valid"][i]]
            r["scores"]["odometry_error_median_m"] = float(np.median(e_odom))
            r["scores"]["odometry_error_p99_m"] = float(np.percentile(e_odom, 99))
        robots.append(r)
    return robots


def run_localize(
    log_path,
    map_path,
    out_dir,
    initial="global",
    params_path=None,
    particles: int | None = None,
    contacts: str = "mixed",
    band_height: int = 5,
    progress=None,
    observer_params=None,
    band_reduce: str = "median",
) -> dict:
    """Localize the robots of the log at `log_path` on the map at `map_path`; write `out_dir`."""
    from jaxquad.io import TumTrajectory, load_log, load_map, write_json, write_tum
    from jaxquad.io.atomic import atomic_dir, atomic_open, check_output_dir

    check_output_dir(out_dir, kind=SUMMARY_KIND)
    lp = load_params(params_path, max_particles=particles)
    occ = load_map(map_path)
    log = load_log(log_path)
    robots = localize_log(log, occ, lp, initial, contacts, band_height, progress, observer_params, band_reduce)
    summary = {
        "kind": SUMMARY_KIND,
        "log": str(log_path),
        "map": str(map_path),
        "params_file": str(params_path or DEFAULTS_FILE),
        "params": dataclasses.asdict(lp),
        "initial": initial if isinstance(initial, str) else list(initial),
        "contacts": contacts,
        "observer_params": None if observer_params is None else str(observer_params),
        "band_height_px": band_height,
        "band_reduce": band_reduce,
        "robots": [],
    }
    with atomic_dir(out_dir) as tmp:
        for r in robots:
            pose = r["pose"]
            q = np.stack([np.zeros(len(pose)), np.zeros(len(pose)), np.sin(pose[:, 2] / 2), np.cos(pose[:, 2] / 2)], 1)
            p = np.concatenate([pose[:, :2], np.zeros((len(pose), 1))], 1)
            write_tum(tmp / f"{r['name']}.tum", TumTrajectory(r["t"], p, q))
            with atomic_open(tmp / f"{r['name']}.npz") as f:
                np.savez(f, **{k: v for k, v in r.items() if k not in ("name", "scores")})
            std = np.sqrt(np.clip(np.diagonal(r["cov"][-1]), 0, None))
            summary["robots"].append(
                {
                    "name": r["name"],
                    "scans": int(len(pose)),
                    "updates": int(r["updated"].sum()),
                    "resamples": int(r["resampled"].sum()),
                    "final_pose": pose[-1].tolist(),
                    "final_std": std.tolist(),
                    **({"scores": r["scores"]} if "scores" in r else {}),
                }
            )
        write_json(tmp / "summary.json", summary)
    return summary


__all__ = [
    "CONVERGED_M",
    "SUMMARY_KIND",
    "field_of_map",
    "localize_log",
    "log_inputs",
    "localize_scans",
    "run_localize",
]
