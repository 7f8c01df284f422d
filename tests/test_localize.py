"""`jaxquad localize` orchestration: parameter files, the chunked fleet run on synthetic scans (NumPy ray
caster), scores, one-line errors, and the benchmark section."""

from __future__ import annotations

import argparse
import dataclasses

import numpy as np
import pytest
from test_particle_filter import GRID, RES, _cast

from jaxquad.cli import main
from jaxquad.io import OccupancyMap, save_map
from jaxquad.kernels import AmclParams
from jaxquad.localize import field_of_map, load_params, localize_log, localize_scans
from jaxquad.localize.run import _scores


def test_default_file_matches_kernel_defaults():
    lp = load_params()
    got, ref = lp.amcl(), AmclParams.paper(n_beams=60)
    for f in dataclasses.fields(AmclParams):
        if f.name != "n_beams":
            np.testing.assert_allclose(np.asarray(getattr(got, f.name)), np.asarray(getattr(ref, f.name)), rtol=1e-4)
    assert lp.max_particles == 2000 and lp.max_beams == got.n_beams == 60


def test_params_file_overrides_and_errors(tmp_path):
    p = tmp_path / "amcl.yaml"
    p.write_text("amcl:\n  ros__parameters:\n    alpha1: 0.05\n    max_particles: 500\n")  # Nav2 layout
    lp = load_params(p, max_particles=None)
    assert lp.alpha1 == 0.05 and lp.max_particles == 500 and lp.alpha2 == 0.2
    assert load_params(p, max_particles=64).max_particles == 64
    for text, words in [
        ("alpha9: 1\n", "unknown key"),
        ("sigma_hit: .nan\n", "sigma_hit"),
        ("max_particles: 2.5\n", "integer"),
        ("recovery_alpha_fast: 2\n", "out of range"),
        ("laser_min_range: 9\n", "laser_min_range"),
        ("[1, 2]\n", "mapping"),
        ("a: [\n", "not valid YAML"),
    ]:
        p.write_text(text)
        with pytest.raises(ValueError, match=words):
            load_params(p)
    with pytest.raises(FileNotFoundError):
        load_params(tmp_path / "missing.yaml")


def test_fleet_run_tracks_truth():
    """Two robots along different paths in the test room, odometry with scale and heading drift; the
    chunked, vmapped run must stay near the truth where the odometry alone drifts away."""
    field = field_of_map(OccupancyMap(GRID, RES, (0.0, 0.0, 0.0)), 2.0)
    bearings = np.linspace(-0.75 * np.pi, 0.75 * np.pi, 90)
    s = np.linspace(0.0, 1.0, 50)
    truth = np.stack(
        [
            np.column_stack([1.0 + 3.5 * s, 1.0 + 0.6 * s, 0.2 + 0 * s]),
            np.column_stack([5.0 - 2.0 * s, 1.2 + 1.0 * s**2, np.pi - 0.5 * s]),
        ]
    )
    odom = np.concatenate([truth[..., :2] * 1.15, truth[..., 2:] * 1.1], -1)
    ranges = np.stack([[_cast(GRID, p, bearings, 8.0) for p in tr] for tr in truth])
    lp = load_params()
    params = AmclParams.paper(update_min_d=0.1, update_min_a=0.1)
    out = localize_scans(params, field, odom, ranges, bearings, 500, truth[:, 0], seed=1)
    assert out.pose.shape == (2, 50, 3) and out.updated.shape == (2, 50)
    err = np.hypot(*(out.pose[..., :2] - truth[..., :2]).transpose(2, 0, 1))
    drift = np.hypot(*((odom - odom[:, :1] + truth[:, :1]) - truth)[..., :2].transpose(2, 0, 1))
    assert np.all(drift[:, -1] > 0.3)
    assert np.all(err[:, -10:] < 0.2), err[:, -10:]
    assert lp.seed == 0


def test_scores_by_hand():
    t = np.arange(6.0)
    gt = np.zeros((6, 3))
    pose = np.array([[3.0, 0, 0], [0, 2.0, 0], [0.4, 0, 0], [0.9, 0, 0], [0.1, 0, 0], [0, 0.2, 0.5]])
    valid = np.array([True, True, True, True, True, True])
    res = _scores(t, pose, gt, valid, global_=True)
    assert res["position_error_median_m"] == pytest.approx(np.median([3, 2, 0.4, 0.9, 0.1, 0.2]))
    assert res["position_error_max_m"] == pytest.approx(3.0)
    assert res["converged_after_s"] == 4.0  # the error stays below 0.5 m from t = 4 on (0.9 at t = 3)
    valid[3] = False  # an invalid (fallen) frame does not count
    assert _scores(t, pose, gt, valid, global_=True)["converged_after_s"] == 2.0


def test_errors_are_one_line(tmp_path, capsys):
    occ = OccupancyMap(GRID, RES, (0.0, 0.0, 0.0))
    with pytest.raises(ValueError, match="no depth"):
        localize_log({"t": np.arange(3.0)}, occ, load_params())
    with pytest.raises(ValueError, match="yaw"):
        field_of_map(OccupancyMap(GRID, RES, (0.0, 0.0, 0.3)), 2.0)
    save_map(tmp_path / "map.yaml", occ)
    blocker = tmp_path / "file"
    blocker.write_text("x")
    log, good_map, out = str(tmp_path / "log.npz"), str(tmp_path / "map.yaml"), str(tmp_path / "o")
    for argv, words in [
        (["localize", log, "--map", good_map, "--out", str(blocker), "--global"], "not a folder"),
        (["localize", log, "--map", str(tmp_path / "no.yaml"), "--out", out, "--global"], "map file not found"),
        (["localize", log, "--map", good_map, "--out", out, "--global"], "log"),
        (["localize", log, "--map", good_map, "--out", out, "--global", "--particles", "0"], "--particles"),
    ]:
        assert main(argv) == 1
        last = capsys.readouterr().err.strip().splitlines()[-1]  # after any progress-bar lines
        assert last.startswith("jaxquad localize: error:") and words in last


def test_bench_section_runs():
    from jaxquad._bench_localize import run

    res = run(argparse.Namespace(loc_robots=[2], loc_particles=64, loc_beams=8, repeats=1))
    (row,) = res["rows"]
    assert row["robots"] == 2 and row["particles"] == 64 and row["beams"] == 8
    assert row["run_ms"] > 0 and row["beam_evals_per_s"] == pytest.approx(2 * 64 * 8 / (row["run_ms"] * 1e-3))


@pytest.mark.slow
def test_cli_end_to_end_on_a_log_with_depth(tmp_path):
    """The fixed-feet log of test_pipeline with depth frames ray cast (kernels.raycast) in a walled
    room: `jaxquad localize` writes its files and, started at the truth, stays at the truth."""
    import json

    import jax.numpy as jnp
    import mujoco
    from test_pipeline import fixed_feet_log as make_log

    from jaxquad.io import read_tum, save_log
    from jaxquad.kernels import Boxes, cast_depth, pinhole_rays
    from jaxquad.robots import load

    log = dict(make_log.__wrapped__(load("go2")))
    # Room 6 m x 4 m around the origin, walls 0.2 m thick and 1 m high, and a block for asymmetry.
    center = np.array([[0, 2.1, 0.5], [0, -2.1, 0.5], [3.1, 0, 0.5], [-3.1, 0, 0.5], [1.5, 1.0, 0.5]])
    half = np.array([[3.2, 0.1, 0.5], [3.2, 0.1, 0.5], [0.1, 2.2, 0.5], [0.1, 2.2, 0.5], [0.3, 0.6, 0.5]])
    boxes = Boxes(jnp.asarray(center, jnp.float32), jnp.asarray(half, jnp.float32), jnp.zeros(5))
    K = np.array([[30.0, 0, 29.5], [0, 30.0, 19.5], [0, 0, 1]])
    T_base_camera = np.eye(4)
    T_base_camera[:3, :3] = [[0, 0, 1], [-1, 0, 0], [0, -1, 0]]  # optical frame looking along base x
    T_base_camera[:3, 3] = [0.28, 0.0, 0.05]
    rays = jnp.asarray(pinhole_rays(K, 40, 60))
    frames = np.arange(5, log["t"].size, 20)
    depth = []
    for k in frames:
        R = np.zeros(9)
        mujoco.mju_quat2Mat(R, log["gt_pose"][k, 3:])
        R_world_cam = R.reshape(3, 3) @ T_base_camera[:3, :3]
        p_world_cam = log["gt_pose"][k, :3] + R.reshape(3, 3) @ T_base_camera[:3, 3]
        # The floor plane at z = 10 m lies above the camera, so no ray hits it: walls and block only.
        d = np.asarray(
            cast_depth(jnp.asarray(p_world_cam, jnp.float32), jnp.asarray(R_world_cam, jnp.float32), rays, boxes, 10.0)
        )
        depth.append(np.where(np.isfinite(d), d, 0.0))
    log.update(depth=np.stack(depth).astype(np.float32), depth_t=log["t"][frames], K=K, T_base_camera=T_base_camera)
    log_path = save_log(tmp_path / "log.npz", log)
    occ = OccupancyMap(np.zeros((100, 140), np.int8), 0.05, (-3.5, -2.5, 0.0))
    xy = occ.cell_centers()
    inside = np.any(np.all(np.abs(xy[..., None, :] - center[:, :2]) <= half[:, :2], -1), -1)
    occ.grid[inside] = 100
    save_map(tmp_path / "map.yaml", occ)
    out = tmp_path / "out"
    argv = [
        "localize",
        str(log_path),
        "--map",
        str(tmp_path / "map.yaml"),
        "--out",
        str(out),
        "--initial-pose-gt",
        "--contacts",
        "truth",
        "--particles",
        "300",
    ]
    assert main(argv) == 0
    summary = json.loads((out / "summary.json").read_text())
    (robot,) = summary["robots"]
    assert robot["scans"] == frames.size and robot["updates"] >= 1
    assert summary["params"]["max_particles"] == 300 and summary["params"]["sigma_hit"] == 0.2
    assert robot["scores"]["position_error_median_m"] < 0.15
    traj = read_tum(out / "robot.tum")
    np.testing.assert_allclose(traj.t_s, log["t"][frames])
    with np.load(out / "robot.npz") as z:
        np.testing.assert_allclose(z["pose"][:, :2], traj.p_world_body[:, :2], atol=1e-6)
