"""2D laser logs for SLAM: CARMEN text logs and the `.npz` laser-log form, both read into a `LaserLog`.

CARMEN (one message per line, fields separated by blanks, `#` lines are comments; `.gz` is read too):

    FLASER n r_1 .. r_n x y theta odom_x odom_y odom_theta ipc_timestamp ipc_hostname logger_timestamp
    ROBOTLASER1 laser_type start_angle field_of_view angular_resolution maximum_range accuracy
        remission_mode n r_1 .. r_n m e_1 .. e_m laser_x laser_y laser_theta robot_x robot_y robot_theta
        tv rv forward_safety_dist side_safety_dist turn_axis ipc_timestamp ipc_hostname logger_timestamp
    ODOM x y theta tv rv accel ipc_timestamp ipc_hostname logger_timestamp

Scans come from ROBOTLASER1 lines when the log has any, else from FLASER lines (logs that carry both
describe the same scans twice). FLASER lines hold no angles: the beams are taken to span
`flaser_fov_deg` (180 deg by default, the front SICK of the classic logs) counter-clockwise from
-fov/2, at fov/(n - 1) per beam when n is odd (both edges measured: 181, 361 beams) and at fov/n
when n is even (180, 360 beams). A ROBOTLASER1 beam i is at start_angle + i angular_resolution, and
its readings at or beyond maximum_range become +inf (no return); FLASER readings are kept as they
are (a log's no-return value, e.g. 81.91 m, is then left out by the matcher's range_max). Each
scan's odometry pose is the one its line records (FLASER's odom_x odom_y odom_theta, ROBOTLASER1's
robot pose); ODOM lines are kept as the log's odometry stream (`odom_t`, `odom_xytheta`). Every other
upper-case tag (PARAM, SYNC, TRUEPOS, RAWLASER1-4, RLASER, ...) is skipped; anything else is an
error naming the file and line.

Real logs are not always in time order (clock jitter, a stray stamp, a log rewritten by a SLAM program
such as the `ODOM ... 0 host 0` lines of corrected logs). The stamps in order are the longest
non-decreasing run of them (`in_time_order`), so that one stray stamp, early or late, is the one left
out. The scans are taken in the file's order, each keeping its own `ipc_timestamp`; a scan whose stamp
is out of order gets the SLAM's clock of the scan before it (`scan_clock`). ODOM lines out of order
are dropped. Some logs repeat stamps: written with six digits (`1.13486e+09`: 10,000 s a step) or
as zeros. A run of equal stamps is spread evenly up to the next stamp (`untie_stamps`) in the trajectories
written and in the SLAM's clock, so that each scan has a time of its own; when most stamps repeat, the
clock steps `UNTIMED_DT` (1 s) per scan instead and the node rule goes by travel alone (`scan_clock`).

`.npz` laser log (float64 arrays):

| key | shape | unit / meaning | |
|---|---|---|---|
| `scan_t` | (S,) | s, each scan's own stamp, in the scans' order (see above) | required |
| `ranges` | (S, B) | m along each beam; +inf = no return, NaN or <= 0 = invalid | required |
| `bearings` | (B,) | rad, beam angles in the laser frame, counter-clockwise from +x | required |
| `odom_t` | (K,) | s, non-decreasing | required |
| `odom_xytheta` | (K, 3) | odometry pose of the robot base x, y (m), theta (rad) | required |
| `scan_odom_xytheta` | (S, 3) | odometry pose recorded with each scan | optional |
| `T_base_laser_xytheta` | (3,) | laser pose in the base frame (zeros if absent) | optional |
| `gt_xytheta` | (S, 3) | ground-truth base pose at each scan | optional |
"""

from __future__ import annotations

import bisect
import dataclasses
import gzip
import math
import os
import re
from pathlib import Path

import numpy as np

from jaxquad.io.atomic import atomic_open
from jaxquad.io.files import read_npz
from jaxquad.kernels.lie import SE2

_TAG = re.compile(r"[A-Z][A-Z0-9_]*$")
# Seconds between scans of a log whose stamps carry no time at all (all equal): the node rule then goes by travel.
UNTIMED_DT = 1.0
_REQUIRED = ("scan_t", "ranges", "bearings", "odom_t", "odom_xytheta")
_OPTIONAL = ("scan_odom_xytheta", "T_base_laser_xytheta", "gt_xytheta")


@dataclasses.dataclass(frozen=True)
class LaserLog:
    """A 2D laser log: scans, odometry and optional ground truth (see the module docstring for units)."""

    scan_t: np.ndarray
    ranges: np.ndarray
    bearings: np.ndarray
    odom_t: np.ndarray
    odom_xytheta: np.ndarray
    scan_odom_xytheta: np.ndarray | None = None
    T_base_laser_xytheta: np.ndarray = dataclasses.field(default_factory=lambda: np.zeros(3))
    gt_xytheta: np.ndarray | None = None

    def __post_init__(self):
        validate_laser_log(self, "LaserLog")

    @property
    def n_scans(self) -> int:
        return self.ranges.shape[0]


def validate_laser_log(log: LaserLog, where: str) -> None:
    """Shapes, finiteness and time order; one-line ValueError naming `where` and the key."""
    for k in _REQUIRED + _OPTIONAL:
        v = getattr(log, k)
        if v is not None:
            object.__setattr__(log, k, np.asarray(v, np.float64))
    S, B, K = log.scan_t.shape[0], log.bearings.shape[0], log.odom_t.shape[0]
    shapes = dict(
        scan_t=(S,),
        ranges=(S, B),
        bearings=(B,),
        odom_t=(K,),
        odom_xytheta=(K, 3),
        scan_odom_xytheta=(S, 3),
        T_base_laser_xytheta=(3,),
        gt_xytheta=(S, 3),
    )
    for k, shape in shapes.items():
        v = getattr(log, k)
        if v is None:
            continue
        if v.shape != shape:
            raise ValueError(f"{where}: key '{k}' has shape {v.shape}, expected {shape}")
        if k != "ranges" and not np.all(np.isfinite(v)):
            raise ValueError(f"{where}: key '{k}' has non-finite values")
    if S == 0 or B == 0:
        raise ValueError(f"{where}: no scans (key 'ranges' has shape {log.ranges.shape})")
    if np.any(np.diff(log.odom_t) < 0):
        raise ValueError(f"{where}: key 'odom_t' is not non-decreasing")


def _floats(tokens: list[str], where: str) -> list[float]:
    try:
        return [float(t) for t in tokens]
    except ValueError as e:
        raise ValueError(f"{where}: {e}") from None


def _count(token: str, where: str, what: str) -> int:
    if not token.isdigit():
        raise ValueError(f"{where}: {what} must be a non-negative integer, got {token!r}")
    return int(token)


def _need(tokens: list[str], n: int, where: str, tag: str) -> None:
    if len(tokens) < n:
        raise ValueError(f"{where}: {tag} line has {len(tokens)} fields, expected {n}")


def flaser_bearings(n: int, fov_deg: float = 180.0) -> np.ndarray:
    """FLASER beam angles (rad): from -fov/2 counter-clockwise, both edges measured when n is odd."""
    fov = math.radians(fov_deg)
    step = fov / (n - 1) if n % 2 == 1 and n > 1 else fov / n
    return -fov / 2 + step * np.arange(n)


def _base_laser(robot_xytheta, laser_xytheta) -> np.ndarray:
    """Laser pose in the base frame from the two world poses a ROBOTLASER1 line records."""
    T = SE2.from_xy_theta(*robot_xytheta).inverse() @ SE2.from_xy_theta(*laser_xytheta)
    return np.array([*np.asarray(T.translation()), float(T.rotation().as_radians())])


def _open_text(path: Path):
    return gzip.open(path, "rt") if path.suffix == ".gz" else open(path)


def read_carmen(path: str | os.PathLike, flaser_fov_deg: float = 180.0) -> LaserLog:
    """A CARMEN log's scans and odometry (see the module docstring for what is read and assumed)."""
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"{path}: no such file")
    scans = {"FLASER": [], "ROBOTLASER1": []}  # (t, ranges, odometry pose, bearings, laser pose, line)
    odom = []
    try:
        with _open_text(path) as f:
            for lineno, line in enumerate(f, 1):
                tokens = line.split()
                if not tokens or tokens[0].startswith("#"):
                    continue
                where, tag = f"{path}:{lineno}", tokens[0]
                if tag == "FLASER":
                    _need(tokens, 2, where, tag)
                    n = _count(tokens[1], where, "num_readings")
                    _need(tokens, n + 11, where, tag)
                    v = _floats(tokens[2 : n + 9], where)
                    bearings = flaser_bearings(n, flaser_fov_deg)
                    scans[tag].append((v[n + 6], v[:n], v[n + 3 : n + 6], bearings, None, where))
                elif tag == "ROBOTLASER1":
                    _need(tokens, 9, where, tag)
                    n = _count(tokens[8], where, "num_readings")
                    _need(tokens, n + 10, where, tag)
                    m = _count(tokens[n + 9], where, "num_remissions")
                    _need(tokens, n + m + 24, where, tag)
                    head = _floats(tokens[2:6], where)
                    r = np.asarray(_floats(tokens[9 : 9 + n], where))
                    r = np.where(r >= head[3], np.inf, r)  # at or beyond maximum_range: no return
                    tail = _floats(tokens[n + m + 10 : n + m + 22], where)
                    bearings = head[0] + head[2] * np.arange(n)
                    scans[tag].append((tail[11], r, tail[3:6], bearings, tail[0:3], where))
                elif tag == "ODOM":
                    _need(tokens, 8, where, tag)
                    v = _floats(tokens[1:8], where)
                    odom.append((v[6], v[0:3]))
                elif not _TAG.match(tag):
                    raise ValueError(f"{where}: not a CARMEN message (first field {tag!r})")
    except (UnicodeDecodeError, EOFError, gzip.BadGzipFile) as e:
        raise ValueError(f"{path}: not a text CARMEN log ({type(e).__name__}: {e})") from None
    tag = "ROBOTLASER1" if scans["ROBOTLASER1"] else "FLASER"
    rows = scans[tag]
    if not rows:
        raise ValueError(f"{path}: no FLASER or ROBOTLASER1 scans")
    n0, bearings0 = len(rows[0][1]), rows[0][3]
    for _, r, _, b, _, where in rows:
        if len(r) != n0 or not np.allclose(b, bearings0):
            raise ValueError(f"{where}: {tag} scan has {len(r)} beams or other angles than the first scan ({n0})")
    scan_t = np.array([row[0] for row in rows])
    scan_odom = np.array([row[2] for row in rows], np.float64)
    if odom:
        odom_t, odom_xy = np.array([o[0] for o in odom]), np.array([o[1] for o in odom])
    else:
        odom_t, odom_xy = scan_t, scan_odom
    keep = in_time_order(odom_t)
    odom_t, odom_xy = odom_t[keep], odom_xy[keep]
    offset = np.zeros(3) if rows[0][4] is None else _base_laser(rows[0][2], rows[0][4])
    try:
        return LaserLog(
            scan_t, np.array([row[1] for row in rows], np.float64), bearings0, odom_t, odom_xy, scan_odom, offset
        )
    except ValueError as e:
        raise ValueError(f"{path}: {str(e).removeprefix('LaserLog: ')}") from None


def read_laser_npz(path: str | os.PathLike) -> LaserLog:
    """A `.npz` laser log (keys in the module docstring); unknown keys are ignored."""
    path = Path(path)
    z = read_npz(path, "laser log")
    missing = [k for k in _REQUIRED if k not in z]
    if missing:
        raise ValueError(f"{path}: missing key '{missing[0]}'")
    fields = {k: z[k] for k in _REQUIRED + _OPTIONAL if k in z}
    try:
        return LaserLog(**fields)
    except ValueError as e:
        raise ValueError(f"{path}: {str(e).removeprefix('LaserLog: ')}") from None


def save_laser_npz(path: str | os.PathLike, log: LaserLog) -> Path:
    """Write a `LaserLog` as a `.npz` laser log, atomically."""
    arrays = {k: getattr(log, k) for k in _REQUIRED + _OPTIONAL if getattr(log, k) is not None}
    with atomic_open(path, "wb") as f:
        np.savez(f, **arrays)
    return Path(path)


def in_time_order(t: np.ndarray) -> np.ndarray:
    """Boolean mask of the longest non-decreasing subsequence of stamps `t` (the first such, O(n log n))."""
    t = np.asarray(t, np.float64)
    tails, tail_idx, prev = [], [], np.full(t.size, -1)
    for i, v in enumerate(t):
        k = bisect.bisect_right(tails, v)
        if k == len(tails):
            tails.append(v)
            tail_idx.append(i)
        else:
            tails[k], tail_idx[k] = v, i
        prev[i] = tail_idx[k - 1] if k else -1
    keep = np.zeros(t.size, bool)
    i = tail_idx[-1] if tail_idx else -1
    while i >= 0:
        keep[i] = True
        i = prev[i]
    return keep


def untie_stamps(t: np.ndarray, untimed_dt: float = UNTIMED_DT) -> np.ndarray:
    """Stamps `t` (S,) with each run of equal consecutive stamps spread evenly up to the stamp after it: a
    run of k scans at c followed by c' > c becomes c, c + (c' - c) / k, ... A run followed by no greater stamp
    (the last, or one before a stray stamp) takes the median per-scan step of the runs that spread, or
    `untimed_dt` s when none did (a log whose stamps are all equal). Unique stamps are returned as they are."""
    t = np.asarray(t, np.float64)
    if t.size < 2:
        return t.copy()
    first = np.r_[True, t[1:] != t[:-1]]
    starts = np.flatnonzero(first)
    group = np.cumsum(first) - 1
    base = t[starts]
    after = np.r_[base[1:], np.nan]
    with np.errstate(invalid="ignore"):
        spreads = after > base
    step = np.where(spreads, (after - base) / np.diff(np.r_[starts, t.size]), np.nan)
    fallback = float(np.median(step[spreads])) if spreads.any() else untimed_dt
    step = np.where(spreads, step, fallback)
    return base[group] + (np.arange(t.size) - starts[group]) * step[group]


def repeated_stamps(t: np.ndarray) -> int:
    """How many of stamps `t` equal the one before."""
    t = np.asarray(t, np.float64)
    return int(np.sum(t[1:] == t[:-1]))


def scan_clock(scan_t: np.ndarray, untimed_dt: float = UNTIMED_DT) -> np.ndarray:
    """The SLAM's clock at each scan: its stamp (repeated stamps spread by `untie_stamps`) where the stamps
    are in order (`in_time_order`), else the clock of the scan before (the first in-order stamp before any).
    When most stamps repeat the one before, they do not time the scans (a log written with six digits holds
    hundreds of scans at one stamp): the scans are then clocked `untimed_dt` s apart from the first stamp."""
    t = np.asarray(scan_t, np.float64)
    if 2 * repeated_stamps(t) > t.size:
        return (t[0] if np.isfinite(t[0]) else 0.0) + untimed_dt * np.arange(t.size)
    t = untie_stamps(t, untimed_dt)
    keep = in_time_order(t)
    if not keep.any():
        return t
    held = np.maximum.accumulate(np.where(keep, t, -np.inf))
    return np.where(np.isfinite(held), held, t[keep][0])


def load_laser_log(path: str | os.PathLike, flaser_fov_deg: float = 180.0) -> LaserLog:
    """`.npz` laser logs by their suffix, anything else as a CARMEN log."""
    if Path(path).suffix == ".npz":
        return read_laser_npz(path)
    return read_carmen(path, flaser_fov_deg)
