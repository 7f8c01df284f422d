"""`jaxquad estimate LOG --out DIR`: contacts and leg-inertial odometry over a robot log.

Writes per robot a TUM trajectory, an .npz of contacts, forces, twists and flags, stabilized and
baseline scans when the log has depth, and summary.json with flag counts and, when the log has ground truth, scores (see jaxquad.estimate.run).
"""

from __future__ import annotations

import argparse


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("log", help="robot log (.npz, single robot or fleet)")
    parser.add_argument("--out", required=True, help="output folder")
    parser.add_argument("--params", default=None, help="observer parameters (YAML or JSON); paper defaults if absent")
    parser.add_argument(
        "--contacts",
        choices=("observer", "mixed", "sensor", "truth"),
        default="mixed",
        help="contact source: momentum observer (plain or mixed mode), the robot's sensors, or ground truth",
    )
    parser.add_argument(
        "--feet", choices=("rolling", "point"), default="rolling",
        help="leg odometry foot model: contact points of round feet rolling on the floor, or the foot centres "
        "fixed in the world (default rolling)",
    )
    parser.add_argument(
        "--robust", choices=("huber", "cauchy", "none"), default="huber",
        help="robust loss over the stance feet against slipping feet (default huber)",
    )
    parser.add_argument(
        "--no-floor", action="store_true",
        help="integrate the base height instead of fusing it with the floor under the stance feet (default: fuse)",
    )
    parser.add_argument("--band-height", type=int, default=5, help="scan band height in px (5 sim, 30 real robot)")
    parser.add_argument("--range-min", type=float, default=0.2, help="scan minimum range, m")
    parser.add_argument("--range-max", type=float, default=8.0, help="scan maximum range, m")


def run(args: argparse.Namespace) -> int:
    import json

    from tqdm import tqdm

    from jaxquad.estimate.run import run_estimate

    bar = tqdm(total=None, desc="estimate", unit="robot")

    def progress(done: int, total: int) -> None:
        bar.total = total
        bar.update(done - bar.n)

    try:
        summary = run_estimate(
            args.log, args.out, args.contacts, args.params, progress, args.band_height, args.range_min, args.range_max,
            odometry=dict(rolling=args.feet == "rolling", robust=args.robust, floor=not args.no_floor),
        )
    finally:
        bar.close()
    brief = {"robots": len(summary["robots"]), "fallen": sum(r["fallen"] for r in summary["robots"])}
    for key, path in (("contact_f1", ("contacts", "f1")), ("drift_horizontal_pct", ("drift", "horizontal_pct"))):
        vals = [r["scores"][path[0]][path[1]] for r in summary["robots"] if path[0] in r["scores"]]
        if vals:
            brief[f"mean_{key}"] = sum(vals) / len(vals)
    print(json.dumps(brief))
    return 0
