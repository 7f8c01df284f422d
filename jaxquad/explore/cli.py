"""`jaxquad explore`: a fleet of simulated robots, each exploring the same unknown world from its own start
with online SLAM, frontier goals, the planner and MPPI (see jaxquad.explore.fleet); writes summary.json
and pictures.

Output folder:
  summary.json   configuration, coverage (per robot, mean, over time), map scores against the true map,
                 outcomes and flags, distance walked, SLAM error, timing (jaxquad.explore.report)
  maps.png       the first robots' final SLAM maps with their true and SLAM paths
  coverage.png   coverage against time, every robot and the mean

A run longer than one sitting: `--checkpoint run.npz --wall-budget 500` saves the run after 500 s of wall
time and exits with status 75; the same command again goes on from the file (jaxquad.explore.checkpoint).
"""

from __future__ import annotations

import argparse

from jaxquad.explore.checkpoint import PAUSED_STATUS
from jaxquad.explore.report import SUMMARY_KIND


def add_loop_arguments(parser: argparse.ArgumentParser) -> None:
    """The loop's options that `jaxquad explore` and `experiments/exploration.py` share (`ExploreConfig`'s fields,
    whose defaults they show); `check_loop_arguments` checks them."""
    from jaxquad.explore.config import ExploreConfig

    c = ExploreConfig
    parser.add_argument(
        "--map-miss-probability",
        type=float,
        default=c.map_miss_probability,
        help="the map's occupancy of a cell a ray crosses, in place of the SLAM file's "
        f"(default {c.map_miss_probability})",
    )
    parser.add_argument(
        "--map-hit-offset-cells",
        type=float,
        default=c.map_hit_offset_cells,
        help="a return marks the map cell this many cells beyond it along the ray, 0-1, in place of the SLAM "
        f"file's (default {c.map_hit_offset_cells:g}: also a face met obliquely leaves the cell in front of it free)",
    )
    parser.add_argument(
        "--wall-heading",
        choices=("on", "off"),
        default="on" if c.wall_heading else "off",
        help="the full variant's SLAM corrects its heading by the walls' directions against the map's, in place of "
        f"the SLAM file's wall_heading (default {'on' if c.wall_heading else 'off'}; the baseline variant: never)",
    )
    parser.add_argument(
        "--max-speed",
        type=float,
        default=c.max_speed,
        help=f"the controller's forward speed limit, m/s (default {c.max_speed:g}: the paper's DWB limit)",
    )
    parser.add_argument(
        "--near-obstacle-speed",
        type=float,
        default=None,
        help="the forward speed limit while the robot stands within the costmap's inflation radius (0.7 m) of a "
        "known obstacle or on an unknown cell, m/s (default: --max-speed everywhere)",
    )
    parser.add_argument(
        "--frontier-gain",
        type=float,
        default=c.frontier_gain,
        help="a frontier cluster's cost is its path cost (m) minus this times its size (m): 0 picks the nearest "
        f"frontier (the paper's explore_lite settings), explore_lite's own defaults are 1/3 (default "
        f"{c.frontier_gain:g})",
    )
    parser.add_argument(
        "--revisit-after",
        type=float,
        default=c.revisit_after,
        help="s without a loop closure before the robot goes back to a place it mapped a minute or more ago to "
        f"close one (active loop closing); 0: never (default {c.revisit_after:g})",
    )
    parser.add_argument(
        "--low-obstacles",
        choices=("on", "off"),
        nargs="?",
        const="on",
        default="on" if c.low_obstacles else "off",
        help="the full variant keeps the robot off obstacles lower than the camera's scan plane, seen in the depth "
        "image's points below it; off: the costmap is the SLAM map's alone (default "
        f"{'on' if c.low_obstacles else 'off'}; the baseline variant: never)",
    )
    parser.add_argument(
        "--view-goals",
        choices=("on", "off"),
        default="on" if c.view_goals else "off",
        help="once no reachable frontier is left, walk to where a frontier out of reach (a slot too narrow to "
        "enter, one too short to count) lies in plain view and look at it, before exploration counts as finished "
        f"(default {'on' if c.view_goals else 'off'}; the baseline variant: never)",
    )
    parser.add_argument(
        "--map-clear-range",
        type=float,
        default=c.map_clear_range,
        help="readings from --map-range up to this mark no wall but clear the map along their ray, short of the "
        "reading by three std of the depth noise, m, at most the camera's 8 m, in place of the SLAM file's "
        f"occupancy_clear_range; 0 or at most --map-range: off (default {c.map_clear_range:g})",
    )
    parser.add_argument(
        "--leg-bias-sideways",
        type=float,
        default=None,
        help="prior std of the leg odometry's sideways velocity bias, which the SLAM estimates from its scan matches "
        "and takes out of its leg edges, m/s, in place of the SLAM file's leg_bias_std_sideways; 0: not estimated "
        "(default: the robot's, 0.01 for the Badger, whose leg odometry drifts sideways, 0 for the Go2)",
    )
    parser.add_argument(
        "--loop-consistency-chi2",
        type=float,
        default=c.loop_consistency_chi2,
        help="the full variant's SLAM refuses a loop closure whose chi-square against the graph (3 dof) exceeds this, "
        f"in place of the SLAM file's loop_consistency_chi2 (default {c.loop_consistency_chi2:g}, the 95 %% point; "
        "the baseline variant: the file's)",
    )
    parser.add_argument(
        "--footprint-padding",
        type=float,
        default=c.footprint_padding,
        help=f"margin added to the footprint's covering disks in the costmap, against the SLAM pose's error, m "
        f"(default {c.footprint_padding:g})",
    )
    parser.add_argument(
        "--outline-padding",
        type=float,
        default=c.outline_padding,
        help="margin by which the controller keeps the footprint's outline off lethal and unknown cells, m (unknown "
        f"cells are not inflated; default {c.outline_padding:g}: the outline itself)",
    )


def check_loop_arguments(args: argparse.Namespace) -> None:
    """A one-line ValueError for a value of `add_loop_arguments`' options out of its range."""
    import math

    for option, value in (("--max-speed", args.max_speed), ("--near-obstacle-speed", args.near_obstacle_speed)):
        if value is not None and not (math.isfinite(value) and value > 0):
            raise ValueError(f"{option} must be a finite number > 0, got {value}")
    if not 0.0 < args.map_miss_probability < 0.5:
        raise ValueError(f"--map-miss-probability must lie in (0, 0.5), got {args.map_miss_probability}")
    if not 0.0 <= args.map_hit_offset_cells <= 1.0:
        raise ValueError(f"--map-hit-offset-cells must lie in [0, 1], got {args.map_hit_offset_cells}")
    if not (math.isfinite(args.loop_consistency_chi2) and args.loop_consistency_chi2 > 0):
        raise ValueError(f"--loop-consistency-chi2 must be a finite number > 0, got {args.loop_consistency_chi2}")
    for option, value in (
        ("--frontier-gain", args.frontier_gain),
        ("--revisit-after", args.revisit_after),
        ("--footprint-padding", args.footprint_padding),
        ("--outline-padding", args.outline_padding),
        ("--map-clear-range", args.map_clear_range),
        ("--leg-bias-sideways", args.leg_bias_sideways),  # None: the robot's default
    ):
        if value is not None and not (math.isfinite(value) and value >= 0):
            raise ValueError(f"{option} must be a finite number >= 0, got {value}")


def add_arguments(parser: argparse.ArgumentParser) -> None:
    from jaxquad.cli import add_band_reduce_argument, add_devices_argument
    from jaxquad.explore.config import VARIANTS

    parser.add_argument("--robot", default="go2", choices=["go2", "badger"], help="robot model (default go2)")
    parser.add_argument("--world", default="house", choices=["house", "warehouse"], help="world kind (default house)")
    parser.add_argument("--robots", type=int, default=2, help="robots, each from its own start (default 2)")
    parser.add_argument("--seconds", type=float, default=60.0, help="simulated time of the run, s (default 60)")
    parser.add_argument(
        "--variant",
        default="full",
        choices=sorted(VARIANTS),
        help="full: leg-inertial odometry + IMU-stabilized scans + leg-odometry SLAM edges; baseline: visual "
        "odometry + fixed-row scans + scan matching alone (default full)",
    )
    parser.add_argument("--seed", type=int, default=0, help="world, starts, robot variation, noise (default 0)")
    parser.add_argument("--out", required=True, help="output folder (replaced whole when the run succeeds)")
    parser.add_argument(
        "--style",
        default="aggressive",
        choices=["calm", "aggressive"],
        help="gait: aggressive swings the body and stops and goes (default aggressive)",
    )
    parser.add_argument("--samples", type=int, default=256, help="MPPI samples per control tick (default 256)")
    parser.add_argument("--horizon", type=int, default=30, help="MPPI horizon in control ticks of 0.096 s (default 30)")
    parser.add_argument(
        "--slam-params", default=None, help="SLAM parameters (YAML, any subset of jaxquad/slam/slam.yaml; default none)"
    )
    parser.add_argument(
        "--map-range", type=float, default=4.0, help="readings beyond this are no-returns for the map, m (default 4)"
    )
    add_loop_arguments(parser)
    parser.add_argument("--band-height", type=int, default=1, help="scan band height in px (default 1)")
    add_band_reduce_argument(parser)
    parser.add_argument(
        "--chunk-ticks",
        type=int,
        default=50,
        help="control ticks per compiled chunk, a multiple of 10 (default 50 = 4.8 s)",
    )
    parser.add_argument(
        "--every", type=float, default=5.0, help="coverage sampling period in summary.json, s (default 5)"
    )
    parser.add_argument("--plot-robots", type=int, default=4, help="robots drawn in maps.png (default 4)")
    parser.add_argument(
        "--checkpoint",
        default=None,
        help="file (.npz) the run is saved to when --wall-budget runs out; a run whose file exists goes on from it "
        "(same settings); removed once the outputs are written (default: none)",
    )
    parser.add_argument(
        "--wall-budget",
        type=float,
        default=None,
        help="wall-clock seconds after which the run is saved to --checkpoint at the end of a chunk and the "
        f"command exits with status {PAUSED_STATUS}; run it again to go on (default: no limit)",
    )
    add_devices_argument(parser, processes=False)


def run(args: argparse.Namespace) -> int:
    import math
    import sys
    from pathlib import Path

    from jaxquad.cli import progress_bar
    from jaxquad.explore.checkpoint import Paused
    from jaxquad.explore.config import ExploreConfig
    from jaxquad.explore.fleet import REPLAN_TICKS, explore
    from jaxquad.explore.report import plot_coverage, plot_maps, summarize
    from jaxquad.io.atomic import atomic_dir, check_output_dir, check_output_file
    from jaxquad.io.jsonfile import to_json, write_json

    for option, value in (
        ("--robots", args.robots),
        ("--samples", args.samples),
        ("--horizon", args.horizon),
        ("--chunk-ticks", args.chunk_ticks),
        ("--plot-robots", args.plot_robots),
        ("--band-height", args.band_height),
    ):
        if value < 1:
            raise ValueError(f"{option} must be >= 1, got {value}")
    if args.chunk_ticks % REPLAN_TICKS:
        raise ValueError(f"--chunk-ticks must be a multiple of {REPLAN_TICKS}, got {args.chunk_ticks}")
    for option, value in (("--seconds", args.seconds), ("--every", args.every), ("--map-range", args.map_range)):
        if not (math.isfinite(value) and value > 0):
            raise ValueError(f"{option} must be a positive number, got {value}")
    check_loop_arguments(args)
    if args.wall_budget is not None:
        if args.checkpoint is None:
            raise ValueError("--wall-budget needs --checkpoint, the file the run is saved to")
        if not (math.isfinite(args.wall_budget) and args.wall_budget > 0):
            raise ValueError(f"--wall-budget must be a positive number of seconds, got {args.wall_budget}")
    check_output_dir(args.out, kind=SUMMARY_KIND)
    if args.checkpoint is not None:
        check_output_file(args.checkpoint, "--checkpoint")
    cfg = ExploreConfig(
        robot=args.robot,
        world=args.world,
        n_robots=args.robots,
        seconds=args.seconds,
        variant=args.variant,
        seed=args.seed,
        style=args.style,
        samples=args.samples,
        horizon=args.horizon,
        chunk_ticks=args.chunk_ticks,
        slam_params=args.slam_params,
        map_range=args.map_range,
        map_miss_probability=args.map_miss_probability,
        map_hit_offset_cells=args.map_hit_offset_cells,
        wall_heading=args.wall_heading == "on",
        revisit_after=args.revisit_after,
        low_obstacles=args.low_obstacles == "on",
        view_goals=args.view_goals == "on",
        frontier_gain=args.frontier_gain,
        max_speed=args.max_speed,
        near_obstacle_speed=args.near_obstacle_speed,
        footprint_padding=args.footprint_padding,
        outline_padding=args.outline_padding,
        map_clear_range=args.map_clear_range,
        leg_bias_sideways=args.leg_bias_sideways,
        loop_consistency_chi2=args.loop_consistency_chi2,
        band_height=args.band_height,
        band_reduce=args.band_reduce,
        trace_robots=max(args.plot_robots, 1),
        devices=args.devices,
    )
    try:
        with progress_bar("explore", "sim s") as progress:
            result = explore(cfg, progress=progress, checkpoint=args.checkpoint, wall_budget_s=args.wall_budget)
    except Paused as e:
        print(f"jaxquad explore: {e}", file=sys.stderr)
        return PAUSED_STATUS
    summary = summarize(result, args.every)
    with atomic_dir(args.out) as tmp:
        write_json(tmp / "summary.json", summary)
        plot_maps(result, tmp / "maps.png", args.plot_robots)
        plot_coverage(result, tmp / "coverage.png", args.every)
    if args.checkpoint is not None:
        Path(args.checkpoint).unlink(missing_ok=True)  # the run is done and its outputs are written
    brief = {"robots": summary["robots"], "coverage_mean": summary["coverage"]["mean"]}
    brief["coverage_per_robot"] = summary["coverage"]["per_robot"]
    brief["map_iou_mean"] = summary["map_iou"]["mean"]
    brief["outcomes"] = summary["outcomes"]
    brief["real_time_factor"] = summary["timing"]["real_time_factor"]
    brief["out"] = str(args.out)
    print(to_json(brief))
    return 0
