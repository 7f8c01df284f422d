"""g2o files: exact round trip, one-line errors with line numbers, and the `jaxquad posegraph` command."""

import json

import gtsam
import numpy as np
import pytest

from jaxquad.cli import main
from jaxquad.io.g2o import G2oGraph, read_g2o, write_g2o
from jaxquad.slam import manhattan_graph


def _graph(n=60, seed=0, step=3, fixed=()):
    sg = manhattan_graph(n, seed=seed)
    ids = 7 + step * np.arange(n)  # non-contiguous ids
    info = sg.information.copy()
    info[:, 0, 1] = info[:, 1, 0] = 12.5  # off-diagonal terms survive the round trip
    return G2oGraph(
        ids,
        sg.initial,
        np.asarray(fixed, np.int64),
        np.stack([ids[sg.edge_i], ids[sg.edge_j]], 1),
        sg.measurement,
        info,
    )


def test_round_trip_is_exact(tmp_path):
    g = _graph(fixed=[7, 10])
    write_g2o(tmp_path / "g.g2o", g)
    back = read_g2o(tmp_path / "g.g2o")
    for f in ("ids", "poses", "fixed_ids", "edge_ids", "measurement", "information"):
        assert np.array_equal(getattr(back, f), getattr(g, f)), f
    assert back.fixed_mask().sum() == 2 and back.fixed_mask()[:2].all()
    np.testing.assert_array_equal(back.ids[back.edge_index()], back.edge_ids)


def test_reads_what_gtsam_reads(tmp_path):
    g = _graph(n=30, seed=4)
    write_g2o(tmp_path / "g.g2o", g)
    graph, values = gtsam.readG2o(str(tmp_path / "g.g2o"), False)
    for k, vid in enumerate(g.ids):
        p = values.atPose2(int(vid))
        np.testing.assert_allclose([p.x(), p.y(), p.theta()], g.poses[k], atol=1e-12)
    assert graph.size() == len(g.edge_ids)


@pytest.mark.parametrize(
    "line, message",
    [
        ("VERTEX_SE2 5 1.0 2.0", "VERTEX_SE2 needs 4 values"),
        ("VERTEX_SE2 5 1.0 x 0.0", "not a number"),
        ("VERTEX_SE2 5.5 1.0 2.0 0.0", "not an integer"),
        ("VERTEX_SE2 0 1 2 3", "declared twice"),
        ("VERTEX_SE2 9 nan 2 3", "non-finite"),
        ("EDGE_SE2 0 1 1 0 0 1 0 0 1 0", "EDGE_SE2 needs 11 values"),
        ("EDGE_SE2 0 42 1 0 0 1 0 0 1 0 1", "vertex 42"),
        ("EDGE_SE2 0 1 1 0 0 1 5 0 1 0 1", "positive semidefinite"),
        ("VERTEX_XY 3 1 2", "unknown tag 'VERTEX_XY'"),
        ("FIX", "FIX needs"),
    ],
)
def test_malformed_line_names_file_and_line(tmp_path, line, message):
    path = tmp_path / "bad.g2o"
    path.write_text(f"# header\nVERTEX_SE2 0 0 0 0\nVERTEX_SE2 1 1 0 0\n{line}\n")
    with pytest.raises(ValueError, match=rf"bad\.g2o:4: .*{message}"):
        read_g2o(path)


def test_empty_and_missing_files(tmp_path):
    (tmp_path / "e.g2o").write_text("# nothing\n")
    with pytest.raises(ValueError, match="no VERTEX_SE2"):
        read_g2o(tmp_path / "e.g2o")
    (tmp_path / "f.g2o").write_text("VERTEX_SE2 0 0 0 0\nFIX 3\n")
    with pytest.raises(ValueError, match="FIX names vertex 3"):
        read_g2o(tmp_path / "f.g2o")
    with pytest.raises(FileNotFoundError):
        read_g2o(tmp_path / "missing.g2o")


def test_cli_optimizes_and_keeps_ids_and_edges(tmp_path, capsys):
    g = _graph(n=80, seed=2)
    write_g2o(tmp_path / "in.g2o", g)
    assert main(["posegraph", str(tmp_path / "in.g2o"), "--out", str(tmp_path / "out.g2o"), "--json"]) == 0
    summary = json.loads(capsys.readouterr().out)
    out = read_g2o(tmp_path / "out.g2o")
    assert np.array_equal(out.ids, g.ids) and np.array_equal(out.edge_ids, g.edge_ids)
    assert np.array_equal(out.measurement, g.measurement) and np.array_equal(out.information, g.information)
    assert np.array_equal(out.poses[0], g.poses[0])  # first vertex held fixed (no FIX line)
    assert summary["n_nodes"] == 80 and summary["n_edges"] == len(g.edge_ids)
    assert summary["final_chi2"] < summary["initial_chi2"] and summary["converged"]
    assert summary["solve_s"] > 0 and summary["compile_s"] > 0 and summary["iterations"] >= 1
    # The reported chi2 is g2o's at the written poses (independent NumPy evaluation).
    p = dict(zip(out.ids, out.poses))
    chi2 = 0.0
    for (i, j), z, omega in zip(out.edge_ids, out.measurement, out.information):
        m = lambda q: np.array([[np.cos(q[2]), -np.sin(q[2]), q[0]], [np.sin(q[2]), np.cos(q[2]), q[1]], [0, 0, 1]])
        E = np.linalg.inv(m(z)) @ np.linalg.inv(m(p[i])) @ m(p[j])
        e = np.array([E[0, 2], E[1, 2], np.arctan2(E[1, 0], E[0, 0])])
        chi2 += e @ omega @ e
    np.testing.assert_allclose(summary["final_chi2"], chi2, rtol=1e-9)


def test_cli_checks_output_before_solving(tmp_path, capsys):
    write_g2o(tmp_path / "in.g2o", _graph(n=20))
    (tmp_path / "dir.g2o").mkdir()
    assert main(["posegraph", str(tmp_path / "in.g2o"), "--out", str(tmp_path / "dir.g2o")]) == 1
    assert "is a folder" in capsys.readouterr().err
    assert main(["posegraph", str(tmp_path / "nope.g2o"), "--out", str(tmp_path / "o.g2o")]) == 1
    assert "not found" in capsys.readouterr().err
