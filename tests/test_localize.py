"""`jaxquad localize` orchestration: parameter files, the chunked fleet run on synthetic scans (NumPy ray
caster), scores, one-line errors, and the benchmark section."""

from __future__ import annotations

import argparse
import dataclasses

import numpy as np
import pytest

from jaxquad.cli import main
from jaxquad.io import OccupancyMap, save_map
from jaxquad.kernels import AmclParams
from jaxquad.localize import field_of_map, load_params, localize_log, localize_scans
from jaxquad.localize.run import _scores
from test_particle_filter import GRID, RES, _cast


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
        ("alpha9: 1\n", "unknown key"), ("sigma_hit: .nan\n", "sigma_hit"), ("max_particles: 2.5\n", "integer"),
        ("recovery_alpha_fast: 2\n", "out of range"), ("laser_min_range: 9\n", "laser_min_range"),
        ("[1, 2]\n", "mapping"), ("a: [\n", "not valid YAML"),
    ]:  # fmt: skip
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
    truth = np.stack([
        np.column_stack([1.0 + 3.5 * s, 1.0 + 0.6 * s, 0.2 + 0 * s]),
        np.column_stack([5.0 - 2.0 * s, 1.2 + 1.0 * s**2, np.pi - 0.5 * s]),
    ])  # fmt: skip
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
    ]:  # fmt: skip
        assert main(argv) == 1
        last = capsys.readouterr().err.strip().splitlines()[-1]  # after any progress-bar lines
        assert last.startswith("jaxquad localize: error:") and words in last


def test_bench_section_runs():
    from jaxquad._bench_localize import run

    res = run(argparse.Namespace(loc_robots=[2], loc_particles=64, loc_beams=8, repeats=1))
    (row,) = res["rows"]
    assert row["robots"] == 2 and row["particles"] == 64 and row["beams"] == 8
    assert row["run_ms"] > 0 and row["beam_evals_per_s"] == pytest.approx(2 * 64 * 8 / (row["run_ms"] * 1e-3))
