"""experiments/slam_accuracy.py's argument checks: a bad value fails in one line before any simulation."""

import subprocess
import sys
from pathlib import Path

import pytest

_PATH = Path(__file__).resolve().parents[1] / "experiments" / "slam_accuracy.py"


@pytest.mark.parametrize(
    "argv, named",
    [
        (["--band-height", "0"], "--band-height"),
        (["--band-height", "x"], "--band-height"),
        (["--params", "no_such_file.yaml"], "no_such_file.yaml"),
    ],
)
def test_bad_arguments_fail_in_one_line(tmp_path, argv, named):
    r = subprocess.run([sys.executable, str(_PATH), *argv], cwd=tmp_path, capture_output=True, text=True, timeout=120)
    assert r.returncode == 2 and r.stdout == "", (r.stdout, r.stderr)
    last = r.stderr.strip().splitlines()[-1]
    assert last.startswith("slam_accuracy.py: error: ") and named in last, r.stderr
    assert "Traceback" not in r.stderr and not list(tmp_path.iterdir())
