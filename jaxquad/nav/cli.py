"""`jaxquad navigate`: a fleet of simulated robots, each sent to random reachable goals in turn through the
closed autonomy loop (see jaxquad.nav.fleet); writes summary.json and paths.png.

Output folder:
  summary.json   configuration, AMCL parameters, success rate, outcome counts, time to goal,
                 localization error statistics, timing, one entry per goal (jaxquad.nav.report)
  paths.png      the map with the first robots' true and estimated paths and their goals by outcome
"""

from __future__ import annotations

import argparse

from jaxquad.nav.report import SUMMARY_KIND


def add_arguments(parser: argparse.ArgumentParser) -> None:
    from jaxquad.cli import add_devices_argument
    from jaxquad.nav.fleet import VARIANTS
    from jaxquad.nav.missions import MAP_SOURCES

    parser.add_argument("--robot", default="go2", help="go2, badger, or a path to an MJCF file (default go2)")
    parser.add_argument("--world", default="house", choices=["house", "warehouse"], help="world kind (default house)")
    parser.add_argument("--robots", type=int, default=4, help="robots, each with its own start and goals (default 4)")
    parser.add_argument("--goals", type=int, default=5, help="goals per robot, visited in turn (default 5)")
    parser.add_argument(
        "--variant",
        default="full",
        choices=sorted(VARIANTS),
        help="full: leg-inertial odometry + IMU-stabilized scans; baseline: visual odometry + "
        "fixed-row scans (default full)",
    )
    parser.add_argument(
        "--odometry",
        default=None,
        choices=["leg", "visual"],
        help="override the variant's odometry (leg with --variant baseline: B+LO; default: the variant's)",
    )
    parser.add_argument(
        "--scans",
        default=None,
        choices=["stabilized", "baseline"],
        help="override the variant's scans (stabilized with --variant baseline: B+SS; default: the variant's)",
    )
    parser.add_argument(
        "--map",
        default="truth",
        choices=sorted(MAP_SOURCES),
        help="the map navigated on: truth = the world's true occupancy map; slam = the map the "
        "variant's SLAM builds on a route-following walk first (default truth)",
    )
    parser.add_argument(
        "--map-walk-seconds",
        type=float,
        default=None,
        help="--map slam: length of the mapping walk, s (default: one lap of the route loop)",
    )
    parser.add_argument("--seed", type=int, default=0, help="world, starts, goals, robot variation, noise (default 0)")
    parser.add_argument("--out", required=True, help="output folder (replaced whole when the run succeeds)")
    parser.add_argument(
        "--style",
        default="aggressive",
        choices=["calm", "aggressive"],
        help="gait: aggressive swings the body and stops and goes (default aggressive)",
    )
    parser.add_argument(
        "--particles",
        type=int,
        default=None,
        help="AMCL particles per robot (default: max_particles of the AMCL file, 2000)",
    )
    parser.add_argument(
        "--amcl-params",
        default=None,
        help="AMCL parameters (YAML, any subset of jaxquad/localize/amcl.yaml; default jaxquad/nav/amcl.yaml)",
    )
    parser.add_argument("--samples", type=int, default=1000, help="MPPI samples per control tick (default 1000)")
    parser.add_argument("--horizon", type=int, default=40, help="MPPI horizon in control ticks of 0.096 s (default 40)")
    parser.add_argument("--band-height", type=int, default=1, help="scan band height in px (default 1)")
    parser.add_argument(
        "--chunk-ticks",
        type=int,
        default=100,
        help="control ticks per compiled chunk, a multiple of 10 (default 100 = 9.6 s)",
    )
    parser.add_argument(
        "--max-seconds",
        type=float,
        default=None,
        help="stop after this much simulated time, s (default: when every run has ended)",
    )
    parser.add_argument("--plot-robots", type=int, default=8, help="robots drawn in paths.png (default 8)")
    add_devices_argument(parser, processes=False)


def run(args: argparse.Namespace) -> int:
    from jaxquad.cli import progress_bar
    from jaxquad.io.atomic import atomic_dir, check_output_dir
    from jaxquad.io.jsonfile import to_json, write_json
    from jaxquad.nav.fleet import REPLAN_TICKS, NavConfig, navigate
    from jaxquad.nav.report import plot_paths, summarize

    for option, value in (
        ("--robots", args.robots),
        ("--goals", args.goals),
        ("--samples", args.samples),
        ("--horizon", args.horizon),
        ("--band-height", args.band_height),
        ("--chunk-ticks", args.chunk_ticks),
        ("--plot-robots", args.plot_robots),
        ("--particles", 1 if args.particles is None else args.particles),
    ):
        if value < 1:
            raise ValueError(f"{option} must be >= 1, got {value}")
    if args.chunk_ticks % REPLAN_TICKS:
        raise ValueError(f"--chunk-ticks must be a multiple of {REPLAN_TICKS}, got {args.chunk_ticks}")
    for option, value in (("--max-seconds", args.max_seconds), ("--map-walk-seconds", args.map_walk_seconds)):
        if value is not None and not value > 0:
            raise ValueError(f"{option} must be positive, got {value}")
    check_output_dir(args.out, kind=SUMMARY_KIND)
    cfg = NavConfig(
        robot=args.robot,
        world=args.world,
        n_robots=args.robots,
        n_goals=args.goals,
        variant=args.variant,
        map=args.map,
        style=args.style,
        seed=args.seed,
        particles=args.particles,
        amcl_params=args.amcl_params,
        samples=args.samples,
        horizon=args.horizon,
        band_height=args.band_height,
        chunk_ticks=args.chunk_ticks,
        odometry=args.odometry,
        scans=args.scans,
        max_seconds=args.max_seconds,
        map_walk_seconds=args.map_walk_seconds,
        trace_robots=max(args.plot_robots, 1),
        devices=args.devices,
    )
    with progress_bar("navigate", "goal") as progress:
        result = navigate(cfg, progress=progress)
    summary = summarize(result)
    with atomic_dir(args.out) as tmp:
        write_json(tmp / "summary.json", summary)
        plot_paths(result, tmp / "paths.png", args.plot_robots)
    brief = {k: summary[k] for k in ("robots", "goals", "success_rate", "outcomes")}
    brief["localization_error_median_m"] = summary["localization_error_m"]["median"]
    brief["real_time_factor"] = summary["timing"]["real_time_factor"]
    brief["out"] = str(args.out)
    print(to_json(brief))
    return 0
