"""Per-role readers: one decoded message -> the numbers of its role (robot joint and foot order)."""

from __future__ import annotations

import numpy as np

from jaxquad.ros.fields import get_array, get_field
from jaxquad.ros.topics import Topics

_DEPTH_ENCODINGS = {"16UC1": ("u2", 1000.0), "32FC1": ("f4", 1.0)}  # dtype, units per metre


def _vector(topics: Topics, role: str, msg, msgtype: str, key: str, n: int, required: bool = True):
    path = topics.field(role, key, msgtype, required)
    if path is None:
        return None
    where = f"{role}.{key} ({topics.roles[role]['topic']})"
    v = get_array(msg, path, where).ravel()
    if v.size == 0:
        return np.full(n, np.nan)  # e.g. a JointState without efforts
    if v.size < n:
        raise ValueError(f"{where}: field {path!r} has {v.size} values, expected {n}")
    return v[:n]


def imu(topics: Topics, msg, msgtype: str) -> dict:
    out = {
        "gyro": _vector(topics, "imu", msg, msgtype, "gyro", 3),
        "acc": _vector(topics, "imu", msg, msgtype, "acc", 3),
    }
    path = topics.field("imu", "quat_wxyz", msgtype, required=False)
    if path is not None:
        q = get_array(msg, path, f"imu.quat_wxyz ({topics.roles['imu']['topic']})").ravel()[:4]
        if topics.roles["imu"].get("quat_order", "wxyz") == "xyzw":
            q = q[[3, 0, 1, 2]]
        cov = getattr(msg, "orientation_covariance", None)
        if cov is not None and cov[0] == -1:  # sensor_msgs/Imu: "no orientation estimate"
            q = np.full(4, np.nan)
        out["quat_wxyz"] = q
    return out


class JointReader:
    """Joint arrays of a message put into the robot's joint order, by joint name."""

    def __init__(self, topics: Topics, joint_names: tuple[str, ...]):
        self.topics, self.joint_names = topics, tuple(joint_names)
        self.entry = topics.roles["joint_states"]
        self._cache: dict[tuple, np.ndarray] = {}

    def _index(self, names: tuple) -> np.ndarray:
        if names not in self._cache:
            rename = self.entry.get("joint_map", {})
            pos = {rename.get(n, n): i for i, n in enumerate(names) if n is not None}
            missing = [j for j in self.joint_names if j not in pos]
            if missing:
                have = ", ".join(str(n) for n in names if n is not None)
                raise ValueError(
                    f"joint_states ({self.entry['topic']}): robot joint(s) {', '.join(missing)} not in the "
                    f"message (it has: {have}); rename with joint_map"
                )
            self._cache[names] = np.array([pos[j] for j in self.joint_names])
        return self._cache[names]

    def __call__(self, msg, msgtype: str) -> dict:
        if "joints" in self.entry:
            names = tuple(self.entry["joints"])
        else:
            path = self.topics.field("joint_states", "names", msgtype, required=False)
            if path is None:
                self.topics.fail("joint_states.joints", f"needed for {msgtype}: the robot joint of each array element")
            names = tuple(get_field(msg, path, "joint_states.names"))
        idx = self._index(names)
        out = {}
        for key in ("q", "qd", "tau"):
            path = self.topics.field("joint_states", key, msgtype, required=key == "q")
            if path is None:
                continue
            where = f"joint_states.{key} ({self.entry['topic']})"
            v = get_array(msg, path, where).ravel()
            if v.size <= idx.max():  # JointState may leave velocity/effort empty: no data
                if key == "q":
                    raise ValueError(f"{where}: field {path!r} has {v.size} values for {len(names)} joint names")
                v = np.full(idx.max() + 1, np.nan)
            out[key] = v[idx]
        return out


def feet(topics: Topics, role: str, msg, msgtype: str, n_feet: int) -> np.ndarray:
    """foot_force or contact values in the robot's foot order (`index`: the element of each foot)."""
    entry = topics.roles[role]
    v = get_array(msg, topics.field(role, "field", msgtype), f"{role} ({entry['topic']})").ravel()
    if "index" in entry:
        if len(entry["index"]) != n_feet or max(entry["index"]) >= v.size:
            topics.fail(f"{role}.index", f"expected {n_feet} element indices below {v.size}, got {entry['index']}")
        v = v[np.asarray(entry["index"])]
    elif v.size != n_feet:
        raise ValueError(
            f"{role} ({entry['topic']}): {v.size} values per message, the robot has {n_feet} feet; "
            f"pick them with 'index'"
        )
    if role == "contact":
        v = (v > float(entry["threshold"])) if "threshold" in entry else (v != 0)
    return v.astype(np.float64)


def depth_image(msg, topic: str) -> np.ndarray:
    """(H, W) float32 z-depth in metres, 0 = invalid (16UC1 millimetres or 32FC1 metres)."""
    enc = msg.encoding
    if enc not in _DEPTH_ENCODINGS:
        raise ValueError(
            f"depth ({topic}): image encoding {enc!r} is not read (depth must be 16UC1 millimetres or 32FC1 metres)"
        )
    kind, per_metre = _DEPTH_ENCODINGS[enc]
    dtype = np.dtype(kind).newbyteorder(">" if msg.is_bigendian else "<")
    h, w, step = int(msg.height), int(msg.width), int(msg.step)
    data = np.asarray(msg.data, np.uint8)
    if data.size < h * step or step < w * dtype.itemsize:
        raise ValueError(f"depth ({topic}): image data of {data.size} bytes does not fit {h}x{w} {enc} (step {step})")
    rows = data[: h * step].reshape(h, step)[:, : w * dtype.itemsize]
    img = (np.ascontiguousarray(rows).view(dtype).reshape(h, w) / per_metre).astype(np.float32)  # rounded once
    img[~np.isfinite(img) | (img < 0)] = 0.0
    return img


def intrinsics(msg) -> tuple[np.ndarray, tuple[int, int]]:
    """K (3, 3) and (height, width) of a CameraInfo (ROS 1 names it `K`, ROS 2 `k`)."""
    k = getattr(msg, "k", None)
    k = msg.K if k is None else k
    return np.asarray(k, np.float64).reshape(3, 3), (int(msg.height), int(msg.width))


def pose(topics: Topics, msg, msgtype: str) -> np.ndarray:
    """Ground-truth x y z qw qx qy qz."""
    topic = topics.roles["ground_truth"]["topic"]
    p = get_array(msg, topics.field("ground_truth", "position", msgtype), f"ground_truth.position ({topic})")
    q = get_array(msg, topics.field("ground_truth", "orientation", msgtype), f"ground_truth.orientation ({topic})")
    return np.concatenate([p.ravel()[:3], q.ravel()[:4]])
