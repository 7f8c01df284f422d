"""experiments/navigation.py's bookkeeping: cells run as separate jobs merged into one Table II."""

import json

import pytest
from _experiments import load

navigation = load("navigation", "navigation_experiment")

SETTINGS = {"robots": 4, "goals": 5, "samples": 64}


def _row(robot, world, cell, reached, settings=SETTINGS):
    outcomes = {
        name: 0 for name in ("pending", "reached", "missed", "collided", "lost", "timeout", "fallen", "skipped")
    }
    outcomes |= {"reached": reached, "lost": 20 - reached}
    return {
        "robot": robot,
        "world": world,
        "cell": cell,
        "runs": 4,
        "goals": 20,
        "success_rate": reached / 20,
        "outcomes": outcomes,
        "time_to_goal_median_s": 30.0,
        "loc_error_median_m": 0.05,
        "loc_error_p99_m": 0.2,
        "compile_s": 10.0,
        "run_s": 5.0,
        "robot_seconds_per_s": 40.0,
        "device": "cpu",
        "settings": settings,
    }


def test_merge_joins_cells_and_prints_table_ii(tmp_path, capsys):
    a, b = tmp_path / "a.json", tmp_path / "b.json"
    a.write_text(json.dumps([_row("go2", "house", "full", 19), _row("go2", "house", "baseline", 3)]))
    b.write_text(json.dumps([_row("badger", "warehouse", "full", 10, SETTINGS | {"max_seconds": 900.0})]))
    rows = navigation.main(["--merge", str(a), str(b), "--json", str(tmp_path / "t.json")])
    assert [r["robot"] for r in rows] == ["go2", "go2", "badger"]
    out = capsys.readouterr().out
    # Rows by method in CELLS order, columns by world / robot as first seen; a cell not run shows "-".
    assert "| baseline | 15.0% of 20 | - |" in out
    assert "| full | 95.0% of 20 | 50.0% of 20 |" in out
    assert json.loads((tmp_path / "t.json").read_text()) == rows


def test_merge_refuses_a_cell_twice_different_settings_and_non_results(tmp_path):
    a, b, c, d = (tmp_path / f"{k}.json" for k in "abcd")
    a.write_text(json.dumps([_row("go2", "house", "full", 19)]))
    b.write_text(json.dumps([_row("go2", "house", "full", 12)]))
    c.write_text(json.dumps([_row("go2", "warehouse", "full", 12, SETTINGS | {"robots": 100})]))
    d.write_text(json.dumps({"cells": []}))
    with pytest.raises(ValueError, match="also in"):
        navigation.merge([str(a), str(b)])
    with pytest.raises(ValueError, match="settings"):
        navigation.merge([str(a), str(c)])
    with pytest.raises(ValueError, match="not a saved navigation result"):
        navigation.merge([str(a), str(d)])
    with pytest.raises(ValueError, match="not a saved navigation result"):
        navigation.merge([str(tmp_path / "missing.json")])


def test_merge_of_a_missing_file_is_a_one_line_usage_error(tmp_path, capsys):
    with pytest.raises(SystemExit) as e:
        navigation.main(["--merge", str(tmp_path / "missing.json")])
    assert e.value.code == 2 and "missing.json: not a saved navigation result" in capsys.readouterr().err
