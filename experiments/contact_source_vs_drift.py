"""Leg-odometry drift and contact F1 for each contact source, both robots, both gait styles.

For every robot (go2, badger) and style (calm, aggressive): simulate a fleet (no depth camera),
run the estimation pipeline with contacts from ground truth, the plain momentum observer, the
mixed-mode observer (paper defaults) and the mixed-mode observer with tuned numbers, and print
one Markdown table of means over the fleet: contact F1, end-point drift in % of the distance
walked (horizontal and 3D) and ATE.

Tuned numbers come from `jaxquad tune` files given with --tuned ROBOT=PATH; for a robot without
one, the grid tuner (jaxquad.estimate.tune) runs on a separate simulated fleet of the same robot
and style (seed + 1000), so the table never scores parameters on the data that chose them.

    python experiments/contact_source_vs_drift.py [--robots 2] [--seconds 5] [--seed 0]
        [--robot go2 --robot badger] [--style calm --style aggressive] [--tuned go2=go2.yaml]
        [--grid-size 3] [--out DIR]
"""

from __future__ import annotations

import argparse
import os
import platform
import shlex
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

SOURCES = ("truth", "observer", "mixed", "tuned")


def _simulate(robot: str, style: str, robots: int, seconds: float, seed: int, out: Path) -> Path:
    from jaxquad.sim.cli import simulate
    from jaxquad.sim.fleet import FleetConfig

    config = FleetConfig(robot=robot, world="house", n_robots=robots, style=style, seed=seed, depth=False)
    return simulate(config, seconds, out, progress=False)


def _tune(log_path: Path, params_path: Path, grid_size: int) -> dict:
    """Grid-tune the mixed-mode observer on every robot of the log; write the params file."""
    from jaxquad.estimate import tune as T
    from jaxquad.io import load_log
    from jaxquad.robots import load

    log = load_log(log_path)
    robot = load(str(np.asarray(log["robot"])))
    inputs, truth, t = T.observer_inputs(robot, log)
    params, summary = T.tune_fleet(
        "grid", inputs, truth, t, mode="mixed", holdout=0.0, spec=T.GridSpec.default(grid_size)
    )
    T.save_params(params_path, params, header=f"grid-tuned on {log_path}")
    return summary


def _drift(robots: list[dict]) -> float:
    from jaxquad.estimate.scores import fleet_mean

    per_robot = [r["scores"] for r in robots]
    return fleet_mean(per_robot, ("drift", "drift_pct", "mean"), ("drift", "drift_pct", "n_segments"))["mean"]


def _mean(robots: list[dict], *path: str) -> float:
    vals = []
    for r in robots:
        d = r["scores"]
        for key in path:
            d = d.get(key, {}) if isinstance(d, dict) else {}
        if isinstance(d, (int, float)):
            vals.append(float(d))
    return float(np.mean(vals)) if vals else float("nan")


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--robots", type=int, default=2, help="robots per fleet (default 2)")
    parser.add_argument("--seconds", type=float, default=5.0, help="simulated seconds per fleet (default 5)")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--robot", action="append", choices=["go2", "badger"], help="robot(s) (default both)")
    parser.add_argument("--style", action="append", choices=["calm", "aggressive"], help="style(s) (default both)")
    parser.add_argument(
        "--tuned", action="append", default=[], metavar="ROBOT=PATH", help="params file from jaxquad tune"
    )
    parser.add_argument("--grid-size", type=int, default=3, help="grid points per axis when tuning here (default 3)")
    parser.add_argument(
        "--out", default=None, help="keep logs, estimates and tuned params here (default: a temporary folder)"
    )
    args = parser.parse_args(argv)
    if args.robots < 1 or not args.seconds > 0:
        parser.error("--robots must be >= 1 and --seconds positive")
    tuned_files = {}
    for item in args.tuned:
        name, sep, path = item.partition("=")
        if not sep or not Path(path).is_file():
            parser.error(f"--tuned expects ROBOT=PATH of an existing file, got {item!r}")
        tuned_files[name] = Path(path)

    import jax

    from jaxquad.estimate.run import run_estimate

    print(f"command: {shlex.join([sys.executable, *sys.argv])}")
    print(
        f"machine: {platform.node()}, {platform.platform()}, {os.cpu_count()} CPUs, jax {jax.__version__} on "
        f"{jax.devices()[0].platform}"
    )
    print(
        f"fleets: {args.robots} robots x {args.seconds:g} s in the house world, seed {args.seed}; "
        f"scores are means over each fleet's robots\n"
    )
    t_start = time.perf_counter()
    work = Path(args.out) if args.out else Path(tempfile.mkdtemp(prefix="contact_source_vs_drift."))
    rows = []
    for robot in args.robot or ["go2", "badger"]:
        for style in args.style or ["calm", "aggressive"]:
            t0 = time.perf_counter()
            folder = work / f"{robot}_{style}"
            log_path = _simulate(robot, style, args.robots, args.seconds, args.seed, folder / "eval")
            params = {"truth": None, "observer": None, "mixed": None, "tuned": tuned_files.get(robot)}
            note = "file" if params["tuned"] else "grid here"
            if params["tuned"] is None:
                tune_log = _simulate(robot, style, args.robots, args.seconds, args.seed + 1000, folder / "tune")
                params["tuned"] = folder / "tuned.yaml"
                _tune(tune_log, params["tuned"], args.grid_size)
            for source in SOURCES:
                contacts = "mixed" if source == "tuned" else source
                s = run_estimate(log_path, folder / f"estimate_{source}", contacts, params[source])
                fallen = sum(r["fallen"] for r in s["robots"])
                rows.append(
                    (
                        robot,
                        style,
                        source + (f" ({note})" if source == "tuned" else ""),
                        _mean(s["robots"], "contacts", "f1"),
                        _drift(s["robots"]),
                        _mean(s["robots"], "drift", "z_error_final_m"),
                        _mean(s["robots"], "trajectory", "ate", "rmse"),
                        f"{len(s['robots'])} ({fallen})",
                    )
                )
            print(f"[{robot} {style}: {time.perf_counter() - t0:.0f} s]", file=sys.stderr, flush=True)

    print(
        "| robot | style | contacts | contact F1 | drift % (2-10 m segments) | z error at end m | ATE m "
        "| robots (fallen) |"
    )
    print("|---|---|---|---:|---:|---:|---:|---:|")
    for robot, style, source, f1, dh, dz, ate, n in rows:
        print(f"| {robot} | {style} | {source} | {f1:.3f} | {dh:.1f} | {dz:+.2f} | {ate:.3f} | {n} |")
    print("\nMeans over robots; drift weighted by each robot's segment count (jaxquad.metrics.segment_drift).")
    kept = f"outputs in {work}" if args.out else "outputs removed (use --out to keep them)"
    print(f"\nwall time {time.perf_counter() - t_start:.0f} s; {kept}")
    if not args.out:
        import shutil

        shutil.rmtree(work, ignore_errors=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
