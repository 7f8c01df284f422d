"""`jaxquad vo LOG --out DIR`: depth-inertial visual odometry, guided and restarted by leg odometry.

Runs the estimator for the leg odometry, then the visual odometry over every robot of the log; writes
per robot a TUM trajectory at the depth frames' stamps and summary.json (tracking losses, keyframes,
alignment statistics and, when the log has ground truth, ATE/ARE/RPE and drift of the visual and
of the leg odometry at the same stamps; see jaxquad.vo.fleet).
"""

from __future__ import annotations

import argparse


def add_arguments(parser: argparse.ArgumentParser) -> None:
    from jaxquad.vo.odometry import COUPLINGS

    parser.add_argument(
        "log",
        help="robot log with depth (.npz, single robot or fleet; see the README's log format)",
    )
    parser.add_argument(
        "--out",
        required=True,
        help="output folder (created; replaced only if it holds an earlier run)",
    )
    parser.add_argument(
        "--leg-odometry",
        choices=COUPLINGS,
        default="guess+restart",
        help="coupling: off = constant-velocity guess, restart at the last pose (RTAB-Map's default); guess = leg "
        "motion as guess and translation prior; guess+restart = also restart from the leg odometry (default)",
    )
    parser.add_argument(
        "--contacts",
        choices=("observer", "mixed", "sensor", "truth"),
        default="mixed",
        help="contact source of the leg odometry (default mixed)",
    )


def run(args: argparse.Namespace) -> int:
    from jaxquad.cli import progress_bar
    from jaxquad.io.jsonfile import to_json
    from jaxquad.vo.fleet import run_vo

    # run_vo checks the output folder and the log before its first progress report.
    with progress_bar("vo", "robot") as progress:
        summary = run_vo(args.log, args.out, args.leg_odometry, args.contacts, progress)
    robots = summary["robots"]
    brief = {
        "robots": len(robots),
        "coupling": args.leg_odometry,
        "out": str(args.out),
        "tracking_losses": sum(r["tracking_losses"] for r in robots),
    }
    ates = [
        r["scores"]["vo"]["trajectory"]["ate"]["rmse"]
        for r in robots
        if "ate" in r.get("scores", {}).get("vo", {}).get("trajectory", {})
    ]
    if ates:
        brief["mean_ate_m"], brief["max_ate_m"] = sum(ates) / len(ates), max(ates)
    print(to_json(brief))
    return 0
