"""experiments/exploration_errors.py on traces written by experiments/exploration.py --traces: the summary
against values built into synthetic traces, and the file round trip."""

import importlib.util
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest
from scipy.stats import norm

from jaxquad.explore import OUTCOMES


def _module(name):
    spec = importlib.util.spec_from_file_location(
        name, Path(__file__).resolve().parents[1] / "experiments" / f"{name}.py"
    )
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


errors, exploration = _module("exploration_errors"), _module("exploration")

T = np.arange(1, 1251) * 0.096  # 1250 ticks, to 120 s


def _traces():
    n = 3
    t = T.astype(np.float32)
    err = np.tile(0.001 * np.arange(len(t))[:, None], (1, n)).astype(np.float32)
    err[500, 1] += 0.2  # run 1 jumps once by 0.2 m (and back)
    active = np.ones((len(t), n), bool)
    end = np.full(n, np.nan)
    end[1] = t[800]
    active[801:, 1] = False
    true_pose = np.zeros((len(t), n, 3), np.float32)
    true_pose[..., 2] = np.pi - 0.01  # the SLAM heading across the +-pi seam: 0.02 rad off, not 2 pi - 0.02
    pose = true_pose.copy()
    pose[..., 2] = -np.pi + 0.01
    outcome = np.array([OUTCOMES.index("running"), OUTCOMES.index("lost"), OUTCOMES.index("collided")])
    return dict(t=t, error=err, active=active, outcome=outcome, end_t=end, pose=pose, true_pose=true_pose)


def test_summary_medians_lost_runs_and_the_random_walk():
    s = errors.summarize(_traces(), yaw_walk=np.deg2rad(0.2))
    assert s["runs"] == 3 and s["lost"] == 1
    m1, m2 = s["per_minute"]  # 120 s of samples, the last a tick before 120 s
    k = np.searchsorted(T, 60.0)
    assert m1["active_runs"] == 3 and m1["position_error_median_m"] == pytest.approx(0.001 * k, rel=1e-5)
    assert m2["active_runs"] == 2  # the lost run ended at 76.9 s
    assert m1["heading_error_median_deg"] == pytest.approx(np.degrees(0.02), abs=1e-3)
    assert m2["imu_yaw_walk_median_deg"] == pytest.approx(norm.ppf(0.75) * 0.2 * np.sqrt(120.0), rel=1e-3)
    (run,) = s["lost_runs"]
    assert run["run"] == 1 and run["end_s"] == pytest.approx(T[800], rel=1e-6)
    assert run["largest_tick_change_m"] == pytest.approx(0.201, rel=1e-4)


def test_traces_round_trip_and_bad_files(tmp_path):
    d = _traces()
    config = SimpleNamespace(robot="go2", world="warehouse", variant="full", seed=0)
    extra = dict(coverage=d["error"], distance=np.ones(3), nodes=np.ones(3), loops=np.zeros(3), starts=np.zeros((3, 3)))
    result = SimpleNamespace(config=config, **d, **extra)
    exploration.save_traces(tmp_path / "cell.npz", result)
    back = errors.load(tmp_path / "cell.npz")
    np.testing.assert_array_equal(back["pose"], d["pose"])
    assert str(back["world"]) == "warehouse" and int(back["seed"]) == 0
    errors.plot(back, np.deg2rad(0.2), tmp_path / "errors.png")
    assert (tmp_path / "errors.png").stat().st_size > 0

    np.savez(tmp_path / "other.npz", t=d["t"])
    with pytest.raises(SystemExit, match="lacks error"):
        errors.load(tmp_path / "other.npz")
    (tmp_path / "broken.npz").write_text("not a zip")
    with pytest.raises(SystemExit, match="cannot read"):
        errors.load(tmp_path / "broken.npz")
