"""`jaxquad estimate LOG --out DIR`: contacts and leg-inertial odometry over a robot log.

Writes per robot a TUM trajectory, an .npz of contacts, forces, twists and flags, stabilized and
baseline scans when the log has depth, and summary.json with flag counts and, when the log has ground
truth, scores (see jaxquad.estimate.run).
"""

from __future__ import annotations

import argparse

from jaxquad.cli import add_band_reduce_argument, add_devices_argument


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("log", help="robot log (.npz, single robot or fleet; see the README's log format)")
    parser.add_argument(
        "--out", required=True, help="output folder (created; replaced only if it holds an earlier estimate)"
    )
    parser.add_argument(
        "--params", default=None, help="observer parameters, YAML or JSON (default: the paper's numbers)"
    )
    parser.add_argument(
        "--contacts",
        choices=("observer", "mixed", "sensor", "truth"),
        default="mixed",
        help="contact source: momentum observer (plain or mixed mode), the robot's sensors, or ground truth "
        "(default mixed)",
    )
    parser.add_argument(
        "--band-height", type=int, default=5, help="scan band height, px (default 5 = simulation; 30 on the real robot)"
    )
    add_band_reduce_argument(parser)
    parser.add_argument("--range-min", type=float, default=0.2, help="scan minimum range, m (default 0.2)")
    parser.add_argument("--range-max", type=float, default=8.0, help="scan maximum range, m (default 8.0)")
    parser.add_argument(
        "--feet",
        choices=("rolling", "point"),
        default="rolling",
        help="leg odometry foot model: contact points of round feet rolling on the floor, or the foot centres "
        "fixed in the world (default rolling)",
    )
    parser.add_argument(
        "--robust",
        choices=("huber", "cauchy", "none"),
        default="huber",
        help="robust loss over the stance feet against slipping feet (default huber)",
    )
    parser.add_argument(
        "--no-robust-prior",
        action="store_true",
        help="weigh the stance feet against the current solve only, not also against the previous sample's "
        "velocity, which picks out feet sliding at touchdown and lift-off (default: both; no effect with "
        "--robust none)",
    )
    parser.add_argument(
        "--no-settle",
        action="store_true",
        help="give a foot its full twist weight from its first stance sample instead of ramping it up over "
        "its first 32 ms, while it may still slide (default: ramp)",
    )
    parser.add_argument(
        "--no-floor",
        action="store_true",
        help="integrate the base height instead of fusing it with the floor under the stance feet (default: fuse)",
    )
    add_devices_argument(parser)


def run(args: argparse.Namespace) -> int:
    from jaxquad import parallel
    from jaxquad.cli import progress_bar
    from jaxquad.estimate import scores
    from jaxquad.estimate.run import SUMMARY_KIND, run_estimate
    from jaxquad.io import check_output_dir, load_log, read_observer_params
    from jaxquad.io.jsonfile import to_json

    if args.band_height < 1:
        raise ValueError(f"--band-height must be >= 1 px, got {args.band_height}")
    if not (0 <= args.range_min < args.range_max):
        raise ValueError(f"need 0 <= --range-min < --range-max, got {args.range_min} and {args.range_max}")
    # Everything the user gave is checked before the (long) estimation starts; the log against the
    # robot and the contact source in run_estimate, before its first progress report.
    check_output_dir(args.out, kind=SUMMARY_KIND)
    log = load_log(args.log)
    if args.params is not None:
        read_observer_params(args.params)
    odometry = dict(
        rolling=args.feet == "rolling",
        robust=args.robust,
        robust_prior=not args.no_robust_prior,
        floor=not args.no_floor,
        settle=not args.no_settle,
    )
    with progress_bar("estimate", "robot") as progress:
        summary = run_estimate(
            log,
            args.out,
            args.contacts,
            args.params,
            progress,
            args.band_height,
            args.range_min,
            args.range_max,
            odometry=odometry,
            devices=args.devices,
            band_reduce=args.band_reduce,
        )
    if not parallel.is_main():
        return 0
    robots = summary["robots"]
    brief = {"robots": len(robots), "fallen": sum(r["fallen"] for r in robots), "out": str(args.out)}
    per_robot = [r["scores"] for r in robots]
    # Fleet means say what they average: robots (and, for drift, segments as weights).
    brief["contact_f1"] = scores.fleet_mean(per_robot, ("contacts", "f1"))
    brief["drift_pct"] = scores.fleet_mean(
        per_robot, ("drift", "drift_pct", "mean"), ("drift", "drift_pct", "n_segments")
    )
    brief["z_error_final_m"] = scores.fleet_mean(per_robot, ("drift", "z_error_final_m"))
    print(to_json(brief))
    return 0
