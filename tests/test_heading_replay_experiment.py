"""experiments/heading_replay.py's inputs and scores: its scans against the tests' NumPy caster, its odometry
against the truth it integrates, the row of hand-built runs, and a bad argument failing in one line."""

import subprocess
import sys
from types import SimpleNamespace

import numpy as np
import pytest
from _experiments import EXPERIMENTS, load
from _laser2d import cast

replay = load("heading_replay")


def _segments(world, height: float) -> np.ndarray:
    """The sides of every box that reaches above the scan plane, as segments (x0 y0 x1 y1)."""
    out = []
    for c, h, yaw in zip(world.center, world.half, world.yaw):
        if c[2] + h[2] < height:
            continue
        R = np.array([[np.cos(yaw), -np.sin(yaw)], [np.sin(yaw), np.cos(yaw)]])
        corners = np.array([[-h[0], -h[1]], [h[0], -h[1]], [h[0], h[1]], [-h[0], h[1]]]) @ R.T + c[:2]
        out += [[*a, *b] for a, b in zip(corners, np.roll(corners, -1, 0))]
    return np.array(out)


def test_scans_and_odometry_of_a_walk():
    """The scans (cast by kernels.raycast, with range noise 1 % of r^2) against the NumPy caster at the true poses:
    the same returns, and residuals over the noise model's std of unit spread. The walk keeps 0.55 m off the boxes
    after its turn in place, and its odometry starts at the truth."""
    from jaxquad.sim.worlds import box_signed_distance, make_world

    x, truth = replay.inputs(1, 14.0, 3, 0.32)
    world = make_world("warehouse", 3000)
    segments = _segments(world, 0.32)
    z = []
    for k in range(0, truth.shape[1], 4):
        r = cast(segments, truth[0, k], replay.BEARINGS, replay.MAX_RANGE_M)
        got = x["ranges"][0, k]
        assert np.array_equal(np.isfinite(r), np.isfinite(got))
        z.append((got[np.isfinite(r)] - r[np.isfinite(r)]) / (0.01 * r[np.isfinite(r)] ** 2))
    z = np.concatenate(z)
    assert z.size > 500 and abs(z.mean()) < 0.15 and 0.85 < z.std() < 1.15
    assert box_signed_distance(world, truth[0, 105:, :2]).min() > 0.5
    np.testing.assert_allclose(x["odom"][0, 0], truth[0, 0])


def test_odometry_without_yaw_walk_follows_the_truth():
    """With no yaw walk the odometry's heading is the truth's and its position errs only by the 2 mm steps' noise."""
    from jaxquad.sim.worlds import make_world

    truth = replay.walk(make_world("warehouse", 1), np.random.default_rng(0), 40.0)
    odom = replay.drifting_odometry(truth, np.random.default_rng(1), 0.0)
    np.testing.assert_allclose(odom[:, 2], truth[:, 2])
    bound = 5 * 0.002 * np.sqrt(np.arange(len(truth)))  # 5 sigma of the summed step noise
    assert np.all(np.linalg.norm(odom[:, :2] - truth[:, :2], axis=1) <= bound + 1e-9)


def test_score_of_hand_built_runs():
    """Run 0 tracks the truth; run 1's heading is 5 deg off from 3 s on (a runaway at 3 s) and its position 0.6 m off
    for 2.5 s (lost); run 2 is 0.6 m off for 1.5 s only (not lost)."""
    S = 100
    truth = np.zeros((3, S, 3))
    truth[..., 0] = np.linspace(0, 5, S)
    pose = truth.copy()
    pose[1, 30:, 2] += np.deg2rad(5.0)
    pose[1, 50:75, 1] += 0.6
    pose[2, 50:65, 1] += 0.6
    out = SimpleNamespace(pose=pose)
    state = SimpleNamespace(loops=np.array([1, 2, 3]), headings=np.array([10, 20, 30]))
    x = {"odom": truth + [0.0, 0.0, np.deg2rad(2.0)]}
    row = replay.score("v", state, out, x, truth, 1.0)
    assert row["robots"] == 3 and row["runaways"] == 1 and row["runaway_first_s_median"] == pytest.approx(3.0)
    assert row["lost"] == 1 and row["heading_max_deg_median"] == pytest.approx(0.0, abs=1e-9)
    assert row["odometry_heading_final_deg_median"] == pytest.approx(2.0)
    assert row["loops_mean"] == 2.0 and row["priors_mean"] == 20.0
    assert "| v | 3 | 1 | 3 | 1 |" in replay.table([row])


@pytest.mark.parametrize(
    "argv, named",
    [
        (["--seconds", "5"], "--seconds"),
        (["--scan-height", "0"], "--scan-height"),
        (["--params", "no_such_file.yaml"], "no_such_file.yaml"),
    ],
)
def test_bad_arguments_fail_in_one_line(tmp_path, argv, named):
    r = subprocess.run(
        [sys.executable, str(EXPERIMENTS / "heading_replay.py"), *argv],
        cwd=tmp_path,
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert r.returncode == 2 and r.stdout == ""
    last = r.stderr.strip().splitlines()[-1]
    assert last.startswith("heading_replay.py: error: ") and named in last and "Traceback" not in r.stderr
