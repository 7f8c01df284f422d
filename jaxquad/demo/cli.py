"""`jaxquad demo`: simulate a small fleet, estimate, score, and write a report folder (see demo.run)."""

from __future__ import annotations

import argparse
from pathlib import Path


def add_arguments(parser: argparse.ArgumentParser) -> None:
    from jaxquad.sim.cli import parse_resolution

    parser.add_argument(
        "--out",
        default="jaxquad-demo",
        help="report folder (default jaxquad-demo; replaced only if it holds an earlier demo)",
    )
    parser.add_argument("--robots", type=int, default=4, help="fleet size (default 4)")
    parser.add_argument("--seconds", type=float, default=20.0, help="simulated time per robot, s (default 20)")
    parser.add_argument("--robot", default="go2", choices=["go2", "badger"], help="robot model (default go2)")
    parser.add_argument(
        "--world", default="house", choices=["house", "warehouse"], help="generated world (default house)"
    )
    parser.add_argument(
        "--style", default="aggressive", choices=["calm", "aggressive"], help="gait style (default aggressive)"
    )
    parser.add_argument("--seed", type=int, default=0, help="random seed of worlds, routes and noise (default 0)")
    parser.add_argument(
        "--resolution", type=parse_resolution, default=(160, 120), help="depth image WxH, px (default 160x120)"
    )


def run(args: argparse.Namespace) -> int:
    from jaxquad.demo.run import run_demo
    from jaxquad.demo.summary import format_table

    summary = run_demo(
        args.out, args.robots, args.seconds, args.robot, args.world, args.style, args.seed, args.resolution
    )
    print()
    print(format_table(summary["sources"], summary["scans"]))
    print()
    fell = sum(summary["fallen"])
    times = ", ".join(f"{k} {v:.0f} s" for k, v in summary["wall_s"].items())
    print(f"{len(summary['fallen'])} robots, {fell} fell; wall time: {times}")
    print(
        f"wrote {Path(args.out).resolve()}: summary.json, trajectories.png, contacts.png, scan_frame.png, "
        "sim/, estimate_*/"
    )
    return 0
