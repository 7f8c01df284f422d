"""TUM trajectory files: round trip, evo reads what we write, one-line errors with file and line."""

import os

import numpy as np
import pytest
from evo.tools import file_interface

from jaxquad.io import TumTrajectory, read_tum, write_tum


def _traj(n=50, seed=0):
    rng = np.random.default_rng(seed)
    q = rng.normal(size=(n, 4))
    return TumTrajectory(
        1.7e9 + np.cumsum(rng.uniform(0.001, 0.1, n)),  # epoch stamps need all 17 digits
        rng.normal(size=(n, 3)) * 100,
        q / np.linalg.norm(q, axis=1, keepdims=True),
    )


def test_round_trip_is_exact_and_evo_reads_it(tmp_path):
    tr = _traj()
    path = tmp_path / "a.tum"
    write_tum(path, tr, header="made by a test\nsecond line")
    back = read_tum(path)
    np.testing.assert_array_equal(back.t_s, tr.t_s)
    np.testing.assert_array_equal(back.p_world_body, tr.p_world_body)
    np.testing.assert_allclose(back.q_world_body_xyzw, tr.q_world_body_xyzw, rtol=0, atol=1e-15)  # renormalized on read
    theirs = file_interface.read_tum_trajectory_file(str(path))
    np.testing.assert_array_equal(theirs.timestamps, tr.t_s)
    np.testing.assert_array_equal(theirs.positions_xyz, tr.p_world_body)
    np.testing.assert_array_equal(theirs.orientations_quat_wxyz, np.roll(tr.q_world_body_xyzw, 1, axis=1))


def test_comments_blank_lines_and_normalization(tmp_path):
    path = tmp_path / "b.tum"
    path.write_text("# t x y z qx qy qz qw\n\n1.0 1 2 3 0 0 0 2\n  # indented comment\n2.5 4 5 6 0 3 0 4\n")
    tr = read_tum(path)
    np.testing.assert_array_equal(tr.t_s, [1.0, 2.5])
    np.testing.assert_array_equal(tr.p_world_body, [[1, 2, 3], [4, 5, 6]])
    np.testing.assert_allclose(tr.q_world_body_xyzw, [[0, 0, 0, 1], [0, 0.6, 0, 0.8]], atol=1e-16)


@pytest.mark.parametrize(
    ("text", "message"),
    [
        ("1 0 0 0 0 0 0 1\n2 0 0 0 0 0 1\n", r"b\.tum:2: expected 8 fields .* got 7"),
        ("1 0 0 0 0 0 0 1\n# c\n2 0 0 x 0 0 0 1\n", r"b\.tum:3: not a number: 'x'"),
        ("1 0 0 nan 0 0 0 1\n", r"b\.tum:1: NaN or infinite"),
        ("1 0 0 0 0 0 0 inf\n", r"b\.tum:1: NaN or infinite"),
        ("1 0 0 0 0 0 0 0\n", r"b\.tum:1: zero quaternion"),
        ("1 0 0 0 0 0 0 1\n1 0 0 0 0 0 0 1\n", r"b\.tum:2: timestamp 1\.0 does not increase \(line 1"),
        ("2 0 0 0 0 0 0 1\n1 0 0 0 0 0 0 1\n", r"b\.tum:2: timestamp"),
        ("# only a comment\n", r"b\.tum: no poses"),
    ],
)
def test_malformed_files_give_one_line_errors(tmp_path, text, message):
    path = tmp_path / "b.tum"
    path.write_text(text)
    with pytest.raises(ValueError, match=message) as err:
        read_tum(path)
    assert "\n" not in str(err.value)


def test_missing_file(tmp_path):
    with pytest.raises(FileNotFoundError, match="nope.tum"):
        read_tum(tmp_path / "nope.tum")


def test_write_is_atomic(tmp_path):
    path = tmp_path / "c.tum"
    write_tum(path, _traj(seed=1))
    before = path.read_bytes()
    bad = _traj(seed=2)
    bad.p_world_body[3, 1] = np.nan
    with pytest.raises(ValueError, match="NaN"):
        write_tum(path, bad)
    assert path.read_bytes() == before  # the old file survives a refused write
    write_tum(path, _traj(seed=3))
    assert path.read_bytes() != before
    assert os.listdir(tmp_path) == ["c.tum"]  # no temporary files left behind


def test_shapes_are_checked():
    with pytest.raises(ValueError, match="shapes"):
        TumTrajectory(np.arange(3.0), np.zeros((3, 3)), np.zeros((2, 4)))
