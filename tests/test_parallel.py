"""Sharding over devices and processes (`jaxquad.parallel`): padding against NumPy, one-line errors,
and the same numbers on 2 devices (one process, `--xla_force_host_platform_device_count=2`) and on
2 processes (jax.distributed over gloo on localhost) as on 1 device. The device count must be set
before JAX starts, so those runs are subprocesses (tests/_parallel_worker.py)."""

from __future__ import annotations

import os
import socket
import subprocess
import sys
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxquad import parallel
from jaxquad.cli import main

WORKER = Path(__file__).with_name("_parallel_worker.py")
_COUNTS = ("tp", "fp", "fn", "force_sq", "samples")


def _env(devices: int = 1, **extra) -> dict:
    """This process's environment (its XLA flags too, see conftest) with `devices` CPU devices."""
    env = {k: v for k, v in os.environ.items() if not k.startswith("JAXQUAD_")}
    flags = [f for f in env.get("XLA_FLAGS", "").split() if not f.startswith("--xla_force_host_platform_device_count")]
    flags.append(f"--xla_force_host_platform_device_count={devices}")
    return env | {"JAX_PLATFORMS": "cpu", "XLA_FLAGS": " ".join(flags)} | extra


def _check(proc: subprocess.CompletedProcess | subprocess.Popen, err: str) -> None:
    assert proc.returncode == 0, f"worker failed ({proc.returncode}):\n{err[-3000:]}"


def _two_devices(*args, timeout: float) -> None:
    env = _env(devices=2)
    proc = subprocess.run(
        [sys.executable, str(WORKER), *args], env=env, capture_output=True, text=True, timeout=timeout
    )
    _check(proc, proc.stderr)


def _two_processes(*args, timeout: float) -> None:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    procs = [
        subprocess.Popen(
            [sys.executable, str(WORKER), *args],
            env=_env(JAXQUAD_COORDINATOR=f"127.0.0.1:{port}", JAXQUAD_NUM_PROCESSES="2", JAXQUAD_PROCESS_ID=str(i)),
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            text=True,
        )
        for i in range(2)
    ]
    try:
        errs = [p.communicate(timeout=timeout)[1] for p in procs]
    finally:
        for p in procs:
            if p.poll() is None:
                p.kill()
    for p, err in zip(procs, errs):
        _check(p, err)


# ---- in this process (one CPU device) ---------------------------------------------------------


def test_pad_and_unpad_against_numpy():
    rng = np.random.default_rng(0)
    tree = {
        "robots": rng.normal(size=(5, 3)),
        "time_major": rng.normal(size=(2, 5, 4)),
        "shared": rng.normal(size=(7,)),
    }
    tree = {k: v.astype(np.float32) for k, v in tree.items()}
    axes = {"robots": 0, "time_major": 1, "shared": None}
    padded = parallel.pad(tree, 8, axes)
    np.testing.assert_array_equal(
        padded["robots"], np.concatenate([tree["robots"], np.repeat(tree["robots"][-1:], 3, 0)])
    )
    np.testing.assert_array_equal(
        padded["time_major"], np.concatenate([tree["time_major"]] + [tree["time_major"][:, -1:]] * 3, 1)
    )
    np.testing.assert_array_equal(padded["shared"], tree["shared"])
    back = parallel.unpad(padded, 5, axes)
    for k in tree:
        np.testing.assert_array_equal(back[k], tree[k])
    keys = jax.random.split(jax.random.key(3), 3)
    padded_keys = parallel.pad(keys, 4)
    data = np.asarray(jax.random.key_data(padded_keys))
    np.testing.assert_array_equal(data, np.asarray(jax.random.key_data(keys))[[0, 1, 2, 2]])


def test_padded_size_and_mesh():
    mesh = parallel.mesh()
    assert mesh.size == jax.device_count() == 1 and mesh.axis_names == (parallel.BATCH,)
    assert [parallel.padded_size(n, mesh) for n in (1, 2, 7)] == [1, 2, 7]
    for bad in (0, 2):
        with pytest.raises(ValueError, match=r"--devices must lie in \[1, 1\]"):
            parallel.mesh(bad)


def test_shard_batched_time_major_on_one_device():
    x = jnp.arange(12.0).reshape(4, 3)  # 4 robots x 3 samples; out time-major (3, 4)
    mesh = parallel.mesh(1)
    fn = jax.vmap(lambda r, w: (jnp.cumsum(r) * w, r.sum()), in_axes=(0, None), out_axes=(1, 0))
    out = jax.jit(parallel.shard_batched(fn, mesh, (0, None), (1, 0)))(*parallel.place((x, 2.0), mesh, (0, None)))
    np.testing.assert_allclose(out[0], 2.0 * np.cumsum(np.asarray(x), 1).T)
    np.testing.assert_allclose(out[1], np.asarray(x).sum(1))


def test_initialize_needs_every_variable(monkeypatch):
    monkeypatch.setenv("JAXQUAD_NUM_PROCESSES", "2")
    monkeypatch.delenv("JAXQUAD_COORDINATOR", raising=False)
    monkeypatch.setenv("JAXQUAD_PROCESS_ID", "0")
    with pytest.raises(ValueError, match="missing JAXQUAD_COORDINATOR"):
        parallel.initialize()
    monkeypatch.setenv("JAXQUAD_COORDINATOR", "127.0.0.1:1")
    monkeypatch.setenv("JAXQUAD_PROCESS_ID", "2")
    with pytest.raises(ValueError, match=r"JAXQUAD_PROCESS_ID must lie in \[0, 2\)"):
        parallel.initialize()


def test_cli_too_many_devices_is_a_one_line_error(tmp_path, capsys):
    assert (
        main(
            [
                "simulate",
                "--robots",
                "2",
                "--seconds",
                "0.1",
                "--devices",
                "3",
                "--no-depth",
                "--out",
                str(tmp_path / "sim"),
            ]
        )
        == 1
    )
    err = capsys.readouterr().err.strip()
    assert "\n" not in err and "--devices must lie in [1, 1]" in err
    assert not (tmp_path / "sim").exists()


# ---- subprocesses: 2 devices, 2 processes ------------------------------------------------------


@pytest.fixture(scope="module")
def grid_run(tmp_path_factory):
    out = tmp_path_factory.mktemp("grid") / "grid.npz"
    _two_devices("grid", str(out), timeout=120)
    return out


def test_grid_same_on_two_devices(grid_run):
    r = np.load(grid_run)
    assert r["d1_tp"].shape == (12, 4) and r["d1_tp"].sum() > 0 and r["d1_fp"].sum() > 0 and r["d1_fn"].sum() > 0
    assert len({int(x) for x in r["d1_tp"].sum(1)}) > 2  # the configurations differ
    for k in _COUNTS:
        np.testing.assert_array_equal(r[f"d2_{k}"], r[f"d1_{k}"], err_msg=k)
    # 4 robots split over 2 devices, each holding 2; outputs time-major.
    np.testing.assert_allclose(r["d2_time_major"], np.cumsum(r["time_major_in"], 1).T)
    assert r["d2_shard_shapes"].tolist() == [[5, 2], [5, 2]]


def test_toy_closed_loop_same_on_two_devices(grid_run):
    r = np.load(grid_run)
    qpos0 = np.arange(6.0).reshape(3, 2)
    noise = r["toy_d1_init"] - qpos0 * np.array([1.0, 2.0, 3.0])[:, None]
    assert 0 < np.abs(noise).max() < 0.05 and np.ptp(noise) > 0  # each robot its own key
    # Ticks 0 and 3 of 6 replan: 1 + 0.5 + 0.5 + 1 + 0.5 + 0.5 = 4 times `shared`.
    np.testing.assert_allclose(r["toy_d1_final"], r["toy_d1_init"] + 4 * np.array([0.1, -0.2]), atol=1e-5)
    np.testing.assert_allclose(r["toy_d1_out"][-1], r["toy_d1_final"].sum(1), atol=1e-5)
    for k in ("init", "final", "out"):
        np.testing.assert_allclose(r[f"toy_d2_{k}"], r[f"toy_d1_{k}"], atol=1e-6, err_msg=k)
    assert r["toy_d1_shards"].tolist() == [3] and r["toy_d2_shards"].tolist() == [2, 2]  # 3 robots padded to 4


@pytest.fixture(scope="module")
def slam_ref():
    """The SLAM scenario of the workers on this process's one device."""
    from _parallel_worker import slam_run

    return slam_run(1)


def test_slam_reference_is_a_real_run(slam_ref):
    r = slam_ref
    assert r["final"].shape == (3, 40, 3) and (r["n_nodes"] > 3).all() and np.abs(r["log_odds"]).max() > 1
    assert np.ptp(r["final"][:, -1, 1]) > 0.3  # the robots' paths differ (0.2 m apart)


def test_grid_slam_and_gather_on_two_processes(grid_run, slam_ref, tmp_path):
    out = tmp_path / "mp.npz"
    _two_processes("multiprocess", str(out), timeout=300)
    r, ref = np.load(out), np.load(grid_run)
    np.testing.assert_array_equal(r["gathered"], r["expected"])
    for k in _COUNTS:
        np.testing.assert_array_equal(r[f"grid_{k}"], ref[f"d1_{k}"], err_msg=k)
    for k in ("final", "online", "n_nodes", "log_odds"):  # every robot's SLAM results, gathered on process 0
        _close(r[f"slam_{k}"], slam_ref[k], k)


def _close(a: np.ndarray, b: np.ndarray, key: str) -> None:
    """Equal up to float rounding: each device's program is compiled for its own robot count, and
    XLA may order a sum differently for another batch size (as on one device with another fleet)."""
    if a.dtype.kind == "b":
        np.testing.assert_array_equal(a, b, err_msg=key)
    else:
        np.testing.assert_allclose(a, b, rtol=0, atol=2e-4 * float(np.abs(b).max()) + 1e-6, err_msg=key)


@pytest.fixture(scope="module")
def fleet_run(tmp_path_factory):
    out = tmp_path_factory.mktemp("fleet") / "fleet.npz"
    _two_devices("fleet", str(out), timeout=900)
    return out


@pytest.mark.slow
def test_fleet_same_on_two_devices(fleet_run):
    r = np.load(fleet_run)
    assert r["d1_q"].shape[:2] == (3, 64) and r["d1_depth"].shape == (3, 8, 12, 16) and not r["d1_fallen"].any()
    for k in [f[3:] for f in r.files if f.startswith("d1_")]:
        _close(r[f"d2_{k}"], r[f"d1_{k}"], k)
