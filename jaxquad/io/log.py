"""Robot logs: one `.npz` per run, recorded on a robot or written by the simulator.

| key | shape | unit / meaning | |
|---|---|---|---|
| `t` | (T,) | s, strictly increasing | required |
| `robot` | () str | robot name (`go2`, `badger`) or path of its MJCF | required |
| `joint_names` | (nj,) str | joint order of every joint array | required |
| `q` | (T, nj) | joint positions, rad | required |
| `qd` | (T, nj) | joint velocities, rad/s | optional |
| `tau` | (T, nj) | joint torques, N m | optional |
| `gyro` | (T, 3) | angular velocity in the IMU frame, rad/s | required |
| `acc` | (T, 3) | specific force in the IMU frame, m/s^2 (+9.81 up at rest) | required |
| `quat_wxyz` | (T, 4) | onboard orientation estimate, world-from-base, unit | optional |
| `foot_force` | (T, 4) | foot force sensor readings, robot's foot order (raw units) | optional |
| `contact` | (T, 4) | measured foot contact flags | optional |
| `depth` | (F, H, W) | depth images, z-depth in metres, 0 = invalid | optional, with the next three |
| `depth_t` | (F,) | s, strictly increasing | with `depth` |
| `K` | (3, 3) | pinhole intrinsics (px) of the depth images | with `depth` |
| `T_base_camera` | (4, 4) | base-from-camera transform; optical frame: x right, y down, z forward | with `depth` |
| `gt_pose` | (T, 7) | ground-truth base pose x y z (m) qw qx qy qz (world-from-base) | optional |
| `gt_contact` | (T, 4) | ground-truth foot contact flags | optional |
| `gt_force` | (T, 4, 3) | ground-truth contact force on each foot, world frame, N | optional |

A fleet log (many robots of one run) adds a leading robot axis N to every per-robot key (all but
`t`, `robot`, `joint_names`, `depth_t`, `K`, `T_base_camera`) and two keys: `fallen` (N,) bool
and `valid` (N, T) bool (False from the sample where a robot fell or its state became invalid;
its later samples repeat the last valid state). `robot_log(fleet, i)` extracts robot i.
Other keys are kept as they are and not checked.
"""

from __future__ import annotations

import os
from collections.abc import Mapping
from pathlib import Path

import numpy as np

from jaxquad.io.atomic import atomic_open
from jaxquad.io.files import read_npz

REQUIRED = ("t", "robot", "joint_names", "q", "gyro", "acc")
SHARED = frozenset({"t", "robot", "joint_names", "depth_t", "K", "T_base_camera"})
_DEPTH_GROUP = ("depth", "depth_t", "K", "T_base_camera")
# Per-robot array shapes after the leading robot axis; "T" and "nj" are resolved per log.
_SHAPES: dict[str, tuple] = {
    "q": ("T", "nj"),
    "qd": ("T", "nj"),
    "tau": ("T", "nj"),
    "gyro": ("T", 3),
    "acc": ("T", 3),
    "quat_wxyz": ("T", 4),
    "foot_force": ("T", 4),
    "contact": ("T", 4),
    "depth": ("F", "H", "W"),
    "gt_pose": ("T", 7),
    "gt_contact": ("T", 4),
    "gt_force": ("T", 4, 3),
}
_MAX_GYRO = 35.0  # rad/s (2000 deg/s, the usual full scale); larger values are deg/s
_MAX_JOINT = 4.0 * np.pi  # rad; larger values are degrees
_MAX_DEPTH = 100.0  # m; larger values are millimetres
_UNIT_QUAT_TOL = 1e-3
# Sensor readings a robot can drop (NaN/inf samples are flagged and held by the estimator);
# timestamps, ground truth and calibration must be finite.
_SENSOR_KEYS = frozenset({"q", "qd", "tau", "gyro", "acc", "quat_wxyz", "foot_force", "contact"})


def _fail(name: str, message: str) -> None:
    raise ValueError(f"log {name}: {message}")


def _check_increasing(name: str, key: str, t: np.ndarray) -> None:
    if t.ndim != 1 or t.size == 0:
        _fail(name, f"'{key}' must be a non-empty 1-D array of seconds, got shape {t.shape}")
    if not np.all(np.isfinite(t)):
        _fail(name, f"'{key}' has non-finite timestamps")
    if t.size > 1 and not np.all(np.diff(t) > 0):
        i = int(np.argmin(np.diff(t) > 0))
        _fail(name, f"'{key}' is not strictly increasing (t[{i}] = {t[i]}, t[{i + 1}] = {t[i + 1]})")


def _check_unit_quat(name: str, key: str, q: np.ndarray) -> None:
    norm = np.linalg.norm(q, axis=-1)
    err = np.abs(norm[np.isfinite(norm)] - 1.0)
    if np.max(err, initial=0.0) > _UNIT_QUAT_TOL:
        _fail(name, f"'{key}' quaternions are not unit (max |norm - 1| = {np.max(err):.3g})")


def validate_log(log: Mapping[str, np.ndarray], name: str = "") -> None:
    """Raise a one-line ValueError naming the first problem of a single or fleet log."""
    missing = [k for k in REQUIRED if k not in log]
    if missing:
        _fail(name, f"missing required key(s) {missing}")
    fleet = "fallen" in log
    t = np.asarray(log["t"])
    _check_increasing(name, "t", t)
    joint_names = np.asarray(log["joint_names"])
    if joint_names.ndim != 1 or joint_names.size == 0:
        _fail(name, f"'joint_names' must be a non-empty 1-D array, got shape {joint_names.shape}")
    if np.asarray(log["robot"]).ndim != 0:
        _fail(name, "'robot' must be a single string")
    present_depth = [k for k in _DEPTH_GROUP if k in log]
    if present_depth and len(present_depth) != len(_DEPTH_GROUP):
        _fail(name, f"depth needs all of {list(_DEPTH_GROUP)}, found only {present_depth}")
    lead: tuple = ()
    if fleet:
        fallen = np.asarray(log["fallen"])
        if fallen.ndim != 1 or fallen.dtype != bool:
            _fail(name, f"'fallen' must be (N,) bool, got {fallen.dtype} {fallen.shape}")
        lead = (fallen.shape[0],)
        if "valid" not in log:
            _fail(name, "fleet log is missing 'valid' (N, T)")
        valid = np.asarray(log["valid"])
        if valid.shape != lead + t.shape or valid.dtype != bool:
            _fail(name, f"'valid' must be {lead + t.shape} bool, got {valid.dtype} {valid.shape}")
    dims = {"T": t.shape[0], "nj": joint_names.shape[0]}
    if present_depth:
        depth_t = np.asarray(log["depth_t"])
        _check_increasing(name, "depth_t", depth_t)
        dims["F"] = depth_t.shape[0]
        depth = np.asarray(log["depth"])
        if depth.ndim == 3 + len(lead):
            dims["H"], dims["W"] = depth.shape[-2:]
    for key, pattern in _SHAPES.items():
        if key not in log:
            continue
        arr = np.asarray(log[key])
        want = lead + tuple(dims.get(p, p) if isinstance(p, str) else p for p in pattern)
        if arr.shape != want:
            _fail(name, f"'{key}' has shape {arr.shape}, expected {want} ({', '.join(map(str, lead + pattern))})")
        if arr.dtype.kind not in "fiub":
            _fail(name, f"'{key}' must be numeric, got dtype {arr.dtype}")
        if key in _SENSOR_KEYS:
            if not np.any(np.isfinite(arr)):
                _fail(name, f"'{key}' has no finite reading")
        elif key != "depth" and not np.all(np.isfinite(arr)):
            _fail(name, f"'{key}' contains NaN or inf")
    for key in ("K", "T_base_camera"):
        if key in log and np.asarray(log[key]).shape != ((3, 3) if key == "K" else (4, 4)):
            _fail(name, f"'{key}' has shape {np.asarray(log[key]).shape}, expected {(3, 3) if key == 'K' else (4, 4)}")
    if present_depth:
        depth = np.asarray(log["depth"])
        if np.any(np.isnan(depth)) or np.any(depth < 0):
            _fail(name, "'depth' has NaN or negative values (invalid pixels must read 0)")
        if np.max(depth, initial=0.0) > _MAX_DEPTH:
            _fail(name, f"'depth' reaches {np.max(depth):.0f}: looks like millimetres, expected metres")
        R = np.asarray(log["T_base_camera"])[:3, :3]
        if not np.allclose(R @ R.T, np.eye(3), atol=1e-4):
            _fail(name, "'T_base_camera' rotation is not orthonormal")
    gyro_max = float(np.nanmax(np.abs(np.where(np.isfinite(log["gyro"]), log["gyro"], np.nan))))
    if gyro_max > _MAX_GYRO:
        _fail(name, f"'gyro' reaches {gyro_max:.0f}: looks like deg/s, expected rad/s")
    acc_norm = np.linalg.norm(np.asarray(log["acc"]), axis=-1)
    acc_norm = float(np.median(acc_norm[np.isfinite(acc_norm)]))
    if not 3.0 < acc_norm < 30.0:
        hint = "units of g" if 0.3 < acc_norm <= 3.0 else "gravity removed or wrong units"
        _fail(name, f"'acc' median magnitude {acc_norm:.2f} m/s^2 (expected ~9.81 specific force): {hint}?")
    q_max = float(np.nanmax(np.abs(np.where(np.isfinite(log["q"]), log["q"], np.nan))))
    if q_max > _MAX_JOINT:
        _fail(name, f"'q' reaches {q_max:.0f}: looks like degrees, expected rad")
    if "quat_wxyz" in log:
        _check_unit_quat(name, "quat_wxyz", np.asarray(log["quat_wxyz"]))
    if "gt_pose" in log:
        _check_unit_quat(name, "gt_pose[..., 3:7]", np.asarray(log["gt_pose"])[..., 3:7])


def is_fleet(log: Mapping[str, np.ndarray]) -> bool:
    return "fallen" in log


def load_log(path: str | os.PathLike) -> dict[str, np.ndarray]:
    """Read and validate a single or fleet log; a bad log raises a one-line ValueError."""
    path = Path(path)
    log = read_npz(path, "log")
    validate_log(log, str(path))
    return log


def save_log(path: str | os.PathLike, log: Mapping[str, np.ndarray], validate: bool = True) -> Path:
    """Validate and write a log atomically (temp file in the same folder, then rename).

    Arrays may be `np.memmap`s: they are streamed into the (uncompressed) archive in chunks.
    """
    path = Path(path)
    if validate:
        validate_log(log, str(path))
    with atomic_open(path, "wb") as f:
        np.savez(f, **{k: np.asarray(v) if not isinstance(v, np.ndarray) else v for k, v in log.items()})
    return path


def robot_log(fleet: Mapping[str, np.ndarray], i: int) -> dict[str, np.ndarray]:
    """Robot i of a fleet log as a single-robot log (its `valid` mask kept as (T,))."""
    if not is_fleet(fleet):
        raise ValueError("robot_log needs a fleet log (with 'fallen')")
    n = np.asarray(fleet["fallen"]).shape[0]
    if not 0 <= i < n:
        raise ValueError(f"robot index {i} out of range for a fleet of {n}")
    return {k: (v if k in SHARED else np.asarray(v)[i]) for k, v in fleet.items() if k != "fallen"}
