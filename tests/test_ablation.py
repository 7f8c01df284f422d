"""The ablation experiment (experiments/ablation.py): its statistics against closed forms, and a
CPU smoke run of the whole table (simulate, estimate, depth odometry, SLAM per variant)."""

import json

import numpy as np
import pytest
from _experiments import load

ablation = load("ablation")


def test_statistics_against_closed_forms():
    v = np.array([0.31, 0.42, 0.28, 0.55, 0.39, np.nan])  # a run without a score is left out
    s = ablation.statistics(v)
    x = v[:5]
    mean = x.sum() / 5
    std = np.sqrt(((x - mean) ** 2).sum() / 4)
    half = 2.7764451051977987 * std / np.sqrt(5)  # Student t, 4 degrees of freedom, 97.5 % (tables)
    assert s["n"] == 5
    np.testing.assert_allclose([s["mean"], s["std"], *s["ci95"]], [mean, std, mean - half, mean + half], rtol=1e-12)
    assert ablation.statistics(np.array([np.nan]))["mean"] is None


def test_paired_tests_against_closed_forms():
    from scipy import stats

    a = np.array([0.30, 0.35, 0.28, 0.41, 0.33])
    b = np.array([0.52, 0.61, 0.49, 0.80, 0.70])
    out = ablation.paired_tests(a, b)
    d = a - b
    t = d.mean() / (d.std(ddof=1) / np.sqrt(5))
    assert out["n"] == 5 and out["mean_difference"] == pytest.approx(d.mean())
    assert out["t_test_p"] == pytest.approx(2 * stats.t.sf(abs(t), 4), rel=1e-9)
    # Exact Wilcoxon signed-rank: all 5 differences of one sign, p = 2 / 2^5 (two-sided).
    assert out["wilcoxon_p"] == pytest.approx(2 / 32)
    # Runs one side did not score are not paired; identical columns have no test.
    b_missing = b.copy()
    b_missing[0] = np.nan
    assert ablation.paired_tests(a, b_missing)["n"] == 4
    assert ablation.paired_tests(a, a)["t_test_p"] is None


@pytest.mark.slow
def test_ablation_smoke_on_cpu(tmp_path):
    out = tmp_path / "table.json"
    result = ablation.main(
        [
            "--runs",
            "2",
            "--seconds",
            "3",
            "--variants",
            "B+LO",
            "full",
            "--quiet",
            "--json",
            str(out),
            "--figures",
            str(tmp_path / "fig"),
        ]
    )
    saved = json.loads(out.read_text())
    assert saved["cells"][0]["runs"] == 2 and saved["settings"]["variants"] == ["B+LO", "full"]
    cell = result["cells"][0]
    standing = 2 - cell["fallen"]
    assert standing >= 1
    for name in ("B+LO", "full"):
        ate = np.array([np.nan if s is None else s for s in cell["scores"][name]["ate"]], float)
        assert np.isfinite(ate).sum() == standing and np.all(ate[np.isfinite(ate)] > 0)
        assert cell["statistics"][name]["ate"]["mean"] == pytest.approx(np.nanmean(ate))
    # The two differ in their scans only (baseline vs stabilized): the same logs, different trajectories.
    assert cell["scores"]["B+LO"]["ate"] != cell["scores"]["full"]["ate"]
    assert cell["full_vs"]["B+LO"]["ate"]["n"] == standing
    figures = sorted(p.name for p in (tmp_path / "fig").iterdir())
    assert figures == ["map_go2_house_B_LO.png", "map_go2_house_full.png", "trajectories_go2_house.png"]


def _saved(path, robot, variants, wall_s, rng):
    """A saved one-cell result as main() writes it, with random scores."""
    scores = {v: {m: list(rng.uniform(0.1, 2.0, 3)) for m in ablation.METRICS} for v in variants}
    arr = lambda v, m: np.array(scores[v][m])  # noqa: E731
    record = {
        "robot": robot,
        "world": "house",
        "runs": 3,
        "fallen": 0,
        "seconds": 20.0,
        "scores": scores,
        "statistics": {v: {m: ablation.statistics(arr(v, m)) for m in ablation.METRICS} for v in variants},
        "full_vs": {
            v: {m: ablation.paired_tests(arr("full", m), arr(v, m)) for m in ablation.METRICS}
            for v in variants
            if v != "full"
        },
    }
    path.write_text(
        json.dumps({"device": "cpu", "wall_s": wall_s, "settings": {"variants": variants}, "cells": [record]})
    )
    return record


def test_merge_joins_cells_run_apart(tmp_path, capsys):
    rng = np.random.default_rng(0)
    a = _saved(tmp_path / "a.json", "go2", ["B+LO", "full"], 10.0, rng)
    b = _saved(tmp_path / "b.json", "badger", ["B+LO", "full"], 32.5, rng)
    out = tmp_path / "table.json"
    merged = ablation.main(["--merge", str(tmp_path / "a.json"), str(tmp_path / "b.json"), "--json", str(out)])
    assert [c["robot"] for c in merged["cells"]] == ["go2", "badger"] and merged["wall_s"] == 42.5
    assert json.loads(out.read_text())["cells"][1]["scores"] == b["scores"]
    text = capsys.readouterr().out
    mean = a["statistics"]["full"]["ate"]["mean"]
    assert "| go2 | house | 3 | ate |" in text and f"{mean:.2f} +- " in text and "| badger | house |" in text
    _saved(tmp_path / "c.json", "go2", ["B", "full"], 1.0, rng)
    with pytest.raises(SystemExit):  # variants differ: one table cannot hold both
        ablation.main(["--merge", str(tmp_path / "a.json"), str(tmp_path / "c.json")])
    (tmp_path / "d.json").write_text("[1, 2]")
    with pytest.raises(SystemExit):
        ablation.main(["--merge", str(tmp_path / "d.json")])
