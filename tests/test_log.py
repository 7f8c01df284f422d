"""Log format: round trip, atomic write, fleet slicing and one-line validation errors."""

import numpy as np
import pytest

from jaxquad.io import load_log, robot_log, save_log, validate_log


def _log(T: int = 50, nj: int = 12) -> dict[str, np.ndarray]:
    rng = np.random.default_rng(0)
    quat = rng.normal(size=(T, 4))
    return {
        "t": np.arange(T) * 0.005,
        "robot": np.array("go2"),
        "joint_names": np.array([f"j{i}" for i in range(nj)]),
        "q": rng.uniform(-1, 1, (T, nj)),
        "qd": rng.normal(size=(T, nj)),
        "gyro": rng.normal(0, 0.3, (T, 3)),
        "acc": np.tile([0.0, 0.0, 9.81], (T, 1)) + rng.normal(0, 0.1, (T, 3)),
        "quat_wxyz": quat / np.linalg.norm(quat, axis=1, keepdims=True),
        "depth": rng.uniform(0, 8, (3, 6, 8)).astype(np.float32),
        "depth_t": np.array([0.0, 0.033, 0.066]),
        "K": np.array([[4.0, 0, 4], [0, 4, 3], [0, 0, 1]]),
        "T_base_camera": np.eye(4),
        "gt_force": np.zeros((T, 4, 3)),
    }


def _fleet(n: int = 3) -> dict[str, np.ndarray]:
    single = _log()
    fleet = {
        k: (v if k in ("t", "robot", "joint_names", "depth_t", "K", "T_base_camera") else np.stack([v] * n))
        for k, v in single.items()
    }
    fleet["fallen"] = np.array([False, True, False])
    fleet["valid"] = np.ones((n, 50), bool)
    return fleet


def test_round_trip_and_fleet_slice(tmp_path):
    log = _log()
    save_log(tmp_path / "a.npz", log)
    back = load_log(tmp_path / "a.npz")
    assert set(back) == set(log)
    for k in log:
        np.testing.assert_array_equal(back[k], log[k])
    assert not list(tmp_path.glob(".*tmp"))  # no temp file left behind
    fleet = _fleet()
    save_log(tmp_path / "f.npz", fleet)
    one = robot_log(load_log(tmp_path / "f.npz"), 1)
    validate_log(one)
    np.testing.assert_array_equal(one["q"], log["q"])


def _broken(edit):
    log = _log()
    edit(log)
    return log


@pytest.mark.parametrize(
    "edit, message",
    [
        (lambda g: g.pop("gyro"), "missing required key"),
        (lambda g: g.__setitem__("gyro", np.rad2deg(g["gyro"]) * 20), "looks like deg/s"),
        (lambda g: g.__setitem__("acc", g["acc"] / 9.81), "units of g"),
        (lambda g: g.__setitem__("q", np.rad2deg(g["q"]) * 10), "looks like degrees"),
        (lambda g: g.__setitem__("quat_wxyz", g["quat_wxyz"] * 1.1), "not unit"),
        (lambda g: g.__setitem__("t", g["t"][::-1].copy()), "not strictly increasing"),
        (lambda g: g.__setitem__("qd", g["qd"][:, :5]), "'qd' has shape"),
        (lambda g: g["q"].__setitem__(slice(None), np.nan), "'q' has no finite reading"),
        (lambda g: g["gt_force"].__setitem__((3, 0, 2), np.inf), "'gt_force' contains NaN or inf"),
        (lambda g: g["gyro"].__setitem__((4, 1), 90.0), "looks like deg/s"),
        (lambda g: g.pop("K"), "depth needs all of"),
        (lambda g: g.__setitem__("depth", g["depth"] * 1000), "millimetres"),
        (lambda g: g.__setitem__("T_base_camera", 2 * np.eye(4)), "orthonormal"),
    ],
)
def test_validation_names_the_problem(edit, message):
    with pytest.raises(ValueError, match=message) as info:
        validate_log(_broken(edit))
    assert "\n" not in str(info.value)


def test_dropped_sensor_samples_are_kept_for_the_estimator(tmp_path):
    # A robot drops readings: they stay NaN/inf in the log, and the estimator flags and holds them.
    log = _log()
    log["q"][3, 2] = np.nan
    log["gyro"][7] = np.inf
    log["acc"][9] = np.nan
    log["quat_wxyz"][11] = np.nan
    save_log(tmp_path / "dropped.npz", log)
    back = load_log(tmp_path / "dropped.npz")
    assert np.isnan(back["q"][3, 2]) and np.all(np.isinf(back["gyro"][7]))
    np.testing.assert_array_equal(back["q"][:3], log["q"][:3])


def test_fleet_validation_and_save_refuses_bad_log(tmp_path):
    fleet = _fleet()
    fleet["valid"] = fleet["valid"][:, :10]
    with pytest.raises(ValueError, match="'valid' must be"):
        validate_log(fleet)
    with pytest.raises(ValueError, match="missing required"):
        save_log(tmp_path / "bad.npz", {"t": np.arange(3.0)})
    assert not list(tmp_path.iterdir())
    with pytest.raises(FileNotFoundError):
        load_log(tmp_path / "none.npz")


def test_empty_and_text_files_fail_in_one_line(tmp_path):
    empty, text = tmp_path / "empty.npz", tmp_path / "notes.npz"
    empty.write_bytes(b"")
    text.write_text("t q gyro\n1 2 3\n")
    with pytest.raises(ValueError, match="empty"):
        load_log(empty)
    with pytest.raises(ValueError, match="not an .npz archive"):
        load_log(text)
