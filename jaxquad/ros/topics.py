"""The topics file of `jaxquad convert`: which bag topic plays which role, and how to read it.

A YAML mapping (every key optional unless marked):

    clock: imu              # imu | joint_states: the stream whose stamps become the log's `t`
    interpolation: linear   # linear | nearest: how other streams are resampled onto the clock
    tolerance_s: 0.02       # a clock sample with no data this close becomes NaN (a gap)
    stamp: header           # header (message header.stamp, bag time if it has none) | receive (bag time)
    types: [msg/my_robot/msg/LowState.msg]   # .msg files (relative to this file), named <pkg>/msg/<Name>.msg
    imu:          {topic: /imu, gyro: ..., acc: ..., quat_wxyz: ..., quat_order: wxyz}     # required
    joint_states: {topic: /joint_states, q: ..., qd: ..., tau: ..., names: ..., joints: [...],
                   joint_map: {message_name: robot_joint_name}}                           # required
    foot_force:   {topic: /foot_force, field: data, index: [1, 0, 3, 2]}
    contact:      {topic: /contact, field: data, index: [...], threshold: 20.0}
    depth:        {topic: /camera/depth/image_rect_raw}
    camera_info:  {topic: /camera/depth/camera_info}
    T_base_camera: {base_frame: base_link, camera_frame: camera_depth_optical_frame}   # or {matrix: 4x4}
    ground_truth: {topic: /mocap/pose, position: ..., orientation: ...}

Field values are paths into the message: `a.b` (nested field), `a[3]` (one element), `a[*].q` (field q
of every element). Standard types have default paths (`FIELD_DEFAULTS`); vendor types need them.
"""

from __future__ import annotations

import dataclasses
import os
from pathlib import Path
from typing import Any

# Default field paths per standard message type and role.
_POSE = {"position": "pose.position", "orientation": "pose.orientation"}
_POSE_COV = {"position": "pose.pose.position", "orientation": "pose.pose.orientation"}
FIELD_DEFAULTS: dict[str, dict[str, str]] = {
    "sensor_msgs/msg/Imu": {"gyro": "angular_velocity", "acc": "linear_acceleration", "quat_wxyz": "orientation"},
    "sensor_msgs/msg/JointState": {"names": "name", "q": "position", "qd": "velocity", "tau": "effort"},
    "nav_msgs/msg/Odometry": _POSE_COV,
    "geometry_msgs/msg/PoseStamped": _POSE,
    "geometry_msgs/msg/PoseWithCovarianceStamped": _POSE_COV,
    "geometry_msgs/msg/TransformStamped": {"position": "transform.translation", "orientation": "transform.rotation"},
    **{f"std_msgs/msg/{k}MultiArray": {"field": "data"} for k in ("Float32", "Float64", "Int16", "Int32", "UInt8")},
}
ROLE_KEYS: dict[str, tuple[str, ...]] = {
    "imu": ("topic", "type", "gyro", "acc", "quat_wxyz", "quat_order"),
    "joint_states": ("topic", "type", "q", "qd", "tau", "names", "joints", "joint_map"),
    "foot_force": ("topic", "type", "field", "index"),
    "contact": ("topic", "type", "field", "index", "threshold"),
    "depth": ("topic", "type"),
    "camera_info": ("topic", "type"),
    "T_base_camera": ("topic", "base_frame", "camera_frame", "matrix"),
    "ground_truth": ("topic", "type", "position", "orientation"),
}
_TOP_KEYS = ("clock", "interpolation", "tolerance_s", "stamp", "types")
_CHOICES = {"clock": ("imu", "joint_states"), "interpolation": ("linear", "nearest"), "stamp": ("header", "receive")}


@dataclasses.dataclass(frozen=True)
class Topics:
    """A checked topics file: `roles` maps a role name to its settings (always with `topic`)."""

    path: Path
    roles: dict[str, dict[str, Any]]
    types: dict[str, str]  # message type name -> .msg text
    clock: str = "imu"
    interpolation: str = "linear"
    tolerance_s: float = 0.02
    stamp: str = "header"

    def fail(self, key: str, message: str) -> None:
        raise ValueError(f"topics file {self.path}: {key}: {message}")

    def field(self, role: str, key: str, msgtype: str, required: bool = True) -> str | None:
        """The field path of `key` in role `role`: the file's, else the default for `msgtype`."""
        path = self.roles[role].get(key, FIELD_DEFAULTS.get(msgtype, {}).get(key))
        if path is None and required:
            self.fail(f"{role}.{key}", f"no default field for message type {msgtype}; give its field path")
        return path


def _msg_type_name(file: Path, where: str) -> str:
    parts = file.with_suffix("").parts
    if file.suffix != ".msg" or len(parts) < 3 or parts[-2] != "msg":
        raise ValueError(f"{where}: {file} must be named <package>/msg/<Name>.msg")
    return "/".join(parts[-3:])


def load_topics(path: str | os.PathLike) -> Topics:
    """Read and check a topics file; a problem raises a one-line ValueError naming the key."""
    import yaml

    from jaxquad.io.files import read_text

    path = Path(path)
    text = read_text(path, "topics")
    try:
        raw = yaml.safe_load(text)
    except yaml.YAMLError as e:
        raise ValueError(f"topics file {path}: not valid YAML ({str(e).splitlines()[0]})") from None
    if not isinstance(raw, dict):
        raise ValueError(f"topics file {path}: expected a mapping of roles to topics")
    unknown = sorted(set(raw) - set(_TOP_KEYS) - set(ROLE_KEYS))
    if unknown:
        raise ValueError(
            f"topics file {path}: unknown key {unknown[0]!r} (known: {', '.join(_TOP_KEYS + tuple(ROLE_KEYS))})"
        )
    where = f"topics file {path}"
    for role in ("imu", "joint_states"):
        if role not in raw:
            raise ValueError(f"{where}: {role}: missing (an IMU and joint states are required)")
    roles = {}
    for role, keys in ROLE_KEYS.items():
        if role not in raw:
            continue
        entry = raw[role]
        if not isinstance(entry, dict):
            raise ValueError(f"{where}: {role}: expected a mapping with 'topic', got {entry!r}")
        bad = sorted(set(entry) - set(keys))
        if bad:
            raise ValueError(f"{where}: {role}.{bad[0]}: unknown key (known: {', '.join(keys)})")
        if role == "T_base_camera":
            if ("matrix" in entry) == ("base_frame" in entry):
                raise ValueError(f"{where}: T_base_camera: give either 'matrix' or 'base_frame' (+ 'camera_frame')")
            entry = {"topic": "/tf_static", **entry}
        elif not isinstance(entry.get("topic"), str):
            raise ValueError(f"{where}: {role}.topic: missing or not a string")
        for key in ("index", "joints"):
            if key in entry and not isinstance(entry[key], list):
                raise ValueError(f"{where}: {role}.{key}: expected a list")
        if "joint_map" in entry and not isinstance(entry["joint_map"], dict):
            raise ValueError(f"{where}: {role}.joint_map: expected a mapping message name -> robot joint name")
        roles[role] = entry
    for key, why in (("camera_info", "their intrinsics"), ("T_base_camera", "the camera pose on the base")):
        if "depth" in roles and key not in roles:
            raise ValueError(f"{where}: {key}: missing (depth images need {why})")
    settings = {}
    for key, choices in _CHOICES.items():
        value = raw.get(key, choices[0])
        if value not in choices:
            raise ValueError(f"{where}: {key}: {value!r} is not one of {', '.join(choices)}")
        settings[key] = value
    tol = raw.get("tolerance_s", 0.02)
    if not isinstance(tol, (int, float)) or not tol > 0:
        raise ValueError(f"{where}: tolerance_s: expected a positive number of seconds, got {tol!r}")
    types = {}
    files = raw.get("types", [])
    if not isinstance(files, list):
        raise ValueError(f"{where}: types: expected a list of .msg files")
    for f in files:
        file = path.parent / str(f)
        if not file.is_file():
            raise FileNotFoundError(f"{where}: types: message definition not found: {file}")
        types[_msg_type_name(Path(str(f)), f"{where}: types")] = file.read_text()
    return Topics(path, roles, types, tolerance_s=float(tol), **settings)
