"""experiments/heading_association.py: its direction density against a closed-form mixture of wrapped Gaussians,
the density's spectrum back, its rows, a small run, and bad arguments failing in one line."""

import json
import subprocess
import sys

import jax.numpy as jnp
import numpy as np
import pytest
from _experiments import EXPERIMENTS, load

from jaxquad.kernels.wall_heading import HeadingSpec, direction_spectrum

assoc = load("heading_association")
SPEC = HeadingSpec()
STD = np.deg2rad(3.0)  # wide enough that 48 harmonics hold the smoothed density (exp(-2 k^2 std^2) < 1e-5 at k = 48)


def _spectrum(rng):
    phi = rng.uniform(0, np.pi, 30)
    w = rng.uniform(0.1, 2.0, 30)
    s = direction_spectrum(SPEC, jnp.asarray(phi, jnp.float32), jnp.asarray(w, jnp.float32), jnp.asarray(0.0))
    return phi, w, s


def test_density_is_the_wrapped_gaussian_mixture():
    phi, w, s = _spectrum(np.random.default_rng(0))
    bins = 360
    theta = np.arange(bins) * np.pi / bins
    n = np.arange(-3, 4)[:, None, None]  # the period is pi
    z = (theta[None, :, None] - phi[None, None, :] + n * np.pi) / STD
    want = (np.exp(-0.5 * z**2).sum(0) / (STD * np.sqrt(2 * np.pi))) @ w
    got = np.asarray(assoc.density(s, jnp.asarray(w.sum(), jnp.float32), STD, bins), np.float64)
    np.testing.assert_allclose(got, want, atol=1e-4 * want.max())


def test_spectrum_of_the_density_is_the_smoothed_spectrum():
    _, w, s = _spectrum(np.random.default_rng(1))
    d = assoc.density(s, jnp.asarray(w.sum(), jnp.float32), STD, 8 * SPEC.harmonics)
    k = np.arange(1, SPEC.harmonics + 1)
    want = np.asarray(s, np.float64) * np.exp(-2.0 * (k * STD) ** 2)[:, None]
    np.testing.assert_allclose(assoc.spectrum_of(d, SPEC.harmonics), want, atol=1e-4 * np.abs(want).max())


def test_rows_count_only_measurements_of_quality():
    measured = np.array([[0.5, 0.9], [-1.5, 0.6], [3.0, 0.7], [-5.0, 0.95], [20.0, 0.2], [np.nan, 0.0]])
    row = assoc.score("v", measured, 0.5)
    assert row["nodes"] == 6 and row["measurements"] == 4
    assert (row["over_1_deg"], row["over_2_deg"], row["over_4_deg"]) == (3, 2, 1)
    assert row["rms_deg"] == pytest.approx(np.sqrt((0.25 + 2.25 + 9 + 25) / 4)) and row["median_deg"] == 2.25
    none = assoc.score("v", measured, 0.99)  # nothing measured: no error to show, not a perfect one
    assert none["measurements"] == 0 and none["rms_deg"] is None and "| v | 6 | 0 | - | - |" in assoc.table([none])


def _run(tmp_path, *argv):
    return subprocess.run(
        [sys.executable, str(EXPERIMENTS / "heading_association.py"), *argv],
        cwd=tmp_path,
        capture_output=True,
        text=True,
        timeout=600,
    )


def test_small_run_prints_a_row_per_variant(tmp_path):
    r = _run(tmp_path, "--robots", "1", "--seconds", "20", "--json", "rows.json")
    assert r.returncode == 0, r.stderr
    rows = json.loads((tmp_path / "rows.json").read_text())
    assert [row["variant"] for row in rows] == list(assoc.VARIANTS)
    assert all(row["nodes"] == 20 and row["measurements"] > 0 for row in rows)  # 10-20 s, a node each 0.5 s
    assert r.stdout.count("\n| ") == 1 + len(assoc.VARIANTS)
    # A sanity check of the rows' order and names: the halves' test only leaves measurements out of the SLAM's own.
    by = {row["variant"]: row for row in rows}
    assert by[assoc.HALVES]["measurements"] <= by["inverse-variance"]["measurements"]


@pytest.mark.parametrize(
    "argv, named", [(["--seconds", "5"], "--seconds"), (["--every", "0"], "--every"), (["--json", "/no/x.json"], "/no")]
)
def test_bad_arguments_fail_in_one_line(tmp_path, argv, named):
    r = _run(tmp_path, *argv)
    assert r.returncode == 2 and r.stdout == ""
    last = r.stderr.strip().splitlines()[-1]
    assert last.startswith("heading_association.py: error: ") and named in last and "Traceback" not in r.stderr
