"""`jaxquad bench --slam` end to end at tiny sizes, with and without gtsam importable."""

import importlib.util
import json

import pytest

from jaxquad.cli import main


@pytest.mark.slow
def test_slam_section_json_without_gtsam(capsys, monkeypatch):
    real = importlib.util.find_spec
    monkeypatch.setattr(importlib.util, "find_spec", lambda name, *a: None if name == "gtsam" else real(name, *a))
    args = [
        "bench",
        "--cpu",
        "--json",
        "--slam",
        "--slam-nodes",
        "60",
        "--slam-batch",
        "2",
        "--slam-batch-nodes",
        "40",
        "--slam-robots",
        "1",
    ]
    assert main(args) == 0
    out = json.loads(capsys.readouterr().out)["sections"]["slam"]
    assert "not importable" in out["gtsam"] and "gtsam_solve_s" not in out["rows"][0]
    assert out["rows"][0]["final_chi2"] < out["rows"][0]["initial_chi2"]
    assert out["batched_converged_fraction"] == 1.0
    assert [r["scans_per_s_per_robot"] > 0 for r in out["occupancy"]] == [True] * 3


def test_bad_slam_sizes_are_one_line_errors(capsys):
    assert main(["bench", "--cpu", "--slam", "--slam-batch", "0"]) == 1
    assert "--slam-batch must be >= 1" in capsys.readouterr().err
