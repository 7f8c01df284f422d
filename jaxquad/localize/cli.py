"""`jaxquad localize LOG --map map.yaml --out DIR`: AMCL localization of a log's robots on a saved map.

Writes per robot a TUM trajectory of the localization pose at every depth frame and an .npz of the
filter's outputs, and summary.json with the parameters used and, where the log has ground truth,
position errors and (global localization) the convergence time (see jaxquad.localize.run)."""

from __future__ import annotations

import argparse


def add_arguments(parser: argparse.ArgumentParser) -> None:
    from jaxquad.cli import add_band_reduce_argument

    parser.add_argument("log", help="robot log (.npz, single robot or fleet) with depth images")
    parser.add_argument("--map", required=True, help="occupancy map YAML (PGM + YAML, map_server format, yaw 0)")
    parser.add_argument(
        "--out", required=True, help="output folder (created; replaced only if it holds an earlier localization)"
    )
    start = parser.add_mutually_exclusive_group(required=True)
    start.add_argument(
        "--initial-pose",
        type=float,
        nargs=3,
        metavar=("X", "Y", "THETA"),
        help="known start pose in the map, m m rad, for every robot (spread by initial_std_xy/yaw)",
    )
    start.add_argument(
        "--initial-pose-gt",
        action="store_true",
        help="start at the log's ground-truth pose of the first depth frame (simulated logs)",
    )
    start.add_argument(
        "--global",
        dest="global_",
        action="store_true",
        help="unknown start: particles uniform over the map's free cells",
    )
    parser.add_argument(
        "--particles",
        type=int,
        default=None,
        help="particles per robot (default: max_particles of the params file, 2000)",
    )
    parser.add_argument(
        "--params",
        default=None,
        help="AMCL parameters (YAML; any subset of jaxquad/localize/amcl.yaml; default: that file)",
    )
    parser.add_argument(
        "--contacts",
        choices=("observer", "mixed", "sensor", "truth"),
        default="mixed",
        help="contact source of the leg-inertial odometry (default: mixed)",
    )
    parser.add_argument(
        "--observer-params",
        default=None,
        help="contact-observer parameters of the odometry (as `jaxquad estimate --params`; default: the paper's)",
    )
    parser.add_argument("--band-height", type=int, default=5, help="scan band height in px (default 5; 30 real robot)")
    add_band_reduce_argument(parser)


def run(args: argparse.Namespace) -> int:
    from jaxquad.cli import progress_bar
    from jaxquad.io.jsonfile import to_json
    from jaxquad.localize.run import run_localize

    if args.particles is not None and args.particles < 1:
        raise ValueError(f"--particles must be >= 1, got {args.particles}")
    if args.band_height < 1:
        raise ValueError(f"--band-height must be >= 1, got {args.band_height}")
    initial = "global" if args.global_ else "gt" if args.initial_pose_gt else tuple(args.initial_pose)
    # run_localize checks the output folder, parameters, map and log before its first progress report.
    with progress_bar("localize", "scan") as progress:
        summary = run_localize(
            args.log,
            args.map,
            args.out,
            initial,
            args.params,
            args.particles,
            args.contacts,
            args.band_height,
            progress,
            args.observer_params,
            args.band_reduce,
        )
    print(to_json({"params_file": summary["params_file"], "params": summary["params"]}))
    brief = {"robots": len(summary["robots"]), "out": str(args.out)}
    errs = [r["scores"] for r in summary["robots"] if "scores" in r]
    if errs:
        brief["median_position_error_m"] = float(sorted(e["position_error_median_m"] for e in errs)[len(errs) // 2])
        brief["max_p99_position_error_m"] = max(e["position_error_p99_m"] for e in errs)
    print(to_json(brief))
    return 0
