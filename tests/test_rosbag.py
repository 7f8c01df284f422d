"""ROS bags in and out: bags written here with rosbags' own writer from known arrays convert back to
those arrays; exported bags read back with rosbags to the estimator's numbers; every user error."""

from __future__ import annotations

import shutil
import sqlite3
from pathlib import Path

import numpy as np
import pytest
import yaml
from scipy.spatial.transform import Rotation

from jaxquad.io import load_log
from jaxquad.ros import convert_bag
from jaxquad.ros.messages import Messages, bag_writer, seconds_to_ns
from jaxquad.robots import load

EXAMPLES = Path(__file__).resolve().parents[1] / "jaxquad" / "ros" / "examples"
JOINTS = load("go2").joint_names
T0_NS = 1_700_000_000_000_000_000  # ROS time of the first sample
N, DT_NS = 120, 4_000_000
H, W = 6, 8


def _truth(seed: int = 0) -> dict:
    rng = np.random.default_rng(seed)
    t = T0_NS + DT_NS * np.arange(N)
    quat = Rotation.from_euler("zyx", rng.normal(0, 0.2, (N, 3))).as_quat()[:, [3, 0, 1, 2]]
    gt_q = Rotation.from_euler("zyx", rng.normal(0, 0.3, (N, 3))).as_quat()[:, [3, 0, 1, 2]]
    depth = rng.integers(300, 5000, (4, H, W)).astype(np.uint16)
    depth[:, 0, :3] = 0  # invalid pixels
    return {
        "t": t, "gyro": rng.normal(0, 0.5, (N, 3)), "acc": rng.normal(0, 0.3, (N, 3)) + [0, 0, 9.81],
        "quat_wxyz": quat, "q": rng.uniform(-1, 1, (N, 12)), "qd": rng.normal(0, 2, (N, 12)),
        "tau": rng.normal(0, 5, (N, 12)), "foot_force": rng.uniform(0, 60, (N, 4)),
        "gt_pose": np.concatenate([rng.normal(0, 1, (N, 3)), gt_q], axis=1),
        "depth_mm": depth, "depth_t": T0_NS + np.array([20, 130, 250, 400]) * 1_000_000,
        "K": np.array([[7.0, 0, 3.9], [0, 7.5, 2.8], [0, 0, 1]]),
    }  # fmt: skip


# base_link -> camera_link -> camera_optical (a mount, then the optical axes).
TF = [("base_link", "camera_link", [0.3, 0.0, 0.1], Rotation.from_euler("y", 0.2)),
      ("camera_link", "camera_optical", [0.0, 0.02, 0.0], Rotation.from_euler("zx", [-np.pi / 2, -np.pi / 2]))]  # fmt: skip


def _tf_matrix() -> np.ndarray:
    T = np.eye(4)
    for _, _, p, r in TF:
        step = np.eye(4)
        step[:3, :3], step[:3, 3] = r.as_matrix(), p
        T = T @ step
    return T


def _write_generic(path: Path, fmt: str, d: dict, msg_names=None, drop=slice(0, 0), encoding="16UC1") -> None:
    names = list(msg_names or JOINTS)
    perm = [JOINTS.index(n) if n in JOINTS else JOINTS.index("FL_hip_joint") for n in names]
    with bag_writer(path, fmt) as w:
        m, ty = w.msgs, w.msgs.types
        ns = d["t"]
        for i in range(N):
            h = m.header(ns[i], "imu")
            imu = ty["sensor_msgs/msg/Imu"](
                header=h, orientation=m.quaternion(d["quat_wxyz"][i]), orientation_covariance=np.zeros(9),
                angular_velocity=m.vector3(d["gyro"][i]), angular_velocity_covariance=np.zeros(9),
                linear_acceleration=m.vector3(d["acc"][i]), linear_acceleration_covariance=np.zeros(9))  # fmt: skip
            w.write("/imu/data", "sensor_msgs/msg/Imu", ns[i], imu)
            if not (drop.start <= i < drop.stop):
                js = ty["sensor_msgs/msg/JointState"](header=m.header(ns[i], ""), name=names,
                                                      position=d["q"][i, perm], velocity=d["qd"][i, perm],
                                                      effort=d["tau"][i, perm])  # fmt: skip
                w.write("/joint_states", "sensor_msgs/msg/JointState", ns[i], js)
            layout = ty["std_msgs/msg/MultiArrayLayout"](dim=[], data_offset=0)
            ff = ty["std_msgs/msg/Float32MultiArray"](layout=layout, data=d["foot_force"][i].astype(np.float32))
            w.write("/foot_force", "std_msgs/msg/Float32MultiArray", ns[i], ff)
            cov = np.zeros(36)
            odom = ty["nav_msgs/msg/Odometry"](
                header=m.header(ns[i], "world"), child_frame_id="base_link",
                pose=ty["geometry_msgs/msg/PoseWithCovariance"](pose=m.pose(d["gt_pose"][i, :3], d["gt_pose"][i, 3:]), covariance=cov),
                twist=ty["geometry_msgs/msg/TwistWithCovariance"](twist=ty["geometry_msgs/msg/Twist"](
                    linear=m.vector3([0, 0, 0]), angular=m.vector3([0, 0, 0])), covariance=cov))  # fmt: skip
            w.write("/odom/ground_truth", "nav_msgs/msg/Odometry", ns[i], odom)
        tfs = [m.transform(ns[0], a, b, p, r.as_quat()[[3, 0, 1, 2]]) for a, b, p, r in TF]
        w.write("/tf_static", "tf2_msgs/msg/TFMessage", ns[0], ty["tf2_msgs/msg/TFMessage"](transforms=tfs))
        for k, t_img in enumerate(d["depth_t"]):
            if encoding == "32FC1":
                img = (d["depth_mm"][k] / 1000.0).astype(np.float32)
                img[img == 0] = np.nan
            else:
                img = d["depth_mm"][k]
            data = np.frombuffer(img.tobytes(), np.uint8)
            msg = ty["sensor_msgs/msg/Image"](header=m.header(t_img, "camera_optical"), height=H, width=W,
                                              encoding=encoding, is_bigendian=0, step=W * img.itemsize, data=data)  # fmt: skip
            w.write("/camera/depth/image_raw", "sensor_msgs/msg/Image", t_img, msg)
            w.write("/camera/depth/camera_info", "sensor_msgs/msg/CameraInfo", t_img, _camera_info(m, t_img, d["K"]))


def _camera_info(m: Messages, t_ns: int, K: np.ndarray):
    ty = m.types
    fields = dict(m.store.fielddefs["sensor_msgs/msg/CameraInfo"][1])
    big = "K" in fields  # ROS 1 names the matrices in capitals
    mats = {("D" if big else "d"): np.zeros(5), ("K" if big else "k"): K.ravel(), ("R" if big else "r"): np.eye(3).ravel(),
            ("P" if big else "p"): np.zeros(12)}  # fmt: skip
    roi = ty["sensor_msgs/msg/RegionOfInterest"](x_offset=0, y_offset=0, height=0, width=0, do_rectify=False)
    return ty["sensor_msgs/msg/CameraInfo"](header=m.header(t_ns, "camera_optical"), height=H, width=W,
                                            distortion_model="plumb_bob", **mats, binning_x=0, binning_y=0, roi=roi)  # fmt: skip


def _topics(tmp: Path, edit=None, base: str = "generic.yaml") -> Path:
    raw = yaml.safe_load((EXAMPLES / base).read_text())
    if base == "generic.yaml":
        raw["contact"].pop("threshold")
        raw["contact"]["threshold"] = 30.0
    if edit:
        edit(raw)
    path = tmp / "topics.yaml"
    path.write_text(yaml.safe_dump(raw))
    if base != "generic.yaml":
        shutil.copytree(EXAMPLES / "msg", tmp / "msg", dirs_exist_ok=True)
    return path


@pytest.mark.parametrize("fmt", ["ros1", "sqlite3", "mcap"])
def test_generic_bag_converts_to_the_same_arrays(tmp_path, fmt):
    d = _truth()
    bag = tmp_path / ("rec.bag" if fmt == "ros1" else "rec")
    _write_generic(bag, fmt, d)
    log = convert_bag(bag, _topics(tmp_path), "go2")
    np.testing.assert_allclose(log["t"], (d["t"] - T0_NS) * 1e-9, atol=1e-12)
    assert float(log["t_origin_s"]) == T0_NS * 1e-9
    for key in ("gyro", "acc", "q", "qd", "tau", "gt_pose"):
        np.testing.assert_allclose(log[key], d[key], rtol=0, atol=1e-12, err_msg=key)
    np.testing.assert_allclose(np.abs(np.sum(log["quat_wxyz"] * d["quat_wxyz"], axis=1)), 1.0, atol=1e-12)
    np.testing.assert_allclose(log["foot_force"], d["foot_force"].astype(np.float32), atol=0)
    np.testing.assert_array_equal(log["contact"], (d["foot_force"].astype(np.float32) > 30.0).astype(float))
    np.testing.assert_allclose(log["depth"], d["depth_mm"] / 1000.0, atol=1e-6)
    np.testing.assert_allclose(log["depth_t"], (d["depth_t"] - T0_NS) * 1e-9, atol=1e-12)
    np.testing.assert_allclose(log["K"], d["K"])
    np.testing.assert_allclose(log["T_base_camera"], _tf_matrix(), atol=1e-12)
