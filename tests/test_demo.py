"""jaxquad demo: scan/map helpers against brute-force references, the picture geometry against the
scan kernel, and one reduced end-to-end run (marked slow: it compiles the simulator and the
estimation pipeline)."""

from __future__ import annotations

import json

import numpy as np
import pytest

from jaxquad import demo, report
from jaxquad.io import OccupancyMap
from jaxquad.metrics import scan_map_hits


def _random_map(rng, rows=40, cols=50, resolution=0.05, origin=(-1.0, 0.5, 0.0)):
    grid = np.zeros((rows, cols), np.int8)
    grid[rng.random((rows, cols)) < 0.03] = 100
    grid[:3, :] = -1
    return OccupancyMap(grid, resolution, origin)


def test_scan_map_hits_matches_brute_force():
    rng = np.random.default_rng(3)
    occ = _random_map(rng)
    rows, cols = occ.grid.shape
    pts = np.c_[rng.uniform(-1.5, 2.2, 400), rng.uniform(0.0, 2.8, 400)]
    pts[::37] = np.nan
    tol = 0.12
    got = scan_map_hits(pts, occ, tol)
    occ_rc = np.argwhere(occ.grid >= 50)
    expected = np.zeros(len(pts), bool)
    for j, p in enumerate(pts):
        if not np.all(np.isfinite(p)):
            continue
        c = int(np.floor((p[0] - occ.origin[0]) / occ.resolution))
        r = int(np.floor((p[1] - occ.origin[1]) / occ.resolution))
        if not (0 <= r < rows and 0 <= c < cols):
            continue
        d = min(np.hypot(r - rr, c - cc) * occ.resolution for rr, cc in occ_rc)
        expected[j] = d <= tol
    np.testing.assert_array_equal(got, expected)
    assert expected.any() and (~expected).any()


def test_scan_map_hits_empty_map_and_shape():
    occ = OccupancyMap(np.zeros((5, 5), np.int8), 0.1, (0.0, 0.0, 0.0))
    assert scan_map_hits(np.zeros((2, 3, 2)), occ).shape == (2, 3)
    assert not scan_map_hits(np.zeros((2, 3, 2)), occ).any()


def test_band_rows_are_the_rows_the_kernel_samples():
    # Depth grows with the row (z = 1 + 0.01 v), so the kernel's per-column minimum range reveals the
    # smallest row it sampled: range = z sqrt(1 + ((u - cx)/fx)^2).
    from jaxquad.kernels import stabilized_scan

    height, width, h = 60, 80, 5
    K = np.array([[70.0, 0, 39.5], [0, 70.0, 29.5], [0, 0, 1]])
    v = np.arange(height, dtype=np.float32)[:, None]
    depth = np.broadcast_to(1.0 + 0.01 * v, (height, width)).astype(np.float32)
    u = np.arange(width)
    for roll, pitch in ((0.0, 0.0), (0.12, -0.08), (-0.2, 0.15)):
        scan = stabilized_scan(depth, (K[0, 0], K[1, 1], K[0, 2], K[1, 2]), roll, pitch, h, 0.0, 100.0)
        z = np.asarray(scan.ranges) / np.sqrt(1 + ((u - K[0, 2]) / K[0, 0]) ** 2)
        rows = report.band_rows(K, roll, pitch, h, width)
        rows = np.where((rows >= 0) & (rows < height), rows, np.inf)
        np.testing.assert_allclose(z, 1.0 + 0.01 * rows.min(0), rtol=1e-5)


def test_camera_pose_and_scan_points_closed_form():
    yaw = 0.7
    gt = np.array([1.0, 2.0, 0.3, np.cos(yaw / 2), 0.0, 0.0, np.sin(yaw / 2)])
    T = np.eye(4)
    T[:3, 3] = [0.28, 0.0, 0.05]
    xy, heading = demo.camera_pose_2d(gt, T)
    np.testing.assert_allclose(xy, [1.0 + 0.28 * np.cos(yaw), 2.0 + 0.28 * np.sin(yaw)], atol=1e-12)
    assert heading == pytest.approx(yaw)
    pts = report.scan_points_world(np.array([2.0, np.inf, 1.0]), np.array([0.0, 0.1, np.pi / 2]), xy, yaw)
    np.testing.assert_allclose(pts[0], xy + 2.0 * np.array([np.cos(yaw), np.sin(yaw)]), atol=1e-12)
    np.testing.assert_allclose(pts[1], xy + np.array([-np.sin(yaw), np.cos(yaw)]), atol=1e-12)
    assert pts.shape == (2, 2)


def test_frame_samples_latest_at_or_before():
    t = np.arange(1, 101) * 0.004
    depth_t = np.array([0.001, 0.004, 0.0319, 0.032, 0.1999, 0.4, 0.5])
    expected = [max(j for j in range(t.size) if t[j] <= x) if x >= t[0] else 0 for x in depth_t]
    np.testing.assert_array_equal(demo.frame_samples(t, depth_t), expected)


def test_mean_scores_and_table():
    """Means say what they average: drift weighted by segments, delays pooled over matched events,
    a robot with no matched event (NaN) left out instead of counting as 0 ms."""
    delay = lambda mean, n: {"mean_ms": mean, "mean_abs_ms": abs(mean), "n_matched": n, "n_missed": 1}  # noqa: E731
    robots = [
        {
            "scores": {
                "contacts": {"f1": 0.5, "precision": 1.0, "recall": 0.25},
                "drift": {"drift_pct": {"mean": 2.0, "n_segments": 30}, "z_error_final_m": -0.1},
                "delays": {"touchdown": delay(4.0, 3), "liftoff": delay(float("nan"), 0)},
                "trajectory": {"ate": {"rmse": 0.1}, "rpe_2m": {"rmse": 0.3}},
            }
        },
        {
            "scores": {
                "contacts": {"f1": 1.0, "precision": 0.5, "recall": 1.0},
                "drift": {"drift_pct": {"mean": 6.0, "n_segments": 10}, "z_error_final_m": -0.3},
                "delays": {"touchdown": delay(8.0, 1), "liftoff": delay(10.0, 2)},
            }
        },
    ]
    m = demo.mean_scores(robots)
    assert m["contact F1"]["value"] == 0.75 and m["contact F1"]["averages"] == "2 robots"
    assert m["drift % (2-10 m)"]["value"] == (2.0 * 30 + 6.0 * 10) / 40
    assert (
        m["touchdown delay ms"]["value"] == (4.0 * 3 + 8.0) / 4
        and "4 matched events" in m["touchdown delay ms"]["averages"]
    )
    assert m["lift-off delay ms"]["value"] == 10.0
    assert m["ATE m"]["value"] == 0.1 and m["ATE m"]["averages"] == "1 robots"
    assert "force RMSE N" not in m
    text = demo.format_table({"a": m, "b": {}}, {"baseline": {"map_agreement_pct": 50.0, "no_reading_pct": 1.0}})
    assert "0.750" in text and "3.0" in text and "50.0" in text
    assert text.splitlines()[1].split()[-1] == "-"


def test_refuses_foreign_folder(tmp_path):
    (tmp_path / "keep.txt").write_text("x")
    with pytest.raises(ValueError, match="holds no earlier jaxquad demo"):
        demo.run_demo(tmp_path, robots=1, seconds=1.0)
    with pytest.raises(ValueError, match="--robots"):
        demo.run_demo(tmp_path / "new", robots=0)
    assert (tmp_path / "keep.txt").read_text() == "x" and not (tmp_path / "new").exists()


@pytest.mark.slow
def test_demo_end_to_end(tmp_path):
    out = tmp_path / "report"
    s = demo.run_demo(out, robots=1, seconds=1.0, style="aggressive", resolution=(32, 24), progress=False)
    on_disk = json.loads((out / "summary.json").read_text())
    assert on_disk["sources"] == s["sources"] and on_disk["kind"] == "jaxquad demo"
    for name in s["files"]:
        assert (out / name).is_file(), name
    for png in ("trajectories.png", "heights.png", "contacts.png", "scan_frame.png"):
        assert (out / png).read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    for name in (
        "sim/fleet.npz",
        "sim/gt_0000.tum",
        "estimate_tuned/robot_000.tum",
        "estimate_paper/robot_000.tum",
        "estimate_truth/robot_000.npz",
    ):
        assert name in s["files"]
    # The shipped tuned numbers are the default, the paper's beside them, and both are recorded.
    assert list(s["sources"]) == ["tuned", "paper", "truth"]
    assert s["source_params"]["tuned"]["bandwidth"] != s["source_params"]["paper"]["bandwidth"] == 30.0
    # Every parameter of every source's pipeline, and the fleet's configuration, are recorded.
    assert set(s["params"]) == set(s["pipeline_config"]) == set(s["sources"])
    assert s["params"]["tuned"]["observer"]["bandwidth"] == s["source_params"]["tuned"]["bandwidth"]
    assert s["params"]["paper"]["observer"]["bandwidth"] == 30.0 and "floor" in s["params"]["truth"]
    assert s["pipeline_config"]["truth"]["contacts"] == "truth"
    fleet = s["fleet_config"]
    assert (fleet["robot"], fleet["n_robots"], fleet["style"]) == ("go2", 1, "aggressive")
    assert (fleet["width"], fleet["height"]) == (32, 24)
    # Ground-truth contacts scored against ground truth: exact.
    assert s["sources"]["truth"]["contact F1"]["value"] == 1.0
    assert 0.0 <= s["sources"]["tuned"]["contact F1"]["value"] <= 1.0
    for src in s["sources"].values():
        assert all("robots" in v["averages"] or "events" in v["averages"] for v in src.values())
    for band in ("baseline", "stabilized"):
        assert 0 <= s["scans"][band]["map_agreement_pct"] <= 100 and s["scans"][band]["rays"] > 0
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".")]  # no temporary folder left
    # A second run replaces the earlier demo folder.
    (out / "stale.txt").write_text("old")
    demo.run_demo(out, robots=1, seconds=1.0, style="calm", resolution=(32, 24), progress=False)
    assert not (out / "stale.txt").exists() and (out / "summary.json").is_file()
