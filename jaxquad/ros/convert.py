"""A robot log (`.npz`, see jaxquad.io.log) from a ROS 1 or ROS 2 bag and a topics file.

The log's clock is the IMU's or the joint states' stamps (topics file `clock`), cropped to the span
where both streams have data; `t` counts from its first sample and `t_origin_s` keeps that
sample's ROS time (s). Other streams are resampled onto the clock (jaxquad.ros.resample; contact
flags always by nearest sample); clock samples with no data within `tolerance_s` are NaN, which
the estimator flags. Depth frames keep their own stamps (`depth_t`). Ground truth must cover every
clock sample.
"""

from __future__ import annotations

import os
from collections import defaultdict
from pathlib import Path

import numpy as np

from jaxquad.ros import extract
from jaxquad.ros.bag import messages, open_bag, topic_connections
from jaxquad.ros.fields import stamp_ns
from jaxquad.ros.resample import resample, resample_quat
from jaxquad.ros.topics import Topics, load_topics


class _Stream:
    """Stamps (ns) and per-key values of one role, sorted by stamp, repeated stamps dropped."""

    def __init__(self):
        self.t, self.values = [], defaultdict(list)

    def add(self, t_ns: int, values: dict) -> None:
        self.t.append(int(t_ns))
        for k, v in values.items():
            self.values[k].append(v)

    def arrays(self) -> tuple[np.ndarray, dict[str, np.ndarray]]:
        t = np.asarray(self.t, np.int64)
        order = np.argsort(t, kind="stable")
        keep = order[np.concatenate([[True], np.diff(t[order]) > 0])] if t.size else order
        return t[keep], {k: np.asarray(v)[keep] for k, v in self.values.items()}


def _tf_chain(transforms: dict, base: str, camera: str, where: str) -> np.ndarray:
    """T_base_camera from parent->child transforms {(parent, child): T_parent_child}, walked both ways."""
    edges = defaultdict(list)
    for (parent, child), T in transforms.items():
        edges[parent].append((child, T))
        edges[child].append((parent, np.linalg.inv(T)))
    found, todo = {base: np.eye(4)}, [base]
    while todo:
        frame = todo.pop()
        for nxt, T in edges[frame]:
            if nxt not in found:
                found[nxt] = found[frame] @ T
                todo.append(nxt)
    if camera not in found:
        frames = ", ".join(sorted(edges)) or "none"
        raise ValueError(f"{where}: no transform chain from {base!r} to {camera!r} (frames: {frames})")
    return found[camera]


def _transform(msg) -> tuple[tuple[str, str], np.ndarray]:
    from scipy.spatial.transform import Rotation

    tr, rot = msg.transform.translation, msg.transform.rotation
    T = np.eye(4)
    T[:3, :3] = Rotation.from_quat([rot.x, rot.y, rot.z, rot.w]).as_matrix()
    T[:3, 3] = tr.x, tr.y, tr.z
    return (msg.header.frame_id.lstrip("/"), msg.child_frame_id.lstrip("/")), T


def read_bag(bag: str | os.PathLike, topics: Topics, joint_names, n_feet: int) -> dict:
    """Every role's stream out of the bag: {role: _Stream} plus 'K', 'image_size', 'transforms', 'frame'."""
    streams = defaultdict(_Stream)
    info: dict = {"transforms": {}, "frame": None}
    joints = extract.JointReader(topics, joint_names)
    with open_bag(bag, topics.types) as reader:
        by_topic = defaultdict(list)
        conns = []
        for role, entry in topics.roles.items():
            if role == "T_base_camera" and "matrix" in entry:
                continue
            cs = topic_connections(reader, bag, entry["topic"], role, entry.get("type"))
            by_topic[entry["topic"]].append(role)
            conns += [c for c in cs if c not in conns]
        for conn, t_recv, msg in messages(reader, bag, conns):
            t_ns = stamp_ns(msg, t_recv, topics.stamp)
            for role in by_topic[conn.topic]:
                mt = conn.msgtype
                if role == "imu":
                    streams[role].add(t_ns, extract.imu(topics, msg, mt))
                elif role == "joint_states":
                    streams[role].add(t_ns, joints(msg, mt))
                elif role in ("foot_force", "contact"):
                    streams[role].add(t_ns, {role: extract.feet(topics, role, msg, mt, n_feet)})
                elif role == "depth":
                    info["frame"] = info["frame"] or msg.header.frame_id.lstrip("/")
                    streams[role].add(t_ns, {"depth": extract.depth_image(msg, conn.topic)})
                elif role == "camera_info" and "K" not in info:
                    info["K"], info["image_size"] = extract.intrinsics(msg)
                elif role == "T_base_camera":
                    info["transforms"].update(_transform(tf) for tf in msg.transforms)
                elif role == "ground_truth":
                    streams[role].add(t_ns, {"gt_pose": extract.pose(topics, msg, mt)})
    for role in ("imu", "joint_states", "depth", "ground_truth", "foot_force", "contact"):
        if role in topics.roles and not streams[role].t:
            raise ValueError(f"bag {bag}: no {role} messages on {topics.roles[role]['topic']!r}")
    if "depth" in topics.roles and "K" not in info:
        raise ValueError(f"bag {bag}: no camera_info messages on {topics.roles['camera_info']['topic']!r}")
    return {"streams": streams, **info}


def _depth(read: dict, topics: Topics, t: np.ndarray, sec, bag) -> dict:
    t_img, v = read["streams"]["depth"].arrays()
    t_img = sec(t_img)
    keep = (t_img >= t[0]) & (t_img <= t[-1])
    if not np.any(keep):
        raise ValueError(f"bag {bag}: no depth frame within the IMU/joint time span")
    shapes = {img.shape for img in v["depth"]}
    if len(shapes) != 1 or shapes.pop() != read["image_size"]:
        raise ValueError(
            f"bag {bag}: depth images ({sorted({i.shape for i in v['depth']})}) do not all match "
            f"the camera_info size {read['image_size']}"
        )
    entry = topics.roles["T_base_camera"]
    if "matrix" in entry:
        T = np.asarray(entry["matrix"], np.float64)
        if T.shape != (4, 4):
            topics.fail("T_base_camera.matrix", f"expected a 4x4 matrix, got shape {T.shape}")
    else:
        camera = entry.get("camera_frame", read["frame"])
        T = _tf_chain(read["transforms"], entry["base_frame"], camera, f"bag {bag}: {entry['topic']}")
    depth = np.stack(v["depth"])[keep]
    return {"depth": depth, "depth_t": t_img[keep], "K": read["K"], "T_base_camera": T}


def convert_bag(bag: str | os.PathLike, topics_path: str | os.PathLike, robot: str) -> dict[str, np.ndarray]:
    """The robot log (a dict, validated when saved) of `bag` read with the topics file at `topics_path`."""
    from jaxquad.robots import load

    topics = load_topics(topics_path)
    model = load(robot)
    read = read_bag(bag, topics, model.joint_names, len(model.foot_names))
    imu_t, imu = read["streams"]["imu"].arrays()
    js_t, js = read["streams"]["joint_states"].arrays()
    clock = imu_t if topics.clock == "imu" else js_t
    clock = clock[(clock >= max(imu_t[0], js_t[0])) & (clock <= min(imu_t[-1], js_t[-1]))]
    if clock.size < 2:
        raise ValueError(f"bag {bag}: the IMU and joint states do not overlap in time")
    origin = int(clock[0])
    sec = lambda ns: (ns - origin) * 1e-9
    t, imu_t, js_t = sec(clock), sec(imu_t), sec(js_t)
    method, tol = topics.interpolation, topics.tolerance_s
    log: dict[str, np.ndarray] = {
        "t": t,
        "t_origin_s": np.float64(origin * 1e-9),
        "robot": np.asarray(robot),
        "joint_names": np.asarray(model.joint_names),
    }
    for s, values in ((imu_t, imu), (js_t, js)):
        for key, x in values.items():
            y = resample_quat(s, x, t, method, tol) if key == "quat_wxyz" else resample(s, x, t, method, tol)
            if np.any(np.isfinite(y)) or key in ("q", "gyro", "acc"):
                log[key] = y
    for role in ("foot_force", "contact"):
        if role in topics.roles:
            s, v = read["streams"][role].arrays()
            s = sec(s)
            log[role] = resample(s, v[role], t, "nearest" if role == "contact" else method, tol)
    if "ground_truth" in topics.roles:
        s, v = read["streams"]["ground_truth"].arrays()
        s = sec(s)
        gt = np.concatenate(
            [resample(s, v["gt_pose"][:, :3], t, method, tol), resample_quat(s, v["gt_pose"][:, 3:], t, method, tol)],
            axis=1,
        )
        bad = ~np.all(np.isfinite(gt), axis=1)
        if np.any(bad):
            raise ValueError(
                f"bag {bag}: ground truth has no sample within {tol} s of t = {t[np.argmax(bad)]:.3f} s "
                f"(raise tolerance_s or drop ground_truth)"
            )
        log["gt_pose"] = gt
    if "depth" in topics.roles:
        log.update(_depth(read, topics, t, sec, bag))
    return log


def convert(bag, topics_path, robot: str, out: str | os.PathLike) -> dict[str, np.ndarray]:
    """Convert and write the log to `out` atomically (validated first)."""
    from jaxquad.io import save_log
    from jaxquad.io.atomic import check_output_file

    check_output_file(out, "--out")
    log = convert_bag(bag, topics_path, robot)
    save_log(Path(out), log)
    return log
