"""`jaxquad bench --metrics`: `jaxquad eval` against evo's command line on one long trajectory, and the
batched metrics path in trajectories per second.

Both command lines run as subprocesses in the same bench run on the same files, so their wall times
(start-up and file reading included) compare like for like: one `jaxquad eval` against `evo_ape` for
ATE, ARE and APE plus `evo_rpe` for every RPE delta.
"""

from __future__ import annotations

import argparse
import os
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

_DELTAS = ("2", "5", "10")


def add_arguments(parser: argparse._ArgumentGroup) -> None:  # the bench command's group for this section
    parser.add_argument(
        "--eval-poses",
        type=int,
        default=100_000,
        metavar="N",
        help="poses of the trajectory for jaxquad eval vs evo (default: 100000)",
    )
    parser.add_argument(
        "--n-traj",
        type=int,
        default=64,
        metavar="N",
        help="trajectories in the batched path (default: 64; use 10000 on a GPU)",
    )
    parser.add_argument(
        "--traj-poses", type=int, default=5000, metavar="N", help="poses per batched trajectory (default: 5000)"
    )


def _write_pair(directory: Path, n: int) -> tuple[Path, Path]:
    """A 100 Hz reference and a noisy, offset, slightly rescaled 100 Hz estimate (2 ms clock offset)."""
    import numpy as np

    from jaxquad.io.tum import TumTrajectory, write_tum

    rng = np.random.default_rng(0)
    t = np.arange(n) * 0.01
    s = np.linspace(0.0, n / 100.0, n)  # ~1 m/s along a wandering loop
    p = np.stack([20 * np.cos(s / 20), 15 * np.sin(s / 13), 0.3 * np.sin(s)], 1)
    yaw = np.unwrap(np.arctan2(np.gradient(p[:, 1]), np.gradient(p[:, 0])))
    q = np.stack([np.zeros(n), np.zeros(n), np.sin(yaw / 2), np.cos(yaw / 2)], 1)
    q_est = q + 0.01 * rng.normal(size=q.shape)
    q_est /= np.linalg.norm(q_est, axis=1, keepdims=True)
    ref, est = directory / "ref.tum", directory / "est.tum"
    write_tum(ref, TumTrajectory(t, p, q))
    write_tum(est, TumTrajectory(t + 0.002, 1.02 * p + 0.05 * rng.normal(size=p.shape) + 1.0, q_est))
    return ref, est


def _wall(cmd: list[str]) -> float:
    t0 = time.perf_counter()
    subprocess.run(cmd, check=True, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    return time.perf_counter() - t0


def _cli_vs_evo(n: int) -> list[dict]:
    bindir = Path(sys.executable).parent
    evo_ape = shutil.which("evo_ape", path=str(bindir)) or shutil.which("evo_ape")
    evo_rpe = shutil.which("evo_rpe", path=str(bindir)) or shutil.which("evo_rpe")
    with tempfile.TemporaryDirectory() as tmp:
        ref, est = _write_pair(Path(tmp), n)
        ours = _wall(
            [
                sys.executable,
                "-m",
                "jaxquad.cli",
                "eval",
                str(ref),
                str(est),
                "--align",
                "se3",
                "--delta",
                *_DELTAS,
                "--json",
            ]
        )
        rows = [
            {
                "case": f"jaxquad eval ({n} poses, ATE ARE APE RPE {'/'.join(_DELTAS)} m)",
                "wall_s": ours,
                "evo_over_ours": 1.0,
            }
        ]
        if evo_ape is None or evo_rpe is None:
            return rows
        evo = sum(
            _wall([evo_ape, "tum", str(ref), str(est), "-a", "-r", r]) for r in ("trans_part", "angle_rad", "full")
        )
        evo += sum(
            _wall([evo_rpe, "tum", str(ref), str(est), "-a", "-r", "trans_part", "-d", d, "-u", "m"]) for d in _DELTAS
        )
        rows.append(
            {"case": f"evo_ape x3 + evo_rpe x{len(_DELTAS)} (same metrics)", "wall_s": evo, "evo_over_ours": evo / ours}
        )
    return rows


def _batched(n_traj: int, n_poses: int) -> dict:
    import jax
    import jax.numpy as jnp

    from jaxquad.bench import time_jitted
    from jaxquad.metrics._evaluate import _batched as batched_fn

    key_p, key_q = jax.random.split(jax.random.PRNGKey(0))
    s = jnp.linspace(0.0, 50.0, n_poses)
    phase = jnp.linspace(0.0, 3.0, n_traj)[:, None]
    p_ref = jnp.stack([20 * jnp.cos(s / 20 + phase), 15 * jnp.sin(s / 13 + phase), 0.3 * jnp.sin(s + phase)], -1)
    yaw = s / 10 + phase
    zeros = jnp.zeros_like(yaw)
    q_ref = jnp.stack([zeros, zeros, jnp.sin(yaw / 2), jnp.cos(yaw / 2)], -1)
    p_est = p_ref + 0.05 * jax.random.normal(key_p, p_ref.shape)
    q_est = q_ref + 0.01 * jax.random.normal(key_q, q_ref.shape)
    deltas = jnp.asarray([2.0, 5.0, 10.0], p_ref.dtype)
    fn = batched_fn("se3", "m", False, 0.1)
    compile_s, run_ms = time_jitted(fn, p_ref, q_ref, p_est, q_est, deltas, deltas, repeats=5)
    return {
        "case": f"evaluate_batch {n_traj} x {n_poses} poses (float32, se3, RPE and drift 2/5/10 m)",
        "compile_s": compile_s,
        "run_ms": run_ms,
        "traj_per_s": n_traj / (run_ms / 1e3),
    }


def run(args: argparse.Namespace) -> dict:
    for name in ("eval_poses", "n_traj", "traj_poses"):
        if getattr(args, name) < 3:
            raise ValueError(f"--{name.replace('_', '-')} must be >= 3, got {getattr(args, name)}")
    rows = _cli_vs_evo(args.eval_poses)
    b = _batched(args.n_traj, args.traj_poses)
    out = {
        "rows": rows,
        "batched": b["case"],
        "batched_compile_s": b["compile_s"],
        "batched_run_ms": b["run_ms"],
        "batched_traj_per_s": b["traj_per_s"],
    }
    if len(rows) > 1:
        out["evo_over_jaxquad_eval"] = rows[1]["evo_over_ours"]
    out["cpu_count"] = os.cpu_count()
    return out
