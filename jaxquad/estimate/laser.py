"""What 2D laser consumers (localization, SLAM) read from a robot log: the estimator's leg-inertial
odometry, its scans and its leg-odometry twist, all at the depth frames.

The leg-odometry twist is put in the plane: with R_level_base(roll, pitch) the base-to-levelled
rotation, (vx, vy) = rows 0-1 of R_level_base v_base and the yaw rate = row 2 of R_level_base
omega_base; its covariance is R cov_v_base R^T (rows 0-1) and `yaw_rate_std`^2 (the estimator
reports no yaw-rate covariance: the gyro's error, bias included, is a setting).
"""

from __future__ import annotations

from collections.abc import Mapping

import jax
import jax.numpy as jnp
import numpy as np

from jaxquad.estimate.scans import frame_samples, log_scans
from jaxquad.kernels.lie import R_level_base, roll_pitch, yaw_of
from jaxquad.kernels.scan import BAND_REDUCTIONS

SCAN_KINDS = ("stabilized", "baseline", "level")


def pose2d(p: np.ndarray, q_wxyz: np.ndarray) -> np.ndarray:
    """(x, y, yaw) rows of positions (..., 3) and w x y z quaternions (..., 4)."""
    return np.concatenate([p[..., :2], np.asarray(yaw_of(jnp.asarray(q_wxyz)))[..., None]], -1)


def planar_twist(q_wxyz, v_base, omega_base, cov_v_base, yaw_rate_std):
    """One sample's leg-odometry twist in the plane, (vx, vy, yaw rate) and its 3x3 covariance (module doc)."""
    R = R_level_base(*roll_pitch(q_wxyz))
    cov = jnp.zeros((3, 3)).at[:2, :2].set(R[:2] @ cov_v_base @ R[:2].T).at[2, 2].set(yaw_rate_std**2)
    return jnp.concatenate([(R @ v_base)[:2], (R @ omega_base)[2:]]), cov


@jax.jit
def _planar_twist(q_wxyz, v_base, omega_base, cov_v_base, yaw_rate_std):
    return jax.vmap(planar_twist, in_axes=(0, 0, 0, 0, None))(q_wxyz, v_base, omega_base, cov_v_base, yaw_rate_std)


ODOMETRY_KINDS = ("lo", "vo")


def _fleet_axis(log: Mapping, key: str) -> np.ndarray:
    """A per-robot array with a leading robot axis (a single robot's log gets one)."""
    return np.asarray(log[key]) if "fallen" in log else np.asarray(log[key])[None]


def scan_ranges(
    log: Mapping,
    est,
    scans: str = "stabilized",
    band_height: int = 5,
    range_min: float = 0.2,
    range_max: float = 8.0,
    band_reduce: str = "median",
) -> tuple[np.ndarray, np.ndarray]:
    """ranges (N, F, W) m of the `scans` kind at the depth frames, sliced with the estimator's attitude
    `est.q_world_base`, and their bearings (W,) rad; `band_reduce` as `jaxquad.kernels.scan` says
    (the median of the band by default; "min" is the paper's rule, biased short by noisy depth)."""
    if scans not in SCAN_KINDS:
        raise ValueError(f"scans must be one of {SCAN_KINDS}, got {scans!r}")
    t, depth_t = np.asarray(log["t"], np.float64), np.asarray(log["depth_t"], np.float64)
    depth = _fleet_axis(log, "depth")
    ranges, bearings = [], None
    for i in range(depth.shape[0]):
        sc = log_scans(
            depth[i],
            depth_t,
            np.asarray(log["K"]),
            t,
            est.q_world_base[i],
            band_height,
            range_min,
            range_max,
            level=scans == "level",
            band_reduce=band_reduce,
        )
        r, b = {
            "stabilized": (sc.ranges_stabilized, sc.bearings),
            "baseline": (sc.ranges_baseline, sc.bearings),
            "level": (sc.ranges_level, sc.bearings_level),
        }[scans]
        ranges.append(np.asarray(r))
        bearings = np.asarray(b)
    return np.stack(ranges), bearings


def visual_odometry_2d(log: Mapping, est, robot, coupling: str = "guess+restart") -> np.ndarray:
    """(N, F, 3) x y yaw at the depth frames of the depth odometry (`jaxquad.vo`), guided by the
    estimator's leg odometry as `coupling` says (off: the leg odometry only gives the first pose)."""
    from jaxquad.estimate.inputs import R_base_imu
    from jaxquad.vo import visual_odometry

    vo = visual_odometry(log, est.p_world_base, est.q_world_base, R_base_imu(robot), coupling)
    return pose2d(vo.p_world_base, vo.q_world_base)


def laser_inputs(
    log: Mapping,
    scans: str = "stabilized",
    contacts: str = "mixed",
    band_height: int = 5,
    range_min: float = 0.2,
    range_max: float = 8.0,
    observer_params=None,
    yaw_rate_std: float = 0.02,
    progress=None,
    odometry: str = "lo",
    vo_coupling: str = "guess+restart",
    devices: int | None = None,
    band_reduce: str = "median",
) -> dict:
    """Per robot (leading axis N) at the F depth frames: t (F,) s, odom (N, F, 3) x y yaw, ranges (N, F, W)
    m of the `scans` kind, bearings (W,) rad, T_base_laser (3,), valid (N, F), lo_twist (N, F, 3) planar
    leg-odometry twist, lo_twist_cov (N, F, 3, 3), lo_valid (N, F) and, with ground truth, gt (N, F, 3).
    odom: the leg-inertial odometry (`odometry="lo"`) or the depth odometry (`"vo"`, guided by the leg
    odometry as `vo_coupling` says; the depth odometry runs on one device). `devices`: the estimator's robots
    are split over that many devices (default all). `observer_params`: a contact-observer file (as `jaxquad estimate
    --params`). The log is checked first (depth, joints, what the contact source needs); then
    `progress(0, F)` says so."""
    from jaxquad.estimate.inputs import check_log
    from jaxquad.estimate.run import estimate_log
    from jaxquad.estimate.run import load_params as load_observer_params
    from jaxquad.robots import load
    from jaxquad.vo import COUPLINGS

    if scans not in SCAN_KINDS:
        raise ValueError(f"scans must be one of {SCAN_KINDS}, got {scans!r}")
    if band_reduce not in BAND_REDUCTIONS:
        raise ValueError(f"band_reduce must be one of {BAND_REDUCTIONS}, got {band_reduce!r}")
    if odometry not in ODOMETRY_KINDS or vo_coupling not in COUPLINGS:
        raise ValueError(
            f"odometry must be one of {ODOMETRY_KINDS} and vo_coupling one of {COUPLINGS}, "
            f"got {odometry!r}, {vo_coupling!r}"
        )
    if "depth" not in log:
        raise ValueError("the log has no depth images: 2D scans are sliced from them")
    robot = load(str(np.asarray(log["robot"])))
    check_log(robot, log, contacts)
    obs = load_observer_params(observer_params, len(robot.foot_names), contacts)
    if progress is not None:
        progress(0, len(log["depth_t"]))
    _, _, est = estimate_log(log, contacts, obs, robot, devices=devices)
    x = leg_laser_inputs(log, est, scans, band_height, range_min, range_max, yaw_rate_std, band_reduce)
    if odometry == "vo":
        x["odom"] = visual_odometry_2d(log, est, robot, vo_coupling)
    return x


def leg_laser_inputs(
    log: Mapping,
    est,
    scans: str = "stabilized",
    band_height: int = 5,
    range_min: float = 0.2,
    range_max: float = 8.0,
    yaw_rate_std: float = 0.02,
    band_reduce: str = "median",
) -> dict:
    """`laser_inputs` from the estimator's output `est` on `log` (`jaxquad.estimate.estimate_log`), with
    the leg-inertial odometry as odom: what variants of one log share (see `jaxquad.slam.variants`)."""
    t, depth_t = np.asarray(log["t"], np.float64), np.asarray(log["depth_t"], np.float64)
    k = frame_samples(t, depth_t)
    n = est.p_world_base.shape[0]
    ranges, bearings = scan_ranges(log, est, scans, band_height, range_min, range_max, band_reduce)
    twist, twist_cov = _planar_twist(
        jnp.asarray(est.q_world_base[:, k].reshape(-1, 4), jnp.float32),
        jnp.asarray(est.v_base[:, k].reshape(-1, 3), jnp.float32),
        jnp.asarray(est.omega_base[:, k].reshape(-1, 3), jnp.float32),
        jnp.asarray(est.cov_v_base[:, k].reshape(-1, 3, 3), jnp.float32),
        jnp.asarray(yaw_rate_std, jnp.float32),
    )
    T_base_camera = np.asarray(log["T_base_camera"])
    valid = np.asarray(log["valid"])[:, k] if "valid" in log else np.ones((n, k.size), bool)
    # A sample without stance holds the last twist and keeps integrating: only a fall ends the odometry.
    lo_valid = valid & ~np.asarray(est.flags.fallen)[:, k]
    out = {
        "t": depth_t,
        "odom": pose2d(est.p_world_base[:, k], est.q_world_base[:, k]),
        "ranges": ranges,
        "bearings": bearings,
        # The scans are levelled along the base's heading: the laser sits at the camera's x y, yaw 0.
        "T_base_laser": np.array([T_base_camera[0, 3], T_base_camera[1, 3], 0.0]),
        "valid": valid,
        "lo_twist": np.asarray(twist).reshape(n, -1, 3),
        "lo_twist_cov": np.asarray(twist_cov).reshape(n, -1, 3, 3),
        "lo_valid": lo_valid,
    }
    if "gt_pose" in log:
        g = _fleet_axis(log, "gt_pose")
        out["gt"] = pose2d(g[:, k, :3], g[:, k, 3:])
    return out


def every_nth_frame(x: dict, every: int) -> dict:
    """`laser_inputs` output with every `every`-th depth frame kept (a lower scan rate)."""
    shared = ("bearings", "T_base_laser")
    return {k: v if k in shared else v[::every] if k == "t" else v[:, ::every] for k, v in x.items()}
