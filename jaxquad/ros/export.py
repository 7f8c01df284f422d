"""A results folder as a ROS bag for RViz and Foxglove.

Read from DIR: every `<name>.tum` trajectory (the `jaxquad estimate` output, ground truth, and the
TUM files of later odometry/SLAM/localization runs), `<name>.npz` beside it (estimate's twists),
`<name>_scans.npz` (estimate's scans) and every map YAML (PGM + YAML, jaxquad.io.load_map).

Written, with `F` the world frame (`--frame`, default `odom`) and `<name>` the file stem:

| topic | type | content |
|---|---|---|
| `/<name>/odom` | nav_msgs/Odometry | every pose, `F` -> `<name>/base_link`; base-frame twist if `<name>.npz` has it |
| `/<name>/path` | nav_msgs/Path | the whole trajectory, once, at its first stamp |
| `/tf` | tf2_msgs/TFMessage | `F` -> `<name>/base_link` per pose, `<name>/base_link` -> `<name>/base_level` per scan |
| `/<name>/scan_stabilized` | sensor_msgs/LaserScan | stabilized scans in `<name>/base_level` (level, yaw only) |
| `/<name>/scan_baseline` | sensor_msgs/LaserScan | fixed-row scans in `<name>/base_link` |
| `/map` or `/map/<stem>` | nav_msgs/OccupancyGrid | each map once, first stamp (-1 unknown, 0..100, bottom row first) |

Scan beams are resampled to equal angle steps (the nearest image column's range; the columns'
bearings are not equally spaced); +inf = no return. The camera's offset on the base is not in the
results folder, so scans are placed at the base origin. One map goes to `/map`, several to `/map/<stem>`.
"""

from __future__ import annotations

import os
import re
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from jaxquad.ros.messages import FORMATS, bag_writer, seconds_to_ns

_SCAN_KEYS = ("depth_t", "ranges_stabilized", "ranges_baseline", "bearings", "roll", "pitch")


def _topic_name(stem: str) -> str:
    name = re.sub(r"[^A-Za-z0-9_]", "_", stem)
    return name if name[:1].isalpha() else f"t_{name}"


def find_results(folder: str | os.PathLike) -> dict:
    """{'trajectories': {name: (TumTrajectory, npz or None)}, 'scans': {name: npz}, 'maps': {stem: OccupancyMap}}."""
    import yaml

    from jaxquad.io import load_map, read_npz, read_tum

    folder = Path(folder)
    if not folder.is_dir():
        raise FileNotFoundError(f"results folder not found: {folder}")
    found: dict = {"trajectories": {}, "scans": {}, "maps": {}}
    for tum in sorted(folder.glob("*.tum")):
        npz = tum.with_suffix(".npz")
        extra = read_npz(npz, "twists") if npz.is_file() else None
        found["trajectories"][_topic_name(tum.stem)] = (read_tum(tum), extra)
    for scans in sorted(folder.glob("*_scans.npz")):
        arrays = read_npz(scans, "scans")
        missing = [k for k in _SCAN_KEYS if k not in arrays]
        if missing:
            raise ValueError(f"scans {scans}: missing key(s) {missing} (as `jaxquad estimate` writes them)")
        found["scans"][_topic_name(scans.name[: -len("_scans.npz")])] = arrays
    for path in sorted(folder.glob("*.yaml")):
        try:
            meta = yaml.safe_load(path.read_text())
        except (yaml.YAMLError, UnicodeDecodeError):
            continue  # not a map (maps are read strictly below)
        if isinstance(meta, dict) and {"image", "resolution", "origin"} <= set(meta):
            found["maps"][_topic_name(path.stem)] = load_map(path)
    if not any(found.values()):
        raise ValueError(f"{folder}: nothing to export (no .tum trajectories, *_scans.npz or map .yaml files)")
    return found


def uniform_beams(ranges: np.ndarray, bearings: np.ndarray) -> tuple[np.ndarray, float, float]:
    """(F, W) ranges over bearings -> ranges over W equally spaced angles (nearest column), angle_min, step."""
    lo, hi = float(bearings.min()), float(bearings.max())
    angles = np.linspace(lo, hi, bearings.size)
    nearest = np.argmin(np.abs(bearings[None, :] - angles[:, None]), axis=1)
    return ranges[:, nearest], lo, (hi - lo) / max(bearings.size - 1, 1)


def _odometry(m, t_ns, name, frame, p, q_wxyz, v, w):
    ty = m.types
    twist = ty["geometry_msgs/msg/Twist"](linear=m.vector3(v), angular=m.vector3(w))
    return ty["nav_msgs/msg/Odometry"](
        header=m.header(t_ns, frame),
        child_frame_id=f"{name}/base_link",
        pose=ty["geometry_msgs/msg/PoseWithCovariance"](pose=m.pose(p, q_wxyz), covariance=np.zeros(36)),
        twist=ty["geometry_msgs/msg/TwistWithCovariance"](twist=twist, covariance=np.zeros(36)),
    )


def _trajectory_messages(m, name, traj, extra, frame):
    ty, out = m.types, []
    ns = seconds_to_ns(traj.t_s)
    q = traj.q_world_body_xyzw[:, [3, 0, 1, 2]]
    twist = extra is not None and "v_base" in extra and len(extra["v_base"]) == len(ns)
    poses = []
    for i, t in enumerate(ns):
        v, w = (extra["v_base"][i], extra["omega_base"][i]) if twist else (np.zeros(3), np.zeros(3))
        out.append(
            (
                t,
                f"/{name}/odom",
                "nav_msgs/msg/Odometry",
                _odometry(m, t, name, frame, traj.p_world_body[i], q[i], v, w),
            )
        )
        tf = m.transform(t, frame, f"{name}/base_link", traj.p_world_body[i], q[i])
        out.append((t, "/tf", "tf2_msgs/msg/TFMessage", ty["tf2_msgs/msg/TFMessage"](transforms=[tf])))
        poses.append(
            ty["geometry_msgs/msg/PoseStamped"](header=m.header(t, frame), pose=m.pose(traj.p_world_body[i], q[i]))
        )
    out.append(
        (
            ns[0],
            f"/{name}/path",
            "nav_msgs/msg/Path",
            ty["nav_msgs/msg/Path"](header=m.header(ns[0], frame), poses=poses),
        )
    )
    return out


def _scan_messages(m, name, scans):
    ty, out = m.types, []
    ns = seconds_to_ns(scans["depth_t"])
    level = Rotation.from_euler("ZYX", np.stack([np.zeros_like(scans["roll"]), scans["pitch"], scans["roll"]], 1)).inv()
    q_base_level = level.as_quat()[:, [3, 0, 1, 2]]
    for key, frame in (("stabilized", f"{name}/base_level"), ("baseline", f"{name}/base_link")):
        ranges, lo, step = uniform_beams(np.asarray(scans[f"ranges_{key}"]), np.asarray(scans["bearings"]))
        finite = ranges[np.isfinite(ranges)]
        rmax = float(finite.max()) if finite.size else 0.0
        for i, t in enumerate(ns):
            msg = ty["sensor_msgs/msg/LaserScan"](
                header=m.header(t, frame),
                angle_min=lo,
                angle_max=lo + step * (ranges.shape[1] - 1),
                angle_increment=step,
                time_increment=0.0,
                scan_time=0.0,
                range_min=0.0,
                range_max=rmax,
                ranges=ranges[i].astype(np.float32),
                intensities=np.zeros(0, np.float32),
            )
            out.append((t, f"/{name}/scan_{key}", "sensor_msgs/msg/LaserScan", msg))
    for i, t in enumerate(ns):
        tf = m.transform(t, f"{name}/base_link", f"{name}/base_level", np.zeros(3), q_base_level[i])
        out.append((t, "/tf", "tf2_msgs/msg/TFMessage", ty["tf2_msgs/msg/TFMessage"](transforms=[tf])))
    return out


def _map_message(m, occ, t_ns, frame):
    ty = m.types
    rows, cols = occ.grid.shape
    x, y, yaw = occ.origin
    info = ty["nav_msgs/msg/MapMetaData"](
        map_load_time=m.time(t_ns),
        resolution=float(occ.resolution),
        width=cols,
        height=rows,
        origin=m.pose([x, y, 0.0], [np.cos(yaw / 2), 0.0, 0.0, np.sin(yaw / 2)]),
    )
    return ty["nav_msgs/msg/OccupancyGrid"](
        header=m.header(t_ns, frame), info=info, data=np.ascontiguousarray(occ.grid, np.int8).ravel()
    )


def export(folder: str | os.PathLike, out: str | os.PathLike, fmt: str = "mcap", frame: str = "odom") -> dict:
    """Write the results in `folder` as a bag at `out` (replaced whole on success); returns topic counts."""
    from jaxquad.io.atomic import atomic_path, check_output_dir, check_output_file

    if fmt not in FORMATS:
        raise ValueError(f"--format {fmt!r} is not one of {', '.join(FORMATS)}")
    if (fmt == "ros1") != (Path(out).suffix == ".bag"):
        raise ValueError(f"--bag {out}: a ROS 1 bag is a .bag file; a ROS 2 bag is a folder (no .bag suffix)")
    (check_output_file if fmt == "ros1" else check_output_dir)(out, "--bag")
    bag = Path(out)
    if fmt != "ros1" and bag.is_dir() and any(bag.iterdir()) and not (bag / "metadata.yaml").is_file():
        raise ValueError(f"--bag {out} is a non-empty folder that holds no earlier ROS 2 bag; choose another")
    found = find_results(folder)
    counts: dict[str, int] = {}
    with atomic_path(out) as tmp, bag_writer(tmp, fmt) as w:
        records = []
        for name, (traj, extra) in found["trajectories"].items():
            records += _trajectory_messages(w.msgs, name, traj, extra, frame)
        for name, scans in found["scans"].items():
            records += _scan_messages(w.msgs, name, scans)
        t0 = min((r[0] for r in records), default=0)
        single = len(found["maps"]) == 1
        for stem, occ in found["maps"].items():
            topic = "/map" if single else f"/map/{stem}"
            records.append((t0, topic, "nav_msgs/msg/OccupancyGrid", _map_message(w.msgs, occ, t0, frame)))
        records.sort(key=lambda r: r[0])
        for t_ns, topic, msgtype, msg in records:
            w.write(topic, msgtype, t_ns, msg)
            counts[topic] = counts.get(topic, 0) + 1
    return {"bag": str(out), "format": fmt, "frame": frame, "topics": dict(sorted(counts.items()))}
