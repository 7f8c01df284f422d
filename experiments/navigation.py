"""Navigation success of the baseline and the full system (the paper's Table II) in the closed loop.

For each robot, world and variant it runs `jaxquad.nav.navigate` on `--worlds` generated worlds
(seeds `--seed`, `--seed` + 1, ...), each with a fleet of `--robots` robots sent to `--goals` random
reachable goals in turn on the world's true map, and prints two Markdown tables: success rates laid
out as Table II (a goal succeeds when the navigation stack reports arrival and the true pose is
within 0.25 m / 0.25 rad), and per cell the outcome counts, time to goal, localization error and
speed. Variants: `full` (leg-inertial odometry + IMU-stabilized scans), `baseline` (depth visual
odometry + fixed-row scans); `--ablation` adds B+LO (leg odometry + fixed rows) and B+SS (visual
odometry + stabilized scans).

    python experiments/navigation.py [--robot go2 --robot badger] [--world house --world warehouse]
        [--robots 2] [--goals 2] [--worlds 1] [--seed 0] [--style aggressive] [--samples 256]
        [--horizon 30] [--particles 500] [--max-seconds S] [--ablation | --cell full ...] [--out DIR]
        [--json rows.json]
    python experiments/navigation.py --merge go2_house.json go2_warehouse.json ... [--json table.json]

`--cell` picks rows (repeatable); `--merge` prints the tables of cells run as separate jobs (one cell per
job where a job's time is limited) from their `--json` files.
"""

from __future__ import annotations

import argparse
import platform
import sys
import time

import numpy as np

CELLS = {  # row label -> (variant, odometry override, scans override)
    "baseline": ("baseline", None, None),
    "B+LO": ("baseline", "leg", None),
    "B+SS": ("baseline", None, "stabilized"),
    "full": ("full", None, None),
}


def run_cell(args, robot: str, world: str, label: str) -> dict:
    import jax

    from jaxquad.nav.closed_loop import OUTCOMES, REACHED
    from jaxquad.nav.fleet import NavConfig, navigate
    from jaxquad.nav.report import plot_paths, summarize

    variant, odometry, scans = CELLS[label]
    outcome, elapsed, errors, compile_s, run_s, robot_s = [], [], [], 0.0, 0.0, 0.0
    for seed in range(args.seed, args.seed + args.worlds):
        cfg = NavConfig(
            robot=robot,
            world=world,
            n_robots=args.robots,
            n_goals=args.goals,
            variant=variant,
            odometry=odometry,
            scans=scans,
            style=args.style,
            seed=seed,
            particles=args.particles,
            samples=args.samples,
            horizon=args.horizon,
            max_seconds=args.max_seconds,
            trace_robots=8,
            devices=args.devices,
        )
        t0 = time.perf_counter()

        def progress(done, total, t0=t0, tag=f"{robot} {world} {label} seed {seed}"):
            print(f"{tag}: {done}/{total} goals ended, {time.perf_counter() - t0:.0f} s", file=sys.stderr, flush=True)

        result = navigate(cfg, progress=progress)
        print(f"{robot} {world} {label} seed {seed}: {time.perf_counter() - t0:.0f} s", file=sys.stderr, flush=True)
        outcome.append(result.outcome)
        elapsed.append(result.elapsed[result.outcome == REACHED])
        errors.append(result.loc_error[result.active].ravel())
        compile_s += result.compile_s
        run_s += result.run_s
        robot_s += args.robots * result.sim_s
        if args.out:
            from pathlib import Path

            from jaxquad.io.jsonfile import write_json

            folder = Path(args.out) / f"{robot}_{world}_{label}_seed{seed}"
            folder.mkdir(parents=True, exist_ok=True)
            write_json(folder / "summary.json", summarize(result))
            plot_paths(result, folder / "paths.png")
    outcome = np.concatenate(outcome)
    err = np.concatenate(errors)
    times = np.concatenate(elapsed)
    return {
        "robot": robot,
        "world": world,
        "cell": label,
        "runs": int(outcome.shape[0]),
        "goals": int(outcome.size),
        "success_rate": float((outcome == REACHED).mean()),
        "outcomes": {name: int((outcome == code).sum()) for code, name in enumerate(OUTCOMES)},
        "time_to_goal_median_s": float(np.median(times)) if times.size else None,
        "loc_error_median_m": float(np.median(err)) if err.size else None,
        "loc_error_p99_m": float(np.percentile(err, 99)) if err.size else None,
        "compile_s": compile_s,
        "run_s": run_s,
        "robot_seconds_per_s": robot_s / run_s if run_s > 0 else None,
        "device": jax.devices()[0].device_kind,
        "devices": args.devices or jax.local_device_count(),
        "settings": {
            k: getattr(args, k)
            for k in ("robots", "goals", "worlds", "seed", "style", "samples", "horizon", "particles", "max_seconds")
        },
    }


def markdown(rows: list[dict]) -> str:
    """Table II (success rate per method and robot/world) and the per-cell details, as Markdown."""
    labels = [x for x in CELLS if any(r["cell"] == x for r in rows)]
    cols = list(dict.fromkeys((r["world"], r["robot"]) for r in rows))
    lines = ["| method | " + " | ".join(f"{w} / {r}" for w, r in cols) + " |", "|---|" + "---:|" * len(cols)]
    for label in labels:
        cells = {(x["world"], x["robot"]): x for x in rows if x["cell"] == label}
        lines.append(
            f"| {label} | "
            + " | ".join(
                f"{100 * cells[c]['success_rate']:.1f}% of {cells[c]['goals']}" if c in cells else "-" for c in cols
            )
            + " |"
        )
    lines += [
        "",
        "| robot | world | method | runs | reached | missed | collided | lost | timeout | fallen | skipped "
        "| pending | time to goal s (median) | loc. error m (median / p99) | compile s | robot-s per s |",
        "|---|---|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---|---:|---:|",
    ]
    fmt = lambda v, d=3: "-" if v is None else f"{v:.{d}f}"  # noqa: E731
    for x in rows:
        o = x["outcomes"]
        lines.append(
            f"| {x['robot']} | {x['world']} | {x['cell']} | {x['runs']} | {o['reached']} | {o['missed']} | "
            f"{o['collided']} | {o['lost']} | {o['timeout']} | {o['fallen']} | {o['skipped']} | {o['pending']} | "
            f"{fmt(x['time_to_goal_median_s'], 1)} | {fmt(x['loc_error_median_m'])} / {fmt(x['loc_error_p99_m'])} | "
            f"{x['compile_s']:.0f} | {fmt(x['robot_seconds_per_s'], 1)} |"
        )
    return "\n".join(lines)


def merge(paths: list[str]) -> list[dict]:
    """The rows of several saved results as one list: a robot/world/method cell may appear once, and every row
    must have been run with the same settings (fleet size, goals, MPPI and AMCL sizes, ...; the time cap aside)."""
    import json
    from pathlib import Path

    rows, seen, settings = [], {}, None
    for path in paths:
        try:
            saved = json.loads(Path(path).read_text())
        except (OSError, ValueError) as e:
            raise ValueError(f"{path}: not a saved navigation result ({e})") from None
        if not isinstance(saved, list) or not all(
            isinstance(r, dict) and {"robot", "world", "cell"} <= r.keys() for r in saved
        ):
            raise ValueError(f"{path}: not a saved navigation result (expected a list of rows)")
        for r in saved:
            # The time cap may differ (a long warehouse cell): goals it cut off show as `pending`.
            mine = {k: v for k, v in (r.get("settings") or {}).items() if k != "max_seconds"}
            settings = mine if settings is None else settings
            if mine != settings:
                raise ValueError(f"{path}: settings {mine} differ from {paths[0]}'s {settings}")
            key = (r["robot"], r["world"], r["cell"])
            if key in seen:
                raise ValueError(f"{path}: cell {'/'.join(key)} is also in {seen[key]}")
            seen[key] = path
            rows.append(r)
    return rows


def main(argv: list[str] | None = None) -> list[dict]:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--robot", action="append", choices=["go2", "badger"], help="robots (default: both)")
    p.add_argument("--world", action="append", choices=["house", "warehouse"], help="worlds (default: both)")
    p.add_argument("--robots", type=int, default=2, help="robots per fleet (default 2)")
    p.add_argument("--goals", type=int, default=2, help="goals per robot (default 2; the paper: 5)")
    p.add_argument("--worlds", type=int, default=1, help="generated worlds per cell, one fleet each (default 1)")
    p.add_argument("--seed", type=int, default=0, help="seed of the first world (default 0)")
    p.add_argument("--style", default="aggressive", choices=["calm", "aggressive"], help="gait (default aggressive)")
    p.add_argument("--samples", type=int, default=256, help="MPPI samples (default 256; the library's 1000)")
    p.add_argument("--horizon", type=int, default=30, help="MPPI horizon in ticks (default 30; the library's 40)")
    p.add_argument("--particles", type=int, default=500, help="AMCL particles (default 500; the library's 2000)")
    p.add_argument(
        "--max-seconds",
        type=float,
        default=None,
        help="cap on each run's simulated time, s; goals still running count as failures (default: none)",
    )
    which = p.add_mutually_exclusive_group()
    which.add_argument("--ablation", action="store_true", help="add the B+LO and B+SS rows")
    which.add_argument(
        "--cell", action="append", choices=tuple(CELLS), help="methods to run (repeatable; default both)"
    )
    which.add_argument(
        "--merge", nargs="+", default=None, metavar="JSON", help="print the tables of saved rows (runs nothing)"
    )
    p.add_argument(
        "--devices", type=int, default=None, help="split each fleet's robots over the first N devices (default all)"
    )
    p.add_argument("--out", default=None, help="folder for each run's summary.json and paths.png")
    p.add_argument("--json", default=None, help="write the rows as JSON here")
    args = p.parse_args(argv)
    if args.merge:
        try:
            rows = merge(args.merge)
        except ValueError as e:
            p.error(str(e))
    else:
        robots = args.robot or ["go2", "badger"]
        worlds = args.world or ["house", "warehouse"]
        labels = args.cell or (list(CELLS) if args.ablation else ["baseline", "full"])

        import jax

        print(f"`python {' '.join(sys.argv)}`  ")
        print(f"machine: {platform.node()}, {jax.devices()[0].device_kind}, jax {jax.__version__}\n")
        rows = [run_cell(args, r, w, label) for label in labels for r in robots for w in worlds]
    print(markdown(rows))
    if args.json:
        from jaxquad.io.jsonfile import write_json

        write_json(args.json, rows)
    return rows


if __name__ == "__main__":
    main()
