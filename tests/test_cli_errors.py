"""Every command fails fast on bad input: exit status 1, one line on stderr naming the file or option,
no traceback, within seconds (before any heavy work), and nothing left at the output path. Also: every
option's help states its default, and output files get uniform permissions."""

import argparse
import importlib
import json
import os
import shutil
import stat
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import pytest

from jaxquad.cli import _COMMANDS, main
from jaxquad.io import OccupancyMap, TumTrajectory, save_log, save_map, write_tum

# Generous: the first call of a command imports its modules (JAX, MuJoCo) on a busy 2-core machine.
FAST_S = 20.0
GO2_JOINTS = [f"{leg}_{part}_joint" for leg in ("FL", "FR", "RL", "RR") for part in ("hip", "thigh", "calf")]
ROOT = os.geteuid() == 0  # root ignores folder permissions


def _log(T: int = 40, depth: bool = True, tau: bool = True) -> dict:
    """A valid single-robot Go2 log standing still (ground truth, torques, a few small depth frames)."""
    rng = np.random.default_rng(0)
    log = {
        "t": np.arange(T) * 0.005,
        "robot": np.array("go2"),
        "joint_names": np.array(GO2_JOINTS),
        "q": np.tile([0.0, 0.8, -1.5], (T, 4)),
        "qd": np.zeros((T, 12)),
        "gyro": rng.normal(0, 0.01, (T, 3)),
        "acc": np.tile([0.0, 0.0, 9.81], (T, 1)),
        "quat_wxyz": np.tile([1.0, 0, 0, 0], (T, 1)),
        "gt_pose": np.tile([0.0, 0, 0.3, 1, 0, 0, 0], (T, 1)),
        "gt_contact": np.ones((T, 4), bool),
        "gt_force": np.tile([0.0, 0, 37.0], (T, 4, 1)),
    }
    if tau:
        log["tau"] = np.zeros((T, 12))
    if depth:
        log.update(
            depth=rng.uniform(0.5, 3.0, (3, 12, 16)).astype(np.float32),
            depth_t=np.array([0.0, 0.05, 0.1]),
            K=np.array([[8.0, 0, 7.5], [0, 8, 5.5], [0, 0, 1]]),
            T_base_camera=np.eye(4),
        )
    return log


@pytest.fixture(scope="module")
def f(tmp_path_factory) -> dict[str, str]:
    """Input files, good and bad, and output places by name (paths as strings for argv templates)."""
    d = tmp_path_factory.mktemp("cli")
    save_log(d / "log.npz", _log())
    save_log(d / "nodepth.npz", _log(depth=False))
    save_log(d / "notau.npz", _log(tau=False))
    (d / "empty.npz").write_bytes(b"")
    (d / "text.npz").write_text("t q gyro acc\n0 1 2 3\n")
    (d / "binary").write_bytes(bytes(range(256)) * 8)
    (d / "afile").write_text("a file where a folder is expected\n")
    (d / "foreign").mkdir()
    (d / "foreign" / "keep.txt").write_text("not jaxquad output\n")
    (d / "dir.yaml").mkdir()
    for name, kind in (("simout", "jaxquad simulate"), ("estout", "jaxquad estimate")):
        (d / name).mkdir()
        (d / name / "summary.json").write_text(json.dumps({"kind": kind}))
    (d / "bad.yaml").write_text("mode: mixed\nbandwidth: -5\n")
    (d / "badamcl.yaml").write_text("sigma_hit: -1\n")
    s = np.linspace(0, 12, 120)
    traj = TumTrajectory(
        s, np.stack([3 * np.cos(s / 2), 2 * np.sin(s / 3), 0.1 * s], 1), np.tile([0, 0, 0, 1.0], (120, 1))
    )
    write_tum(d / "ref.tum", traj)
    save_map(d / "map.yaml", OccupancyMap(np.zeros((40, 40), np.int8), 0.1, (-2.0, -2.0, 0.0)))
    (d / "graph.g2o").write_text("VERTEX_SE2 0 0 0 0\nVERTEX_SE2 1 1 0 0\nEDGE_SE2 0 1 1 0 0 1 0 0 1 0 1\n")
    shutil.copy(
        Path(importlib.import_module("jaxquad.ros").__file__).parent / "examples" / "generic.yaml", d / "topics.yaml"
    )
    (d / "empty.bag").write_bytes(b"")
    (d / "text.bag").write_text("not a bag\n")
    for name in ("res_empty", "res_text", "res_keys"):
        (d / name).mkdir()
        write_tum(d / name / "a.tum", traj)
    (d / "res_empty" / "a.npz").write_bytes(b"")
    (d / "res_text" / "a_scans.npz").write_text("scans\n")
    np.savez(d / "res_keys" / "a_scans.npz", depth_t=np.zeros(2))
    paths = {p.name.replace(".", "_"): str(p) for p in d.iterdir()}
    return paths | {
        "dir": str(d),
        "new": str(d / "new_out"),
        "new_yaml": str(d / "new.yaml"),
        "missing": str(d / "missing.npz"),
    }


def _fails(argv: list[str], capsys) -> str:
    """Run the command in-process; assert exit 1, one stderr line and a quick return; give that line."""
    t0 = time.perf_counter()
    try:
        code = main(argv)
    except SystemExit as e:  # argparse errors
        code = e.code
    took = time.perf_counter() - t0
    err = capsys.readouterr().err
    lines = err.strip().splitlines()
    assert code == 1, f"{argv}: exit {code}, stderr {err!r}"
    assert len(lines) == 1 and "Traceback" not in err, f"{argv}: stderr {err!r}"
    assert lines[0].startswith(f"jaxquad {argv[0]}: error: "), lines[0]
    assert took < FAST_S, f"{argv}: {took:.1f} s before failing"
    return lines[0]


# (argv template, words the error line must hold). "{x}" is replaced by the fixture's path x.
CASES = {
    "estimate": [
        ("estimate {log_npz} --out {afile}", ["afile", "not a folder"]),
        ("estimate {log_npz} --out {afile}/sub", ["afile", "not a folder"]),
        ("estimate {log_npz} --out {foreign}", ["foreign", "non-empty"]),
        ("estimate {log_npz} --out {simout}", ["simout", "no earlier jaxquad estimate"]),
        ("estimate {empty_npz} --out {new}", ["empty.npz", "empty"]),
        ("estimate {text_npz} --out {new}", ["text.npz", "not an .npz"]),
        ("estimate {binary} --out {new}", ["binary", "not an .npz"]),
        ("estimate {missing} --out {new}", ["missing.npz", "not found"]),
        ("estimate {log_npz} --out {new} --params {bad_yaml}", ["bad.yaml", "bandwidth"]),
        ("estimate {log_npz} --out {new} --params {text_npz}", ["text.npz"]),
        ("estimate {notau_npz} --out {new}", ["'tau'"]),
        ("estimate {log_npz} --out {new} --range-min 9", ["--range-min"]),
        ("estimate {log_npz}", ["--out"]),
        ("estimate {log_npz} --out {new} --contacts psychic", ["--contacts", "psychic"]),
        ("estimate {log_npz} --out {new} --band-height x", ["--band-height"]),
    ],
    "simulate": [
        ("simulate --out {afile}", ["afile", "not a folder"]),
        ("simulate --out {afile}/sub", ["afile", "not a folder"]),
        ("simulate --out {foreign}", ["foreign", "non-empty"]),
        ("simulate --out {estout}", ["estout", "no earlier jaxquad simulate"]),
        ("simulate --robot spot --out {new}", ["spot"]),
        ("simulate --robot {text_npz} --out {new}", ["text.npz"]),
        ("simulate --robots 0 --out {new}", ["--robots"]),
        ("simulate --seconds 0 --out {new}", ["--seconds"]),
        ("simulate --world moon --out {new}", ["--world", "moon"]),
        ("simulate --resolution 4x4 --out {new}", ["--resolution"]),
        ("simulate", ["--out"]),
    ],
    "tune": [
        ("tune --log {log_npz} --method grid --out {afile}/p.yaml", ["afile", "not a folder"]),
        ("tune --log {log_npz} --method grid --out {dir_yaml}", ["dir.yaml", "folder"]),
        ("tune --log {log_npz} --method grid --out {new}.txt", ["--out", ".txt"]),
        ("tune --log {empty_npz} --method grid --out {new_yaml}", ["empty.npz", "empty"]),
        ("tune --log {text_npz} --method grid --out {new_yaml}", ["text.npz", "not an .npz"]),
        ("tune --log {missing} --method grid --out {new_yaml}", ["missing.npz"]),
        ("tune --log {notau_npz} --method grid --out {new_yaml}", ["tau"]),
        ("tune --log {log_npz} --method grid --out {new_yaml} --holdout 1.5", ["--holdout"]),
        ("tune --log {log_npz} --method gradient --out {new_yaml} --steps 0", ["--steps"]),
        ("tune --simulate --robot spot --method grid --out {new_yaml}", ["spot"]),
        ("tune --log {log_npz} --out {new_yaml}", ["--method"]),
        ("tune --log {log_npz} --method grid --out {new_yaml} --grid-size 0", ["--grid-size"]),
    ],
    "eval": [
        ("eval {ref_tum} {binary}", ["binary", "UTF-8"]),
        ("eval {binary} {ref_tum}", ["binary", "UTF-8"]),
        ("eval {ref_tum} {empty_npz}", ["empty.npz"]),
        ("eval {ref_tum} {text_npz}", ["text.npz:1"]),
        ("eval {ref_tum} {missing}", ["missing.npz"]),
        ("eval {ref_tum} {ref_tum} --plot {afile}/x.png", ["--plot", "afile"]),
        ("eval {ref_tum} {ref_tum} --plot {foreign}", ["--plot", "foreign", "folder"]),
        ("eval {ref_tum}", ["est"]),
        ("eval {ref_tum} {ref_tum} --align sideways", ["--align"]),
    ],
    "demo": [
        ("demo --out {afile}", ["afile", "not a folder"]),
        ("demo --out {afile}/sub", ["afile", "not a folder"]),
        ("demo --out {foreign}", ["foreign", "non-empty"]),
        ("demo --out {estout}", ["estout", "no earlier jaxquad demo"]),
        ("demo --robots 0 --out {new}", ["--robots"]),
        ("demo --seconds -1 --out {new}", ["--seconds"]),
        ("demo --robot spot --out {new}", ["--robot", "spot"]),
        ("demo --resolution 3x3 --out {new}", ["--resolution"]),
    ],
    "bench": [
        ("bench --batch 0", ["--batch"]),
        ("bench --cpu --repeats 0", ["--repeats"]),
        ("bench --batch x", ["--batch"]),
        ("bench --sim-depth sometimes", ["--sim-depth"]),
    ],
    "convert": [
        ("convert {text_bag} --topics {topics_yaml} --robot go2 --out {afile}/x.npz", ["afile", "not a folder"]),
        ("convert {text_bag} --topics {topics_yaml} --robot go2 --out {foreign}", ["foreign", "folder"]),
        ("convert {empty_bag} --topics {topics_yaml} --robot go2 --out {new}.npz", ["empty.bag"]),
        ("convert {text_bag} --topics {topics_yaml} --robot go2 --out {new}.npz", ["text.bag"]),
        ("convert {text_npz} --topics {topics_yaml} --robot go2 --out {new}.npz", ["text.npz", "not a bag"]),
        ("convert {text_bag} --topics {bad_yaml} --robot go2 --out {new}.npz", ["bad.yaml", "bandwidth"]),
        ("convert {text_bag} --topics {binary} --robot go2 --out {new}.npz", ["binary", "UTF-8"]),
        ("convert {text_bag} --topics {topics_yaml} --robot spot --out {new}.npz", ["spot"]),
        ("convert {text_bag} --robot go2 --out {new}.npz", ["--topics"]),
    ],
    "export": [
        ("export {res_empty} --bag {new}", ["a.npz", "empty"]),
        ("export {res_text} --bag {new}", ["a_scans.npz", "not an .npz"]),
        ("export {res_keys} --bag {new}", ["a_scans.npz", "ranges_stabilized"]),
        ("export {res_keys} --bag {foreign}", ["foreign", "non-empty"]),
        ("export {res_keys} --bag {afile}/b", ["afile", "not a folder"]),
        ("export {missing} --bag {new}", ["missing.npz"]),
        ("export {res_keys} --bag {new} --format ros1", [".bag"]),
        ("export {res_keys} --bag {new} --format zip", ["--format"]),
    ],
    "localize": [
        ("localize {log_npz} --map {map_yaml} --out {afile} --global", ["afile", "not a folder"]),
        ("localize {log_npz} --map {map_yaml} --out {afile}/sub --global", ["afile", "not a folder"]),
        ("localize {log_npz} --map {map_yaml} --out {foreign} --global", ["foreign", "non-empty"]),
        ("localize {log_npz} --map {map_yaml} --out {estout} --global", ["estout", "no earlier jaxquad localize"]),
        ("localize {empty_npz} --map {map_yaml} --out {new} --global", ["empty.npz", "empty"]),
        ("localize {text_npz} --map {map_yaml} --out {new} --global", ["text.npz", "not an .npz"]),
        ("localize {nodepth_npz} --map {map_yaml} --out {new} --global", ["depth"]),
        ("localize {log_npz} --map {binary} --out {new} --global", ["binary", "UTF-8"]),
        ("localize {log_npz} --map {text_npz} --out {new} --global", ["text.npz"]),
        ("localize {log_npz} --map {missing} --out {new} --global", ["missing.npz"]),
        (
            "localize {log_npz} --map {map_yaml} --out {new} --global --params {badamcl_yaml}",
            ["badamcl.yaml", "sigma_hit"],
        ),
        (
            "localize {log_npz} --map {map_yaml} --out {new} --global --observer-params {bad_yaml}",
            ["bad.yaml", "bandwidth"],
        ),
        ("localize {log_npz} --map {map_yaml} --out {new} --global --particles 0", ["--particles"]),
        ("localize {log_npz} --map {map_yaml} --out {new}", ["--global"]),
    ],
    "slam": [
        ("slam {log_npz} --out {afile}", ["afile", "not a folder"]),
        ("slam {log_npz} --out {afile}/sub", ["afile", "not a folder"]),
        ("slam {log_npz} --out {foreign}", ["foreign", "non-empty"]),
        ("slam {log_npz} --out {estout}", ["estout", "no earlier jaxquad slam"]),
        ("slam {empty_npz} --out {new}", ["empty.npz", "empty"]),
        ("slam {text_npz} --out {new}", ["text.npz"]),
        ("slam {binary} --out {new}", ["binary"]),
        ("slam {missing} --out {new}", ["missing.npz"]),
        ("slam {nodepth_npz} --out {new}", ["depth"]),
        ("slam {notau_npz} --out {new}", ["'tau'"]),
        ("slam {log_npz} --out {new} --params {bad_yaml}", ["bad.yaml", "bandwidth"]),
        ("slam {log_npz} --out {new} --observer-params {bad_yaml}", ["bad.yaml", "bandwidth"]),
        ("slam {log_npz} --out {new} --true-map {binary}", ["binary", "UTF-8"]),
        ("slam {log_npz} --out {new} --band-height 0", ["--band-height"]),
        ("slam {log_npz} --out {new} --band-reduce max", ["--band-reduce"]),
        ("slam {log_npz} --out {new} --format gps", ["--format"]),
        ("slam {log_npz} --out {new} --variant full --scans baseline", ["--variant", "--scans"]),
        ("slam {log_npz} --out {new} --variant B+LO --lo-constraints off", ["--variant", "--lo-constraints"]),
        ("slam {log_npz} --out {new} --variant ours", ["--variant"]),
        ("slam {log_npz} --out {new} --vo-leg-odometry off", ["--vo-leg-odometry", "--odometry vo"]),
        ("slam {text_npz} --out {new} --format carmen --odometry vo", ["robot log", "carmen"]),
    ],
    "navigate": [
        ("navigate --out {afile}", ["afile", "not a folder"]),
        ("navigate --out {afile}/sub", ["afile", "not a folder"]),
        ("navigate --out {foreign}", ["foreign", "non-empty"]),
        ("navigate --out {estout}", ["estout", "no earlier jaxquad navigate"]),
        ("navigate --out {new} --robots 0", ["--robots"]),
        ("navigate --out {new} --chunk-ticks 15", ["--chunk-ticks", "10"]),
        ("navigate --out {new} --max-seconds -1", ["--max-seconds"]),
        ("navigate --out {new} --amcl-params {badamcl_yaml}", ["badamcl.yaml", "sigma_hit"]),
        ("navigate --out {new} --amcl-params {missing}", ["missing.npz"]),
        ("navigate --out {new} --robot spot", ["spot"]),
        ("navigate --out {new} --map slam2", ["--map"]),
    ],
    "explore": [
        ("explore --out {afile}", ["afile", "not a folder"]),
        ("explore --out {foreign}", ["foreign", "non-empty"]),
        ("explore --out {estout}", ["estout", "no earlier jaxquad explore"]),
        ("explore --out {new} --robot spot", ["--robot", "spot"]),
        ("explore --out {new} --world moon", ["--world", "moon"]),
        ("explore --out {new} --variant ours", ["--variant"]),
        ("explore --out {new} --robots 0", ["--robots"]),
        ("explore --out {new} --seconds -5", ["--seconds"]),
        ("explore --out {new} --seconds nan", ["--seconds"]),
        ("explore --out {new} --chunk-ticks 15", ["--chunk-ticks", "10"]),
        ("explore --out {new} --map-range 0", ["--map-range"]),
        ("explore --out {new} --map-miss-probability 0.5", ["--map-miss-probability"]),
        ("explore --out {new} --map-hit-offset-cells -0.1", ["--map-hit-offset-cells"]),
        ("explore --out {new} --map-hit-offset-cells 1.5", ["--map-hit-offset-cells", "[0, 1]"]),
        ("explore --out {new} --frontier-gain -0.5", ["--frontier-gain"]),
        ("explore --out {new} --outline-padding nan", ["--outline-padding"]),
        ("explore --out {new} --max-speed 0", ["--max-speed"]),
        ("explore --out {new} --near-obstacle-speed -0.1", ["--near-obstacle-speed"]),
        ("explore --out {new} --revisit-after -1", ["--revisit-after"]),
        ("explore --out {new} --revisit-after inf", ["--revisit-after"]),
        ("explore --out {new} --leg-bias-sideways -0.01", ["--leg-bias-sideways"]),
        ("explore --out {new} --band-height 0", ["--band-height"]),
        ("explore --out {new} --band-reduce mean", ["--band-reduce"]),
        ("explore --out {new} --slam-params {bad_yaml}", ["bad.yaml", "bandwidth"]),
        ("explore --out {new} --slam-params {missing}", ["missing.npz"]),
        ("explore --robots 2", ["--out"]),
        ("explore --out {new} --wall-budget 100", ["--wall-budget", "--checkpoint"]),
        ("explore --out {new} --checkpoint {new}.npz --wall-budget -1", ["--wall-budget"]),
        ("explore --out {new} --checkpoint {foreign}", ["--checkpoint", "foreign", "folder"]),
        ("explore --out {new} --checkpoint {afile}/c.npz", ["--checkpoint", "afile"]),
    ],
    "posegraph": [
        ("posegraph {binary} --out {new}.g2o", ["binary", "UTF-8"]),
        ("posegraph {empty_npz} --out {new}.g2o", ["empty.npz", "VERTEX_SE2"]),
        ("posegraph {missing} --out {new}.g2o", ["missing.npz"]),
        ("posegraph {graph_g2o} --out {afile}/o.g2o", ["afile", "not a folder"]),
        ("posegraph {graph_g2o} --out {foreign}", ["foreign", "folder"]),
        ("posegraph {graph_g2o} --out {new}.g2o --max-iterations 0", ["--max-iterations"]),
        ("posegraph {graph_g2o} --out {new}.g2o --robust-width -1", ["--robust-width"]),
        ("posegraph {graph_g2o}", ["--out"]),
    ],
    "vo": [
        ("vo {log_npz} --out {afile}", ["afile", "not a folder"]),
        ("vo {log_npz} --out {afile}/sub", ["afile", "not a folder"]),
        ("vo {log_npz} --out {foreign}", ["foreign", "non-empty"]),
        ("vo {log_npz} --out {estout}", ["estout", "no earlier jaxquad vo"]),
        ("vo {empty_npz} --out {new}", ["empty.npz", "empty"]),
        ("vo {text_npz} --out {new}", ["text.npz", "not an .npz"]),
        ("vo {nodepth_npz} --out {new}", ["nodepth.npz", "depth"]),
        ("vo {notau_npz} --out {new}", ["'tau'"]),
        ("vo {log_npz} --out {new} --leg-odometry always", ["--leg-odometry"]),
    ],
}


def test_every_command_has_cases():
    assert set(CASES) == set(_COMMANDS)


@pytest.mark.parametrize("command", sorted(CASES))
def test_bad_input_fails_fast_in_one_line(command, f, capsys):
    for template, words in CASES[command]:
        argv = [a.format(**f) for a in template.split()]
        line = _fails(argv, capsys)
        for word in words:
            assert word in line, f"{template}: {line!r} lacks {word!r}"
        # Nothing was created or touched at the output paths.
        new = [p for p in Path(f["dir"]).iterdir() if p.name.startswith("new") or p.name.startswith(".")]
        assert not new, f"{template}: left {new}"
        assert (Path(f["foreign"]) / "keep.txt").is_file() and Path(f["afile"]).is_file()


def test_read_only_output_folder_fails_fast(f, tmp_path, capsys, monkeypatch):
    ro = tmp_path / "ro"
    ro.mkdir()
    ro.chmod(0o500)
    if ROOT:  # root writes into read-only folders: make the OS refuse there as it does for a user
        mkstemp = tempfile.mkstemp

        def refusing(*args, dir=None, **kwargs):
            if dir is not None and Path(dir).resolve() == ro.resolve():
                raise PermissionError(13, "Permission denied")
            return mkstemp(*args, dir=dir, **kwargs)

        monkeypatch.setattr(tempfile, "mkstemp", refusing)
    try:
        for template in (
            "estimate {log_npz} --out {ro}/out",
            "simulate --out {ro}/out",
            "demo --out {ro}/out",
            "tune --log {log_npz} --method grid --out {ro}/p.yaml",
            "vo {log_npz} --out {ro}/out",
            "eval {ref_tum} {ref_tum} --plot {ro}/p.png",
            "posegraph {graph_g2o} --out {ro}/o.g2o",
            "localize {log_npz} --map {map_yaml} --out {ro}/out --global",
            "navigate --out {ro}/out",
            "explore --out {ro}/out",
            "export {res_keys} --bag {ro}/bag",
            "slam {log_npz} --out {ro}/out",
            "convert {text_bag} --topics {topics_yaml} --robot go2 --out {ro}/log.npz",
        ):
            line = _fails([a.format(ro=ro, **f) for a in template.split()], capsys)
            assert "cannot write" in line and str(ro) in line, line
        assert not list(ro.iterdir())
    finally:
        ro.chmod(0o700)


def test_unknown_robot_as_a_user_runs_it(tmp_path):
    """`python -m jaxquad simulate --robot spot --out x/`: exit 1, one line, no x/, in seconds."""
    t0 = time.perf_counter()
    r = subprocess.run(
        [sys.executable, "-m", "jaxquad", "simulate", "--robot", "spot", "--out", "x/"],
        cwd=tmp_path,
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert r.returncode == 1 and r.stdout == ""
    assert r.stderr.startswith("jaxquad simulate: error: ") and r.stderr.count("\n") == 1, r.stderr
    assert "spot" in r.stderr and "Traceback" not in r.stderr
    assert not list(tmp_path.iterdir())
    assert time.perf_counter() - t0 < FAST_S


@pytest.mark.slow
def test_tune_on_a_single_robot_log_with_the_default_holdout(f, tmp_path, capsys):
    """No robot to hold out: tuned and scored on itself (not an error after the search), the best
    parameters printed on stdout as written, and every parameter of the run recorded."""
    import yaml

    out = tmp_path / "p.yaml"
    assert main(["tune", "--log", f["log_npz"], "--method", "grid", "--grid-size", "1", "--out", str(out)]) == 0
    printed = json.loads(capsys.readouterr().out)
    assert printed == json.loads((tmp_path / "p.summary.json").read_text())
    assert printed["holdout_requested"] == 0.25 and printed["holdout"] == 0.0
    assert printed["robots_train"] == 1 and printed["robots_heldout"] == 0 and "tuned_heldout" not in printed
    assert printed["params"] == yaml.safe_load(out.read_text())
    assert printed["observer_inputs"] == {
        "max_gap_s": 0.05,
        "torque_saturation": 0.99,
        "chunk": 4096,
        "axes": "xyz",
        "passive": True,
        "rows": "legs",
    }
    assert set(printed["options"]) == {"chunk", "f1_tolerance", "top_k", "max_delay_s", "devices"}
    assert printed["base_params"]["bandwidth"] == 30.0  # the paper's, around which the grid lies


# ---------------------------------------------------------------- help texts


def _parser(command: str) -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog=f"jaxquad {command}")
    importlib.import_module(_COMMANDS[command][0]).add_arguments(parser)
    return parser


def _shown(value, text: str) -> bool:
    """Whether a default value is written in a help text (numbers as written by people: 8 for 8.0)."""
    if isinstance(value, (list, tuple)):
        return all(_shown(v, text) for v in value)
    if isinstance(value, float):
        return any(s in text for s in (f"{value:g}", repr(value)))
    return str(value) in text


@pytest.mark.parametrize("command", sorted(_COMMANDS))
def test_every_option_has_help_with_its_default(command):
    """Each option has a help text; one that takes a value and may be left out says its default, and
    a default other than None is written out (None: the help says what happens instead)."""
    parser = _parser(command)
    required = {id(a) for g in parser._mutually_exclusive_groups if g.required for a in g._group_actions}
    for action in parser._actions:
        if isinstance(action, argparse._HelpAction):
            continue
        name = "/".join(action.option_strings) or action.dest
        assert action.help, f"jaxquad {command} {name}: no help text"
        takes_value = action.option_strings and action.nargs != 0
        if not takes_value or action.required or id(action) in required:
            continue
        assert "default" in action.help, f"jaxquad {command} {name}: help does not say its default: {action.help!r}"
        if action.default is not None:
            assert _shown(action.default, action.help), (
                f"jaxquad {command} {name}: default {action.default!r} not in help"
            )


def test_help_prints_and_exits_0(capsys):
    with pytest.raises(SystemExit) as e:
        main(["simulate", "--help"])
    assert e.value.code == 0 and "(default go2)" in capsys.readouterr().out


# ---------------------------------------------------------------- file modes


def test_outputs_have_uniform_modes(tmp_path):
    """Every writer goes through jaxquad.io.atomic: files 0666 & ~umask, folders 0777 & ~umask."""
    from jaxquad.io import atomic_dir, atomic_open, read_tum, write_json
    from jaxquad.metrics import evaluate
    from jaxquad.metrics.plot import plot_evaluation
    from jaxquad.report import plot_heights

    old = os.umask(0o022)
    try:
        save_log(tmp_path / "log.npz", _log(T=10, depth=False))
        with atomic_open(tmp_path / "arrays.npz") as fh:
            np.savez(fh, x=np.zeros(3))
        write_json(tmp_path / "s.json", {"a": 1})
        plot_heights(tmp_path / "h.png", np.arange(3.0), np.zeros(3), {"truth": np.ones(3)})
        s = np.arange(50.0)
        write_tum(
            tmp_path / "a.tum", TumTrajectory(s, np.c_[np.cos(s), np.sin(s), 0.1 * s], np.tile([0, 0, 0, 1.0], (50, 1)))
        )
        traj = read_tum(tmp_path / "a.tum")
        plot_evaluation(evaluate(traj, traj, align="none", deltas=[1.0]), tmp_path / "e.png")
        with atomic_dir(tmp_path / "folder") as d:
            (d / "x.txt").write_text("x")
    finally:
        os.umask(old)
    for name in ("log.npz", "arrays.npz", "s.json", "h.png", "a.tum", "e.png"):
        assert stat.S_IMODE((tmp_path / name).stat().st_mode) == 0o644, name
    assert stat.S_IMODE((tmp_path / "folder").stat().st_mode) == 0o755
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".")]
