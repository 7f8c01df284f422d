"""`jaxquad eval`: JSON equals evo's numbers, KITTI drift, table and plot outputs, one-line errors."""

import copy
import json

import numpy as np
import pytest
from evo.core import metrics as evo_metrics
from evo.core import sync
from evo.main_ape import ape as evo_ape
from evo.main_rpe import rpe as evo_rpe
from evo.tools import file_interface
from scipy.spatial.transform import Rotation

from jaxquad.cli import main
from jaxquad.io import TumTrajectory, read_tum, write_tum
from jaxquad.metrics import associate, evaluate_drift


def _strict(text):
    return json.loads(text, parse_constant=lambda c: pytest.fail(f"non-standard JSON token {c}"))


@pytest.fixture(scope="module")
def files(tmp_path_factory):
    d = tmp_path_factory.mktemp("eval")
    rng = np.random.default_rng(2)
    n = 800
    t = np.arange(n) * 0.02
    s = np.linspace(0, 30, n)
    p = np.stack([8 * np.cos(s / 6), 5 * np.sin(s / 4), 0.3 * np.sin(s)], 1)
    q = Rotation.from_rotvec(np.stack([0.05 * np.sin(s), 0.05 * np.cos(s), s / 6], 1)).as_quat()
    write_tum(d / "ref.tum", TumTrajectory(t, p, q))
    q_est = q[::2] + 0.01 * rng.normal(size=q[::2].shape)
    write_tum(
        d / "est.tum",
        TumTrajectory(
            t[::2] + 0.004,
            1.1 * p[::2] + 0.05 * rng.normal(size=(n // 2, 3)),
            q_est / np.linalg.norm(q_est, axis=1, keepdims=True),
        ),
    )
    return d


def test_json_matches_evo(files, capsys):
    ref, est = str(files / "ref.tum"), str(files / "est.tum")
    assert main(["eval", ref, est, "--align", "sim3", "--delta", "2", "5", "--json"]) == 0
    out = _strict(capsys.readouterr().out)
    assert set(out) == {
        "ate",
        "are",
        "are_deg",
        "ape",
        "ape_rotation_part",
        "rpe_2m",
        "rpe_5m",
        "drift_pct",
        "drift_deg_per_m",
        "n_pairs",
        "alignment",
        "ok",
    }
    r, e = sync.associate_trajectories(
        file_interface.read_tum_trajectory_file(ref), file_interface.read_tum_trajectory_file(est), max_diff=0.01
    )
    assert out["n_pairs"] == len(r.timestamps)
    kinds = {
        "ate": evo_metrics.PoseRelation.translation_part,
        "are": evo_metrics.PoseRelation.rotation_angle_rad,
        "are_deg": evo_metrics.PoseRelation.rotation_angle_deg,
        "ape": evo_metrics.PoseRelation.full_transformation,
    }
    for key, rel in kinds.items():
        stats = evo_ape(copy.deepcopy(r), copy.deepcopy(e), rel, align=True, correct_scale=True).stats
        for s in ("rmse", "mean", "median", "std", "min", "max"):
            np.testing.assert_allclose(out[key][s], stats[s], rtol=1e-9, err_msg=f"{key} {s}")
    for d in (2, 5):
        res = evo_rpe(
            copy.deepcopy(r),
            copy.deepcopy(e),
            evo_metrics.PoseRelation.translation_part,
            delta=d,
            delta_unit=evo_metrics.Unit.meters,
            align=True,
            correct_scale=True,
        )
        for s in ("rmse", "mean", "median", "std", "min", "max"):
            np.testing.assert_allclose(out[f"rpe_{d}m"][s], res.stats[s], rtol=1e-9)
        assert out[f"rpe_{d}m"]["n_pairs"] == res.np_arrays["error_array"].size
    a = out["alignment"]
    assert a["mode"] == "sim3" and np.asarray(a["rotation"]).shape == (3, 3) and len(a["translation"]) == 3
    np.testing.assert_allclose(a["scale"], 1 / 1.1, rtol=0.02)


def test_json_drift_is_kitti_and_alignment_free(files, capsys):
    ref, est = str(files / "ref.tum"), str(files / "est.tum")
    outs = []
    for align in ("sim3", "none"):
        assert (
            main(["eval", ref, est, "--align", align, "--drift-length", "2", "5", "40", "--drift-step", "4", "--json"])
            == 0
        )
        outs.append(_strict(capsys.readouterr().out))
    assert outs[0]["drift_pct"] == outs[1]["drift_pct"] and outs[0]["drift_deg_per_m"] == outs[1]["drift_deg_per_m"]
    r, e = read_tum(ref), read_tum(est)
    i, j = associate(r.t_s, e.t_s, 0.01)
    d = evaluate_drift(
        r.p_world_body[i], r.q_world_body_xyzw[i], e.p_world_body[j], e.q_world_body_xyzw[j], (2.0, 5.0, 40.0), 4
    ).to_dict()
    for key in ("drift_pct", "drift_deg_per_m"):
        got = outs[0][key]
        assert got["lengths_m"] == [2.0, 5.0, 40.0] and got["step_poses"] == 4
        assert got["n_segments"] == sum(got["n_segments_per_length"]) == d[key]["n_segments"] > 0
        # The reference path (~38 m) is shorter than 40 m: no segment, null (NaN), never 0.
        assert got["n_segments_per_length"][2] == 0 and got["per_length"][2] is None
        np.testing.assert_allclose(got["per_length"][:2], d[key]["per_length"][:2], rtol=1e-12)
        np.testing.assert_allclose(got["mean"], d[key]["mean"], rtol=1e-12)
    assert 5.0 < outs[0]["drift_pct"]["mean"] < 15.0  # the estimate is the truth scaled by 1.1, plus noise


def test_table_and_plot(files, capsys):
    png = files / "out.png"
    assert main(["eval", str(files / "ref.tum"), str(files / "est.tum"), "--plot", str(png)]) == 0
    text = capsys.readouterr().out
    for label in (
        "ATE (m)",
        "ARE (rad)",
        "ARE (deg)",
        "APE (full)",
        "RPE 2m",
        "RPE 5m",
        "RPE 10m",
        "rmse",
        "drift (KITTI, unaligned)",
        "deg/m",
        "segments",
    ):
        assert label in text
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" and png.stat().st_size > 10_000


@pytest.mark.parametrize(
    ("extra", "message"),
    [
        (["--delta", "1000"], "RPE delta 1000 m gives no pose pair"),
        (["--max-diff", "0.001"], "no matching timestamps"),
        (["--drift-length", "-2"], "drift segment lengths must be positive"),
        (["--drift-step", "0"], "drift step must be an integer >= 1"),
    ],
)
def test_errors_are_one_line(files, capsys, extra, message):
    assert main(["eval", str(files / "ref.tum"), str(files / "est.tum"), *extra]) == 1
    err = capsys.readouterr().err
    assert err.startswith("jaxquad eval: error: ") and message in err and err.count("\n") == 1


def test_bad_file_is_reported_with_line(files, capsys):
    bad = files / "bad.tum"
    bad.write_text("0 0 0 0 0 0 0 1\n1 0 0 0 0 0 0\n")
    assert main(["eval", str(files / "ref.tum"), str(bad)]) == 1
    assert "bad.tum:2: expected 8 fields" in capsys.readouterr().err
