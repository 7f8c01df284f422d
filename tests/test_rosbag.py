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
from jaxquad.robots import load
from jaxquad.ros import convert_bag
from jaxquad.ros.messages import Messages, bag_writer

EXAMPLES = Path(__file__).resolve().parents[1] / "jaxquad" / "ros" / "examples"
JOINTS = load("go2").joint_names
T0_NS = 1_700_000_000_000_000_000  # ROS time of the first sample
N, DT_NS = 120, 4_000_000
H, W = 12, 16


def _truth(seed: int = 0) -> dict:
    rng = np.random.default_rng(seed)
    t = T0_NS + DT_NS * np.arange(N)
    quat = Rotation.from_euler("zyx", rng.normal(0, 0.2, (N, 3))).as_quat()[:, [3, 0, 1, 2]]
    gt_q = Rotation.from_euler("zyx", rng.normal(0, 0.3, (N, 3))).as_quat()[:, [3, 0, 1, 2]]
    depth = rng.integers(300, 5000, (4, H, W)).astype(np.uint16)
    depth[:, 0, :3] = 0  # invalid pixels
    return {
        "t": t,
        "gyro": rng.normal(0, 0.5, (N, 3)),
        "acc": rng.normal(0, 0.3, (N, 3)) + [0, 0, 9.81],
        "quat_wxyz": quat,
        "q": rng.uniform(-1, 1, (N, 12)),
        "qd": rng.normal(0, 2, (N, 12)),
        "tau": rng.normal(0, 5, (N, 12)),
        "foot_force": rng.uniform(0, 60, (N, 4)),
        "gt_pose": np.concatenate([rng.normal(0, 1, (N, 3)), gt_q], axis=1),
        "depth_mm": depth,
        "depth_t": T0_NS + np.array([20, 130, 250, 400]) * 1_000_000,
        "K": np.array([[7.0, 0, 3.9], [0, 7.5, 2.8], [0, 0, 1]]),
    }


# base_link -> camera_link -> camera_optical (a mount, then the optical axes).
TF = [
    ("base_link", "camera_link", [0.3, 0.0, 0.1], Rotation.from_euler("y", 0.2)),
    ("camera_link", "camera_optical", [0.0, 0.02, 0.0], Rotation.from_euler("zx", [-np.pi / 2, -np.pi / 2])),
]


def _tf_matrix() -> np.ndarray:
    T = np.eye(4)
    for _, _, p, r in TF:
        step = np.eye(4)
        step[:3, :3], step[:3, 3] = r.as_matrix(), p
        T = T @ step
    return T


def _write_generic(path: Path, fmt: str, d: dict, rename=None, drop=slice(0, 0), encoding="16UC1") -> None:
    """Standard messages; the JointState lists the joints shuffled, with names renamed by `rename`."""
    perm = list(np.random.default_rng(9).permutation(len(JOINTS)))
    names = [(rename or {}).get(JOINTS[k], JOINTS[k]) for k in perm]
    with bag_writer(path, fmt) as w:
        m, ty = w.msgs, w.msgs.types
        ns = d["t"]
        for i in range(N):
            h = m.header(ns[i], "imu")
            imu = ty["sensor_msgs/msg/Imu"](
                header=h,
                orientation=m.quaternion(d["quat_wxyz"][i]),
                orientation_covariance=np.zeros(9),
                angular_velocity=m.vector3(d["gyro"][i]),
                angular_velocity_covariance=np.zeros(9),
                linear_acceleration=m.vector3(d["acc"][i]),
                linear_acceleration_covariance=np.zeros(9),
            )
            w.write("/imu/data", "sensor_msgs/msg/Imu", ns[i], imu)
            if not (drop.start <= i < drop.stop):
                js = ty["sensor_msgs/msg/JointState"](
                    header=m.header(ns[i], ""),
                    name=names,
                    position=d["q"][i, perm],
                    velocity=d["qd"][i, perm],
                    effort=d["tau"][i, perm],
                )
                w.write("/joint_states", "sensor_msgs/msg/JointState", ns[i], js)
            layout = ty["std_msgs/msg/MultiArrayLayout"](dim=[], data_offset=0)
            ff = ty["std_msgs/msg/Float32MultiArray"](layout=layout, data=d["foot_force"][i].astype(np.float32))
            w.write("/foot_force", "std_msgs/msg/Float32MultiArray", ns[i], ff)
            cov = np.zeros(36)
            odom = ty["nav_msgs/msg/Odometry"](
                header=m.header(ns[i], "world"),
                child_frame_id="base_link",
                pose=ty["geometry_msgs/msg/PoseWithCovariance"](
                    pose=m.pose(d["gt_pose"][i, :3], d["gt_pose"][i, 3:]), covariance=cov
                ),
                twist=ty["geometry_msgs/msg/TwistWithCovariance"](
                    twist=ty["geometry_msgs/msg/Twist"](linear=m.vector3([0, 0, 0]), angular=m.vector3([0, 0, 0])),
                    covariance=cov,
                ),
            )
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
            msg = ty["sensor_msgs/msg/Image"](
                header=m.header(t_img, "camera_optical"),
                height=H,
                width=W,
                encoding=encoding,
                is_bigendian=0,
                step=W * img.itemsize,
                data=data,
            )
            w.write("/camera/depth/image_raw", "sensor_msgs/msg/Image", t_img, msg)
            w.write("/camera/depth/camera_info", "sensor_msgs/msg/CameraInfo", t_img, _camera_info(m, t_img, d["K"]))


def _camera_info(m: Messages, t_ns: int, K: np.ndarray):
    ty = m.types
    fields = dict(m.store.fielddefs["sensor_msgs/msg/CameraInfo"][1])
    big = "K" in fields  # ROS 1 names the matrices in capitals
    mats = {
        ("D" if big else "d"): np.zeros(5),
        ("K" if big else "k"): K.ravel(),
        ("R" if big else "r"): np.eye(3).ravel(),
        ("P" if big else "p"): np.zeros(12),
    }
    roi = ty["sensor_msgs/msg/RegionOfInterest"](x_offset=0, y_offset=0, height=0, width=0, do_rectify=False)
    return ty["sensor_msgs/msg/CameraInfo"](
        header=m.header(t_ns, "camera_optical"),
        height=H,
        width=W,
        distortion_model="plumb_bob",
        **mats,
        binning_x=0,
        binning_y=0,
        roi=roi,
    )


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
    if fmt != "ros1":  # the bare storage file reads the same as its folder
        bare = convert_bag(next(bag.glob("*.mcap" if fmt == "mcap" else "*.db3")), _topics(tmp_path), "go2")
        for key in log:
            np.testing.assert_array_equal(bare[key], log[key], err_msg=key)


def _write_lowstate(path: Path, fmt: str, d: dict, types: dict) -> None:
    """The vendor LowState stream (no header: stamped by receive time), motors in FR FL RR RL order."""
    motor_order = [
        JOINTS.index(f"{leg}_{j}_joint") for leg in ("FR", "FL", "RR", "RL") for j in ("hip", "thigh", "calf")
    ]
    with bag_writer(path, fmt, types) as w:
        ty = w.msgs.types
        for i, t in enumerate(d["t"]):
            motors = [
                ty["example_quad/msg/MotorState"](
                    mode=1, q=d["q"][i, k], dq=d["qd"][i, k], ddq=0.0, tau_est=d["tau"][i, k]
                )
                for k in motor_order
            ] + [ty["example_quad/msg/MotorState"](mode=0, q=0.0, dq=0.0, ddq=0.0, tau_est=0.0)] * 8
            imu = ty["example_quad/msg/IMUState"](
                quaternion=d["quat_wxyz"][i].astype(np.float32),
                gyroscope=d["gyro"][i].astype(np.float32),
                accelerometer=d["acc"][i].astype(np.float32),
                rpy=np.zeros(3, np.float32),
                temperature=30,
            )
            feet = np.round(d["foot_force"][i][[1, 0, 3, 2]]).astype(np.int16)  # FR FL RR RL
            msg = ty["example_quad/msg/LowState"](imu_state=imu, motor_state=motors, foot_force=feet, tick=i)
            w.write("/lowstate", "example_quad/msg/LowState", t, msg)
            mocap = ty["geometry_msgs/msg/PoseStamped"](
                header=w.msgs.header(t, "world"), pose=w.msgs.pose(d["gt_pose"][i, :3], d["gt_pose"][i, 3:])
            )
            w.write("/mocap/pose", "geometry_msgs/msg/PoseStamped", t, mocap)


def _lowstate_topics(raw: dict) -> None:
    for role in ("depth", "camera_info", "T_base_camera"):
        raw.pop(role)


def _vendor_types() -> dict:
    return {
        f"example_quad/msg/{n}": (EXAMPLES / "msg/example_quad/msg" / f"{n}.msg").read_text()
        for n in ("LowState", "MotorState", "IMUState")
    }


def _strip_definitions(bag: Path) -> None:
    """Make a ROS 2 sqlite3 bag look recorded before Humble: no message definitions inside."""
    with sqlite3.connect(next(bag.glob("*.db3"))) as db:
        db.execute("DELETE FROM message_definitions")
    meta = bag / "metadata.yaml"
    meta.write_text(meta.read_text().replace("type_description_hash: RIHS01_", "type_description_hash: X"))


@pytest.mark.parametrize("fmt", ["ros1", "sqlite3"])
def test_vendor_lowstate_converts_in_robot_order(tmp_path, fmt):
    d = _truth(1)
    bag = tmp_path / ("low.bag" if fmt == "ros1" else "low")
    _write_lowstate(bag, fmt, d, _vendor_types())
    if fmt == "sqlite3":
        _strip_definitions(bag)
        no_types = _topics(tmp_path, lambda r: (_lowstate_topics(r), r.pop("types")), "go2_lowstate.yaml")
        with pytest.raises(ValueError, match="example_quad/msg/LowState.*unknown.*'types'"):
            convert_bag(bag, no_types, "go2")
    log = convert_bag(bag, _topics(tmp_path, _lowstate_topics, "go2_lowstate.yaml"), "go2")
    f32 = lambda a: a.astype(np.float32).astype(np.float64)
    for key in ("q", "qd", "tau", "gyro", "acc"):
        np.testing.assert_array_equal(log[key], f32(d[key]), err_msg=key)
    q32 = f32(d["quat_wxyz"])
    np.testing.assert_allclose(log["quat_wxyz"], q32 / np.linalg.norm(q32, axis=1, keepdims=True), atol=1e-12)
    np.testing.assert_array_equal(log["foot_force"], np.round(d["foot_force"]))
    np.testing.assert_allclose(log["gt_pose"], d["gt_pose"], atol=1e-12)  # PoseStamped motion capture
    np.testing.assert_allclose(log["t"], (d["t"] - T0_NS) * 1e-9, atol=1e-12)


def test_gaps_stay_gaps_and_linear_interpolation_bridges_within_tolerance(tmp_path):
    d = _truth(2)
    bag = tmp_path / "gap"
    _write_generic(bag, "mcap", d, drop=slice(40, 60))  # joints missing for 80 ms
    t = (d["t"] - T0_NS) * 1e-9
    log = convert_bag(bag, _topics(tmp_path), "go2")
    gap = np.zeros(N, bool)
    gap[40:60] = True
    assert np.all(np.isnan(log["q"][gap])) and np.all(np.isfinite(log["q"][~gap]))
    log = convert_bag(bag, _topics(tmp_path, lambda r: r.update(tolerance_s=0.05)), "go2")
    keep = ~gap
    for j in range(12):  # a gap of 84 ms between neighbours: bridged where both lie within 50 ms
        ref = np.interp(t, t[keep], d["q"][keep, j])
        inside = gap & (t - t[39] <= 0.05) & (t[60] - t <= 0.05)
        np.testing.assert_allclose(log["q"][inside | keep, j], ref[inside | keep], atol=1e-12)
        assert np.all(np.isnan(log["q"][gap & ~inside, j]))


def test_resample_matches_references():
    from jaxquad.ros.resample import resample, resample_quat

    rng = np.random.default_rng(3)
    s = np.cumsum(rng.uniform(0.002, 0.006, 200))
    x = rng.normal(size=(200, 2))
    t = np.linspace(s[0] - 0.01, s[-1] + 0.01, 333)
    tol = 0.004
    lin = resample(s, x, t, "linear", tol)
    near = resample(s, x, t, "nearest", tol)
    for k, tk in enumerate(t):
        j = int(np.argmin(np.abs(s - tk)))
        want = x[j] if abs(s[j] - tk) <= tol else np.full(2, np.nan)
        np.testing.assert_array_equal(near[k], want)
        lo, hi = s[s <= tk], s[s > tk]
        ok = lo.size and (lo[-1] == tk or (hi.size and tk - lo[-1] <= tol and hi[0] - tk <= tol))
        want = [np.interp(tk, s, x[:, c]) for c in range(2)] if ok else np.full(2, np.nan)
        np.testing.assert_allclose(lin[k], want, atol=1e-12)
    rot = Rotation.random(200, random_state=4)
    q = rot.as_quat()[:, [3, 0, 1, 2]]
    out = resample_quat(s, q, t, "linear", tol)
    ok = np.isfinite(out[:, 0])
    from scipy.spatial.transform import Slerp

    ref = Slerp(s, rot)(t[ok]).as_quat()[:, [3, 0, 1, 2]]
    np.testing.assert_allclose(np.abs(np.sum(out[ok] * ref, axis=1)), 1.0, atol=1e-9)


def test_32fc1_depth_in_metres_with_nan_as_invalid(tmp_path):
    d = _truth(4)
    bag = tmp_path / "f32"
    _write_generic(bag, "mcap", d, encoding="32FC1")
    log = convert_bag(bag, _topics(tmp_path), "go2")
    want = (d["depth_mm"] / 1000.0).astype(np.float32)
    np.testing.assert_array_equal(log["depth"], want)
    assert np.all(log["depth"][:, 0, :3] == 0)


@pytest.fixture(scope="module")
def generic_bag(tmp_path_factory) -> Path:
    bag = tmp_path_factory.mktemp("bag") / "rec"
    _write_generic(bag, "mcap", _truth(5))
    return bag


def _raises(bag, topics, match):
    with pytest.raises(ValueError, match=match):
        convert_bag(bag, topics, "go2")


def test_error_unknown_topic_lists_the_bags_topics(tmp_path, generic_bag):
    topics = _topics(tmp_path, lambda r: r["imu"].update(topic="/imu/raw"))
    _raises(
        generic_bag, topics, r"topic '/imu/raw' \(imu\) not found; the bag has: .*/imu/data \(sensor_msgs/msg/Imu\)"
    )


def test_error_joint_names_name_the_missing_ones(tmp_path):
    bag = tmp_path / "names"
    _write_generic(bag, "mcap", _truth(6), rename={"RR_calf_joint": "rr_knee"})
    _raises(bag, _topics(tmp_path), r"robot joint\(s\) RR_calf_joint not in the message .*rr_knee.*joint_map")
    log = convert_bag(
        bag, _topics(tmp_path, lambda r: r["joint_states"]["joint_map"].update(rr_knee="RR_calf_joint")), "go2"
    )
    np.testing.assert_allclose(log["q"], _truth(6)["q"], atol=1e-12)


def test_error_image_encoding(tmp_path):
    bag = tmp_path / "rgb"
    _write_generic(bag, "mcap", _truth(7), encoding="rgb8")
    _raises(bag, _topics(tmp_path), r"image encoding 'rgb8' is not read \(depth must be 16UC1 millimetres or 32FC1")


def test_error_no_imu_and_malformed_topics_files(tmp_path, generic_bag):
    _raises(generic_bag, _topics(tmp_path, lambda r: r.pop("imu")), r"imu: missing")
    _raises(generic_bag, _topics(tmp_path, lambda r: r["imu"].update(gyr="x")), r"imu\.gyr: unknown key")
    _raises(generic_bag, _topics(tmp_path, lambda r: r.update(imus={})), r"unknown key 'imus'")
    _raises(generic_bag, _topics(tmp_path, lambda r: r.update(clock="camera")), r"clock: 'camera' is not one of")
    _raises(generic_bag, _topics(tmp_path, lambda r: r["imu"].update(gyro="angular_velocity.w")), r"field 'w' of")
    _raises(
        generic_bag,
        _topics(tmp_path, lambda r: r["imu"].update(type="sensor_msgs/msg/Temperature")),
        r"carries sensor_msgs/msg/Imu, the topics file says",
    )
    _raises(
        generic_bag,
        _topics(tmp_path, lambda r: r["T_base_camera"].update(base_frame="trunk")),
        r"no transform chain from 'trunk' to 'camera_optical'",
    )
    (tmp_path / "msg" / "a" / "msg").mkdir(parents=True)
    (tmp_path / "msg" / "a" / "msg" / "B.msg").write_text("float32 [ x y\n")
    _raises(generic_bag, _topics(tmp_path, lambda r: r.update(types=["msg/a/msg/B.msg"])), r"a/msg/B: cannot be parsed")
    (tmp_path / "B.msg").write_text("float32 x\n")
    _raises(
        generic_bag, _topics(tmp_path, lambda r: r.update(types=["B.msg"])), r"must be named <package>/msg/<Name>.msg"
    )
    _raises(generic_bag, _topics(tmp_path, lambda r: r.pop("T_base_camera")), r"T_base_camera: missing")
    (tmp_path / "bad.yaml").write_text("imu: [1, 2\n")
    _raises(generic_bag, tmp_path / "bad.yaml", r"not valid YAML")
    with pytest.raises(ValueError, match="not a bag"):
        convert_bag(tmp_path / "bad.yaml", _topics(tmp_path), "go2")


def _npz_log(d: dict) -> dict:
    """The .npz log equivalent to what `_write_generic` records."""
    t = (d["t"] - T0_NS) * 1e-9
    return {
        "t": t,
        "robot": np.asarray("go2"),
        "joint_names": np.asarray(JOINTS),
        **{k: d[k] for k in ("q", "qd", "tau", "gyro", "acc", "quat_wxyz", "gt_pose")},
        "foot_force": d["foot_force"].astype(np.float32).astype(np.float64),
        "contact": (d["foot_force"].astype(np.float32) > 30.0).astype(float),
        "depth": d["depth_mm"] / 1000.0,
        "depth_t": (d["depth_t"] - T0_NS) * 1e-9,
        "K": d["K"],
        "T_base_camera": _tf_matrix(),
    }


@pytest.fixture(scope="module")
def estimated(tmp_path_factory):
    """`jaxquad estimate` on a converted bag and on the equivalent .npz (one MJX compile for both)."""
    from jaxquad.cli import main
    from jaxquad.io import save_log

    root = tmp_path_factory.mktemp("est")
    d = _truth(8)
    d["gyro"] *= 0.2
    _write_generic(root / "rec", "mcap", d)
    topics = _topics(root)
    assert (
        main(["convert", str(root / "rec"), "--topics", str(topics), "--robot", "go2", "--out", str(root / "bag.npz")])
        == 0
    )
    save_log(root / "ref.npz", _npz_log(d))
    for name in ("bag", "ref"):
        assert (
            main(["estimate", str(root / f"{name}.npz"), "--out", str(root / f"est_{name}"), "--band-height", "3"]) == 0
        )
    return root


@pytest.mark.slow  # compiles the MJX estimator (about a minute on an idle 2-core CPU)
def test_estimate_on_converted_bag_equals_estimate_on_npz(estimated):
    a, b = (np.load(estimated / f"est_{n}" / "robot.npz") for n in ("bag", "ref"))
    assert set(a.files) == set(b.files)
    for key in a.files:
        np.testing.assert_array_equal(a[key], b[key], err_msg=key)
    a, b = (np.load(estimated / f"est_{n}" / "robot_scans.npz") for n in ("bag", "ref"))
    for key in b.files:
        np.testing.assert_array_equal(a[key], b[key], err_msg=key)
    assert (estimated / "est_bag" / "robot.tum").read_text() == (estimated / "est_ref" / "robot.tum").read_text()
    from jaxquad.ros.export import export

    counts = export(estimated / "est_bag", estimated / "est_bag_mcap")["topics"]  # a real estimate folder
    assert counts["/robot/odom"] == N and counts["/robot/scan_stabilized"] == counts["/robot/scan_baseline"] == 4


def _read_bag(path: Path) -> dict[str, list]:
    from rosbags.highlevel import AnyReader

    out: dict[str, list] = {}
    with AnyReader([path]) as reader:
        for conn, t_ns, raw in reader.messages():
            out.setdefault(conn.topic, []).append((t_ns, reader.deserialize(raw, conn.msgtype)))
    return out


@pytest.fixture(scope="module")
def results(tmp_path_factory) -> Path:
    """A results folder as `jaxquad estimate` writes it, plus a ground-truth TUM and a map."""
    from jaxquad.io import OccupancyMap, TumTrajectory, save_map, write_tum

    folder = tmp_path_factory.mktemp("res")
    rng = np.random.default_rng(10)
    t = 0.5 + 0.004 * np.arange(50)
    for name in ("robot", "gt_0000"):
        q = Rotation.random(50, random_state=11).as_quat()
        write_tum(folder / f"{name}.tum", TumTrajectory(t, rng.normal(size=(50, 3)), q))
    np.savez(
        folder / "robot.npz",
        t=t,
        v_base=rng.normal(size=(50, 3)).astype(np.float32),
        omega_base=rng.normal(size=(50, 3)).astype(np.float32),
    )
    ranges = rng.uniform(0.3, 6.0, (2, 4, W))
    ranges[:, 1, :5] = np.inf
    bearings = np.arctan2(-(np.arange(W) - 7.3), 9.0)
    np.savez(
        folder / "robot_scans.npz",
        depth_t=t[[3, 15, 30, 44]],
        ranges_stabilized=ranges[0],
        ranges_baseline=ranges[1],
        bearings=bearings,
        roll=rng.normal(0, 0.1, 4),
        pitch=rng.normal(0, 0.1, 4),
    )
    grid = rng.choice(np.array([-1, 0, 100], np.int8), (5, 7))
    save_map(folder / "map.yaml", OccupancyMap(grid, 0.05, (-1.0, 2.0, 0.0)))
    return folder


@pytest.mark.parametrize("fmt", ["mcap", "sqlite3", "ros1"])
def test_export_reads_back_to_the_same_numbers(results, tmp_path, fmt):
    from jaxquad.cli import main
    from jaxquad.io import load_map, read_tum

    out = tmp_path / ("out.bag" if fmt == "ros1" else "out")
    assert main(["export", str(results), "--bag", str(out), "--format", fmt]) == 0
    assert [p.name for p in tmp_path.iterdir()] == [out.name]  # no temporary left
    bag = _read_bag(out)
    est = np.load(results / "robot.npz")
    for name in ("robot", "gt_0000"):
        traj = read_tum(results / f"{name}.tum")
        odom = bag[f"/{name}/odom"]
        assert [t for t, _ in odom] == list(np.round(traj.t_s * 1e9).astype(np.int64))
        pose = [m.pose.pose for _, m in odom]
        np.testing.assert_array_equal([[p.position.x, p.position.y, p.position.z] for p in pose], traj.p_world_body)
        np.testing.assert_array_equal(
            [[p.orientation.x, p.orientation.y, p.orientation.z, p.orientation.w] for p in pose], traj.q_world_body_xyzw
        )
        v = np.array([[m.twist.twist.linear.x, m.twist.twist.linear.y, m.twist.twist.linear.z] for _, m in odom])
        np.testing.assert_array_equal(v, est["v_base"].astype(np.float64) if name == "robot" else 0 * v)
        assert {m.header.frame_id for _, m in odom} == {"odom"} and odom[0][1].child_frame_id == f"{name}/base_link"
        ((_, path),) = bag[f"/{name}/path"]
        np.testing.assert_array_equal(
            [[s.pose.position.x, s.pose.position.y] for s in path.poses], traj.p_world_body[:, :2]
        )
        tfs = [tf for _, m in bag["/tf"] for tf in m.transforms if tf.child_frame_id == f"{name}/base_link"]
        np.testing.assert_array_equal([tf.transform.translation.z for tf in tfs], traj.p_world_body[:, 2])
    scans = np.load(results / "robot_scans.npz")
    b = scans["bearings"]
    for key in ("stabilized", "baseline"):
        msgs = bag[f"/robot/scan_{key}"]
        assert [t for t, _ in msgs] == list(np.round(scans["depth_t"] * 1e9).astype(np.int64))
        for _, m in msgs:
            angles = m.angle_min + m.angle_increment * np.arange(len(m.ranges))
            assert abs(angles[-1] - b.max()) < 1e-5 and abs(m.angle_min - b.min()) < 1e-6
            assert m.header.frame_id == ("robot/base_level" if key == "stabilized" else "robot/base_link")
        # each beam: the range of the column whose bearing is nearest the beam's angle
        beams = np.linspace(b.min(), b.max(), b.size)
        want = [[scans[f"ranges_{key}"][i, np.argmin(np.abs(b - a))] for a in beams] for i in range(len(msgs))]
        np.testing.assert_array_equal([m.ranges for _, m in msgs], np.float32(want))
    level = [
        tf.transform.rotation for _, m in bag["/tf"] for tf in m.transforms if tf.child_frame_id == "robot/base_level"
    ]
    for r, roll, pitch in zip(level, scans["roll"], scans["pitch"]):  # base attitude then base->level: level
        R = Rotation.from_euler("ZYX", [0.0, pitch, roll]) * Rotation.from_quat([r.x, r.y, r.z, r.w])
        np.testing.assert_allclose(R.as_matrix(), np.eye(3), atol=1e-12)
    ((_, occ),) = bag["/map"]
    grid = load_map(results / "map.yaml").grid
    assert (occ.info.width, occ.info.height, occ.info.resolution) == (7, 5, np.float32(0.05))
    assert (occ.info.origin.position.x, occ.info.origin.position.y) == (-1.0, 2.0)
    np.testing.assert_array_equal(np.asarray(occ.data).reshape(5, 7), grid)  # row 0 = bottom, as the map


def test_export_errors_and_failed_export_leaves_nothing(tmp_path):
    from jaxquad.ros.export import export

    (tmp_path / "empty").mkdir()
    with pytest.raises(ValueError, match="nothing to export"):
        export(tmp_path / "empty", tmp_path / "out")
    with pytest.raises(ValueError, match="a ROS 1 bag is a .bag file"):
        export(tmp_path / "empty", tmp_path / "out", "ros1")
    (tmp_path / "bad").mkdir()
    (tmp_path / "bad" / "a.tum").write_text("0 0 0 0 0 0 0 1\n1 nan 0 0 0 0 0 1\n")
    with pytest.raises(ValueError, match="a.tum:2"):
        export(tmp_path / "bad", tmp_path / "out")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["bad", "empty"]


def test_cli_convert_writes_the_log_and_errors_in_one_line(tmp_path, generic_bag, capsys):
    from jaxquad.cli import main

    topics, out = _topics(tmp_path), tmp_path / "log.npz"
    assert main(["convert", str(generic_bag), "--topics", str(topics), "--robot", "go2", "--out", str(out)]) == 0
    log, want = load_log(out), convert_bag(generic_bag, topics, "go2")
    assert set(log) == set(want)
    for key in want:
        np.testing.assert_array_equal(log[key], want[key], err_msg=key)
    capsys.readouterr()
    bad = _topics(tmp_path, lambda r: r["joint_states"].update(topic="/joints"))
    assert (
        main(["convert", str(generic_bag), "--topics", str(bad), "--robot", "go2", "--out", str(tmp_path / "x.npz")])
        == 1
    )
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "topic '/joints' (joint_states) not found" in err
    assert not (tmp_path / "x.npz").exists()
