"""`jaxquad bench`: dispatcher, table formatting and one end-to-end kernel run in JSON."""

import json

import pytest

from jaxquad.bench import format_table
from jaxquad.cli import main


def test_format_table_aligns_columns():
    text = format_table([{"kernel": "twist", "run_ms": 0.0123456}, {"kernel": "level_scan", "run_ms": 12.0}])
    lines = text.splitlines()
    assert lines[0].split() == ["kernel", "run_ms"]
    assert lines[2].split() == ["twist", "0.01235"] and lines[3].split() == ["level_scan", "12"]
    assert lines[2].index("0.01235") == lines[0].index("run_ms")


def test_bad_batch_is_a_one_line_error(capsys):
    assert main(["bench", "--batch", "0"]) == 1
    assert "batch" in capsys.readouterr().err


def test_kernel_section_json(capsys):
    # Batch 2 exercises the vmapped path and its in_axes; the unbatched path is the same functions.
    assert main(["bench", "--cpu", "--json", "--batch", "2", "--repeats", "1"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["backend"] == "cpu" and out["jax_version"] and out["device"]
    rows = out["sections"]["kernels"]["rows"]
    names = {
        "observer+twist",
        "observer+twist, scanned",
        "observer",
        "twist",
        "stabilized_scan",
        "baseline_scan",
        "level_scan",
    }
    assert {(r["kernel"], r["batch"]) for r in rows} == {(n, b) for n in names for b in (2,)}
    for r in rows:
        assert r["compile_s"] > 0 and r["run_ms"] > 0
        assert r["throughput_per_s"] == pytest.approx(r["batch"] / (r["run_ms"] * 1e-3), rel=1e-2)
