"""Short MJX fleet runs (slow: one compile per robot): logs validate, physics and sensors agree."""

import shutil

import numpy as np
import pytest

from jaxquad.io import load_log, load_map, read_tum, robot_log
from jaxquad.sim.cli import simulate
from jaxquad.sim.fleet import GT_CONTACT_MIN_FORCE, FleetConfig


def _R(q_wxyz: np.ndarray) -> np.ndarray:
    w, x, y, z = np.moveaxis(q_wxyz, -1, 0)
    return np.stack(
        [
            np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)], -1),
            np.stack([2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)], -1),
            np.stack([2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)], -1),
        ],
        -2,
    )


@pytest.mark.slow
@pytest.mark.parametrize("robot", ["go2", "badger"])
def test_fleet_run(robot, tmp_path, monkeypatch):
    cfg = FleetConfig(robot=robot, n_robots=2, n_worlds=2, frames_per_chunk=16, seed=1, width=32, height=24)
    log = load_log(simulate(cfg, 2.0, tmp_path / "a", progress=False))  # load_log validates
    n, T = 2, log["t"].shape[0]
    assert log["q"].shape[:2] == (n, T) and T * 0.004 >= 2.0
    assert log["depth"].shape[:2] == (n, log["depth_t"].shape[0]) and log["depth"].shape[2:] == (24, 32)
    assert not log["fallen"].any() and log["valid"].all() and not log["collided"].any()
    np.testing.assert_allclose(np.diff(log["t"]), 0.004, rtol=1e-9)
    assert (log["depth"] > 0).mean() > 0.3  # walls and furniture in view, mostly valid

    # Ground-truth TUM files hold the logged base poses (x y z qx qy qz qw).
    for i in range(n):
        traj = read_tum(tmp_path / "a" / f"gt_{i:04d}.tum")
        np.testing.assert_allclose(traj.p_world_body, log["gt_pose"][i, :, :3], atol=1e-6)
        np.testing.assert_allclose(
            np.abs(np.sum(traj.q_world_body_xyzw * log["gt_pose"][i, :, [4, 5, 6, 3]].T, -1)), 1.0, atol=1e-5
        )
    assert load_map(tmp_path / "a" / "map_house_1.yaml").grid.shape[0] > 100

    # The accelerometer reads specific force: rotated to the world and averaged over the walk it
    # is +g upward (the mean acceleration of a walking base over 2 s is small).
    pose = log["gt_pose"]
    acc_world = np.einsum("ntij,ntj->nti", _R(pose[..., 3:7]), log["acc"])  # IMU site axes = base axes
    np.testing.assert_allclose(acc_world[:, T // 4 :].mean(1), np.tile([0, 0, 9.81], (n, 1)), atol=0.8)
    # The floor only pushes (normal force up, within the friction cone); feet in the air carry none.
    f = log["gt_force"]
    assert np.all(f[..., 2] >= -1e-3)
    assert np.all(
        np.linalg.norm(f[..., :2], axis=-1) <= 1.8 * f[..., 2] + 1e-3
    )  # pyramid: each tangent axis <= mu (<= 1.2) * normal
    assert np.all(f[..., 2][~log["gt_contact"]] <= GT_CONTACT_MIN_FORCE)  # gt_contact: load above 1 N
    one = robot_log(log, 0)
    assert one["q"].shape == (T, len(log["joint_names"]))

    if robot == "go2":
        # Same seed, same log (the second run reuses the compiled chunk); another seed differs.
        again = load_log(simulate(cfg, 2.0, tmp_path / "b", progress=False))
        for k in ("q", "acc", "gt_pose", "depth"):
            np.testing.assert_array_equal(again[k], log[k])
        other = load_log(simulate(FleetConfig(**{**cfg.__dict__, "seed": 2}), 2.0, tmp_path / "c", progress=False))
        assert not np.allclose(other["gt_pose"], log["gt_pose"])

        # A disk without room for the log twice (memory-mapped arrays, then fleet.npz) is refused
        # before simulating, and nothing is left at the output path.
        F = log["depth_t"].shape[0]
        need = 2 * sum(v.nbytes for v in log.values() if v.ndim >= 2 and v.shape[:2] in ((n, T), (n, F)))
        for free, refused in ((need - 1, True), (need, False)):
            usage = shutil._ntuple_diskusage(10 * need, 0, free)
            monkeypatch.setattr(shutil, "disk_usage", lambda _folder, u=usage: u)
            if refused:
                with pytest.raises(ValueError, match="the log needs .* GB"):
                    simulate(cfg, 2.0, tmp_path / "d", progress=False)
                assert not (tmp_path / "d").exists()
            else:
                simulate(cfg, 2.0, tmp_path / "d", progress=False)
