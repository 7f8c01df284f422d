"""`jaxquad slam` on real 2D laser scans with odometry of a known drift.

    python experiments/laser_drift.py LOG [LOG ...] [--seeds 0 1 2] [--scale 0.01] [--rot-scale 0.01]
        [--heading-drift 0.004] [--params FILE] --out DIR [--json rows.json]

Each LOG is a CARMEN log whose scans carry good poses (a "corrected" log, as SLAM programs write them:
the public Radish logs converted by gmapping, for instance). Those poses are the reference; the
odometry is re-drawn from their scan-to-scan steps (dx, dy, dtheta; travel d = |(dx, dy)|) with a
scale error, a rotation-scale error, a heading drift per metre and Gaussian noise of std 0.005 d +
1e-4 m on x and y and 0.002 d + 0.002 |dtheta| + 1e-4 rad on the heading, one draw per seed. The
log with that odometry and the reference goes to DIR/<log>_s<seed>.npz (the `.npz` laser-log form)
and through `jaxquad slam` (laser.yaml's defaults, or --params) into DIR/<log>_s<seed>/; a Markdown
table (stdout) gives per log and seed the odometry's and the SLAM's ATE (summary.json's, evo's
definition, SE(3)-aligned) and the wall time.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import re
import shlex
import sys
import time
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np


def drifted_odometry(ref, scale: float, rot_scale: float, heading_drift: float, seed: int) -> np.ndarray:
    """Odometry (S, 3) integrated from the steps of the reference poses `ref` (S, 3) with the errors
    of the module docstring."""
    from jaxquad.kernels.lie import se2, xy_theta

    ref = jnp.asarray(ref)
    steps = np.asarray(xy_theta(se2(ref[:-1]).inverse() @ se2(ref[1:])), np.float64)
    d = np.hypot(steps[:, 0], steps[:, 1])
    std = np.stack([0.005 * d + 1e-4, 0.005 * d + 1e-4, 0.002 * d + 0.002 * np.abs(steps[:, 2]) + 1e-4], 1)
    noise = np.random.default_rng(seed).normal(size=steps.shape) * std
    bad = steps * [1 + scale, 1 + scale, 1 + rot_scale]
    bad[:, 2] += heading_drift * d
    bad += noise

    def step(T, delta):
        T = T @ se2(delta)
        return T, xy_theta(T)

    _, poses = jax.lax.scan(step, se2(ref[0]), jnp.asarray(bad, ref.dtype))
    return np.concatenate([np.asarray(ref[:1], np.float64), np.asarray(poses, np.float64)])


def run(log_path: Path, seed: int, args) -> dict:
    from jaxquad.cli import main
    from jaxquad.io.carmen import LaserLog, in_time_order, read_carmen, save_laser_npz

    log = read_carmen(log_path)
    ref = log.scan_odom_xytheta
    odom = drifted_odometry(ref, args.scale, args.rot_scale, args.heading_drift, seed)
    keep = in_time_order(log.scan_t)  # the odometry stream must be in time order
    name = re.sub(r"(\.log|\.clf)?(\.gz)?$", "", log_path.name) + f"_s{seed}"
    npz = save_laser_npz(
        args.out / f"{name}.npz",
        LaserLog(
            log.scan_t, log.ranges, log.bearings, log.scan_t[keep], odom[keep], odom, log.T_base_laser_xytheta, ref
        ),
    )
    argv = ["slam", str(npz), "--out", str(args.out / name)] + (["--params", args.params] if args.params else [])
    t0 = time.perf_counter()
    if main(argv) != 0:
        raise SystemExit(f"jaxquad slam failed on {npz}")
    wall = time.perf_counter() - t0
    robot = json.loads((args.out / name / "summary.json").read_text())["robots"][0]
    ate = {w: robot["scores"][w].get("ate", {}).get("rmse") for w in ("odometry", "final")}
    path = float(np.sum(np.hypot(*np.diff(ref[:, :2], axis=0).T)))
    return {
        "log": log_path.name,
        "seed": seed,
        "scans": log.n_scans,
        "path_m": path,
        "nodes": robot["nodes"],
        "loop_closures": robot["loop_closures"],
        "ate_odometry_m": ate["odometry"],
        "ate_slam_m": ate["final"],
        "wall_s": wall,
    }


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("logs", nargs="+", type=Path, help="corrected CARMEN logs (their scan poses are the reference)")
    p.add_argument("--seeds", nargs="+", type=int, default=[0], help="one odometry draw per seed (default 0)")
    p.add_argument("--scale", type=float, default=0.01, help="translation scale error (default 0.01)")
    p.add_argument("--rot-scale", type=float, default=0.01, help="rotation scale error (default 0.01)")
    p.add_argument("--heading-drift", type=float, default=0.004, help="heading drift, rad/m (default 0.004)")
    p.add_argument("--params", default=None, help="SLAM parameters over laser.yaml's defaults (YAML)")
    p.add_argument("--out", type=Path, required=True, help="folder for the drifted logs and the SLAM outputs")
    p.add_argument("--json", type=Path, default=None, help="write the rows here")
    args = p.parse_args(argv)
    missing = [str(log) for log in args.logs if not log.is_file()]
    if missing:
        p.error(f"log not found: {', '.join(missing)}")
    try:
        args.out.mkdir(parents=True, exist_ok=True)
    except OSError as e:
        p.error(f"--out {args.out}: {e.strerror}")
    print(f"command: python experiments/laser_drift.py {shlex.join(sys.argv[1:] if argv is None else argv)}")
    print(
        f"machine: {platform.node()}, {platform.processor() or platform.machine()}, {os.cpu_count()} CPUs, "
        f"jax {jax.__version__} ({jax.default_backend()})"
    )
    rows = [run(log, seed, args) for log in args.logs for seed in args.seeds]
    print("| log | seed | scans | path m | nodes | loops | ATE odometry m | ATE SLAM m | wall s |")
    print("|---|---:|---:|---:|---:|---:|---:|---:|---:|")
    for r in rows:
        print(
            f"| {r['log']} | {r['seed']} | {r['scans']} | {r['path_m']:.0f} | {r['nodes']} | {r['loop_closures']} | "
            f"{r['ate_odometry_m']:.3f} | {r['ate_slam_m']:.3f} | {r['wall_s']:.0f} |"
        )
    if args.json:
        args.json.write_text(json.dumps(rows, indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())
