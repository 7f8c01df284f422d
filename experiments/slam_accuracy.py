"""Online SLAM on simulated fleets: accuracy per leg-odometry constraint kind, and speed.

    python experiments/slam_accuracy.py [--robot go2 --robot badger] [--world house --world warehouse]
        [--robots 2] [--seconds 10] [--style aggressive] [--contacts truth] [--scan-hz 10]
        [--lo-constraints off velocity preintegrated] [--band-height 5] [--band-reduce median]
        [--map-scans every|nodes]
        [--throughput 1 4096] [--devices 1 2] [--params slam.yaml] [--view-range 8] [--pose-split] [--json rows.json]

For each robot and world it simulates a fleet (`jaxquad.sim.rollout`, depth on, `--robots` robots in
up to 4 distinct worlds), runs the estimator once (leg-inertial odometry with `--contacts`, the
stabilized scans at `--scan-hz`, each ray the `--band-reduce` of its `--band-height`-pixel band), then the online
SLAM (`jaxquad.slam`, the parameters of slam.yaml, overridden by `--params`) once per constraint kind on the same
scans; the map scored is drawn from every scan at its final pose (`--map-scans nodes`: the nodes' scans alone).
Printed as Markdown, means +- std over the fleet's robots: ATE (m, SE(3)-aligned, evo's definition)
of the odometry alone, of the online SLAM pose at each scan and of the final (after the last
optimization) trajectory; occupied-cell IoU, precision and recall of the final map against the true
map (`jaxquad.metrics.map_scores`: recall counts every visible wall of the world, also those never in
view; the in-view IoU only the walls an ideal laser on the true path faced, out to `--view-range`, by
default the longest reading the map reads, `jaxquad.slam.map_max_range`, `jaxquad.metrics.cells_in_view`);
loop closures per robot; the SLAM's wall time. A second table scores the graphs' edges at the true node
poses, pooled over the fleet (`jaxquad.slam.report.edge_errors`): per edge kind the rms error (x, y,
heading), the mean chi-square against the edges' information (3 when calibrated) and the edges off by more
than 0.3 m. With --pose-split, a third table: the in-view IoU of the every-scan maps drawn at the final SLAM poses, at
the true positions with the SLAM's headings, at the SLAM's positions with the true headings and at the true poses,
mean over the robots, which tells whether the SLAM's positions or its headings cost the map more. With
--throughput B...: the real-time factor (scan time span / wall time, compile apart) of B robots' online SLAM in one
jitted vmapped run (the fleet's robots repeated), split over each device count of --devices in turn; robot-s per s =
B x span / wall, the robots it keeps in real time.
"""

from __future__ import annotations

import argparse
import platform
import sys
import time

import jax
import numpy as np


def _stats(vals) -> str:
    vals = np.asarray([v for v in vals if v is not None and np.isfinite(v)], float)
    return f"{vals.mean():.3f} +- {vals.std():.3f}" if vals.size else "-"


def _cell(args, robot: str, world: str, rows: list, json_rows: list, edge_rows: list, split_rows: list | None) -> dict:
    from jaxquad.estimate.laser import every_nth_frame, laser_inputs
    from jaxquad.sim.fleet import FleetConfig
    from jaxquad.sim.rollout import rollout
    from jaxquad.slam import final_poses, load_params, map_grid, map_max_range, redraw_maps, run_fleet, slam_config
    from jaxquad.slam.report import robot_report, robot_slice, truth_in_view

    config = FleetConfig(
        robot=robot,
        world=world,
        n_robots=args.robots,
        n_worlds=min(4, args.robots),
        style=args.style,
        seed=args.seed,
        depth=True,
    )
    log = rollout(config, args.seconds, progress=True)
    maps = log.maps()
    values = load_params(args.params)
    x = laser_inputs(
        log,
        "stabilized",
        args.contacts,
        args.band_height,
        0.2,
        map_max_range(values),
        None,
        values["leg_yaw_rate_std"],
        band_reduce=args.band_reduce,
    )
    every = max(1, round(config.camera_hz / args.scan_hz))
    x = every_nth_frame(x, every)
    t = np.asarray(x["t"], np.float64)
    grid = map_grid(x, values["resolution"], map_max_range(values))
    world_index = np.asarray(log["world_index"])
    robot_maps = [maps[world_index[i] % len(maps)] for i in range(args.robots)]
    view_range = map_max_range(values) if args.view_range is None else args.view_range
    in_view = [truth_in_view(x, i, robot_maps[i], view_range) for i in range(args.robots)]
    for lo in args.lo_constraints:
        spec, params = slam_config(values, grid, lo, x["T_base_laser"])
        t0 = time.perf_counter()
        state, out, _ = run_fleet(spec, params, x)
        wall = time.perf_counter() - t0
        final = final_poses(state, out)
        if args.map_scans == "every":
            state = redraw_maps(spec, params, state, out, x)
        reps = [
            robot_report(spec, t, robot_slice(state, i), robot_slice(out, i), final[i], x, i, robot_maps[i], in_view[i])
            for i in range(args.robots)
        ]
        ate = lambda which, reps=reps: [r["scores"][which].get("ate", {}).get("rmse") for r in reps]  # noqa: E731
        ms = lambda key, reps=reps: [r["map_scores"][key] for r in reps]  # noqa: E731
        rows.append(
            f"| {robot} | {world} | {lo} | {_stats(ate('odometry'))} | {_stats(ate('online'))} | "
            f"{_stats(ate('final'))} | {_stats(ms('iou'))} | {_stats(ms('iou_in_view'))} | {_stats(ms('precision'))} | "
            f"{_stats(ms('recall'))} | {np.mean([r['loop_closures'] for r in reps]):.1f} | {wall:.1f} |"
        )
        json_rows.append({"robot": robot, "world": world, "lo_constraints": lo, "wall_s": wall, "robots": reps})
        if split_rows is not None:
            split = _pose_split(spec, params, x, final, robot_maps, in_view)
            split_rows.append(f"| {robot} | {world} | {lo} | " + " | ".join(_stats(v) for v in split.values()) + " |")
            print(split_rows[-1], file=sys.stderr)
        edge_rows += _edge_rows(robot, world, lo, reps)
        print(rows[-1], file=sys.stderr)
    return {"x": x, "grid": grid, "values": values}


POSE_SPLIT = ("SLAM poses", "true positions, SLAM headings", "SLAM positions, true headings", "true poses")


def _pose_split(spec, params, x: dict, final: np.ndarray, true_maps: list, in_view: list) -> dict[str, list[float]]:
    """Per robot, the in-view IoU of the maps drawn from every scan (those the final trajectory has a pose for) at
    each kind of pose of `POSE_SPLIT`: the SLAM's final poses, its positions or headings swapped for the true ones,
    and the true poses."""
    import jax.numpy as jnp

    from jaxquad.kernels.lie import se2, xy_theta
    from jaxquad.metrics import map_scores
    from jaxquad.slam.mapping import fleet_maps, to_occupancy_map
    from jaxquad.slam.report import robot_slice

    true = np.asarray(x["gt"], np.float64)
    final = np.asarray(final, np.float64)
    ok = np.asarray(x["valid"], bool) & np.all(np.isfinite(final), axis=-1)
    ranges = jnp.asarray(np.where(ok[..., None], x["ranges"], np.nan), jnp.float32)
    poses = (
        final,
        np.concatenate([true[..., :2], final[..., 2:]], -1),
        np.concatenate([final[..., :2], true[..., 2:]], -1),
        true,
    )
    T_base_laser = se2(jnp.asarray(x["T_base_laser"], jnp.float32))
    scores = {}
    for name, base in zip(POSE_SPLIT, poses):
        laser = xy_theta(se2(jnp.asarray(np.where(ok[..., None], base, 0.0), jnp.float32)) @ T_base_laser)
        grids = fleet_maps(spec.grid, params.occupancy, laser, ranges, jnp.asarray(x["bearings"]), jnp.asarray(ok))
        scores[name] = [
            map_scores(to_occupancy_map(spec.grid, robot_slice(grids, i)), true_maps[i], in_view[i]).iou_in_view
            for i in range(len(true_maps))
        ]
    return scores


def _edge_rows(robot: str, world: str, lo: str, reps: list[dict]) -> list[str]:
    """Markdown rows of the edge errors pooled over the robots that have them (rms and chi-square weighted by
    edge counts); `robots` says how many (a robot without truth at every node is not scored)."""
    rows = []
    for kind in ("match", "odometry", "leg_odometry", "loop", "wall_heading"):
        per = [r["edge_errors"][kind] for r in reps if (r.get("edge_errors") or {}).get(kind)]
        if not per:
            continue
        n = np.array([p["n"] for p in per], float)
        weighted = lambda key, per=per, n=n: np.sum(n * np.array([p[key] for p in per])) / n.sum()  # noqa: E731
        squares = lambda key, per=per, n=n: np.sum(n * np.array([p[key] for p in per]) ** 2) / n.sum()  # noqa: E731
        rms = [np.sqrt(squares(k)) for k in ("rms_x_m", "rms_y_m", "rms_theta_rad")]
        rows.append(
            f"| {robot} | {world} | {lo} | {kind} | {len(per)} | {int(n.sum())} | "
            f"{100 * rms[0]:.1f} / {100 * rms[1]:.1f} | {np.degrees(rms[2]):.2f} | {weighted('chi2_mean'):.2f} | "
            f"{sum(p['off'] for p in per)} |"
        )
    return rows


def _throughput(cell: dict, batches, devices, rows: list) -> None:
    from jaxquad.slam import run_fleet, slam_config

    x, values = cell["x"], cell["values"]
    spec, params = slam_config(values, cell["grid"], "preintegrated", x["T_base_laser"])
    span = float(x["t"][-1] - x["t"][0])
    for b in batches:
        reps = -(-b // x["odom"].shape[0])
        xb = {
            k: (v if k in ("t", "bearings", "T_base_laser") else np.concatenate([v] * reps)[:b]) for k, v in x.items()
        }
        for d in devices:
            t0 = time.perf_counter()
            run_fleet(spec, params, xb, devices=d)  # compiles
            first = time.perf_counter() - t0
            t0 = time.perf_counter()
            run_fleet(spec, params, xb, devices=d)
            wall = time.perf_counter() - t0
            n_dev = d or jax.device_count()
            rows.append(
                f"| {b} | {n_dev} | {len(x['t'])} | {span:.1f} | {first - wall:.1f} | {wall:.2f} | {span / wall:.2f} | "
                f"{b * span / wall:,.0f} |"
            )
            print(rows[-1], file=sys.stderr)


def main() -> None:
    from jaxquad.cli import add_band_reduce_argument
    from jaxquad.slam.cli import MAP_SCANS

    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--robot", action="append", choices=("go2", "badger"), help="robots (default: go2)")
    p.add_argument("--world", action="append", choices=("house", "warehouse"), help="worlds (default: house)")
    p.add_argument("--robots", type=int, default=2, help="robots per fleet (default 2)")
    p.add_argument("--seconds", type=float, default=10.0, help="simulated time per fleet, s (default 10)")
    p.add_argument(
        "--style", choices=("calm", "aggressive"), default="aggressive", help="gait style (default aggressive)"
    )
    p.add_argument("--seed", type=int, default=0, help="simulation seed (default 0)")
    p.add_argument(
        "--contacts",
        choices=("truth", "mixed", "observer"),
        default="truth",
        help="contact source of the leg odometry (default truth)",
    )
    p.add_argument("--scan-hz", type=float, default=10.0, help="scans per second fed to the SLAM (default 10)")
    p.add_argument("--params", default=None, help="SLAM parameter file over jaxquad/slam/slam.yaml (default: none)")
    p.add_argument(
        "--lo-constraints",
        nargs="+",
        default=["off", "velocity", "preintegrated"],
        choices=("off", "velocity", "preintegrated"),
        help="constraint kinds (default: all three)",
    )
    p.add_argument("--band-height", type=int, default=5, help="scan band height in px (default 5)")
    add_band_reduce_argument(p)
    p.add_argument(
        "--map-scans",
        choices=MAP_SCANS,
        default="every",
        help="the scans that draw the scored map: every scan at its final pose, or the nodes' alone (default every)",
    )
    p.add_argument("--throughput", type=int, nargs="*", default=[], help="robot counts for the speed table")
    p.add_argument(
        "--devices",
        type=int,
        nargs="+",
        default=[None],
        help="device counts the speed table's robots are split over, a row each (default: all devices)",
    )
    p.add_argument(
        "--view-range",
        type=float,
        default=None,
        help="range of the ideal laser that decides the in-view walls, m (default: the longest reading the map "
        "reads, max_laser_range or occupancy_clear_range beyond it)",
    )
    p.add_argument(
        "--pose-split",
        action="store_true",
        help="also score the every-scan maps drawn at the true positions with the SLAM's headings, at the SLAM's "
        "positions with the true headings and at the true poses (in-view IoU)",
    )
    p.add_argument("--json", default=None, help="also write every robot's report to this JSON file")
    args = p.parse_args()
    if args.view_range is not None and not args.view_range > 0:
        p.error(f"--view-range must be positive, got {args.view_range}")
    args.robot, args.world = args.robot or ["go2"], args.world or ["house"]
    if args.band_height < 1:
        p.error(f"--band-height must be >= 1, got {args.band_height}")
    if args.params:
        from jaxquad.slam import load_params

        try:  # a missing or bad file: one line before the simulation, not a traceback after it
            load_params(args.params)
        except (ValueError, OSError) as e:
            p.error(str(e))
    print(f"command: {' '.join(sys.argv)}")
    print(f"machine: {platform.node()}, {jax.devices()[0].device_kind} ({jax.default_backend()})")
    rows = [
        "| robot | world | LO constraints | ATE odometry m | ATE online m | ATE final m | map IoU | IoU in view | "
        "precision | recall | loops/robot | SLAM wall s |",
        "|---|---|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|",
    ]
    edges = [
        "| robot | world | LO constraints | edges | robots | count | rms error x / y cm | rms heading deg | "
        "chi-square mean | off > 0.3 m |",
        "|---|---|---|---|---:|---:|---|---:|---:|---:|",
    ]
    split = [] if args.pose_split else None
    json_rows, cell = [], None
    for robot in args.robot:
        for world in args.world:
            cell = _cell(args, robot, world, rows, json_rows, edges, split)
    print("\n".join(rows))
    print("\n" + "\n".join(edges))
    if split is not None:
        print("\n| robot | world | LO constraints | " + " | ".join(f"IoU in view, {k}" for k in POSE_SPLIT) + " |")
        print("|---|---|---|" + "---:|" * len(POSE_SPLIT))
        print("\n".join(split))
    if args.throughput:
        speed = [
            "| robots | devices | scans | scan span s | compile s | run s | real-time factor | robot-s per s |",
            "|---:|---:|---:|---:|---:|---:|---:|---:|",
        ]
        _throughput(cell, args.throughput, args.devices, speed)
        print("\n" + "\n".join(speed))
    if args.json:
        from jaxquad.io import write_json

        write_json(args.json, json_rows)


if __name__ == "__main__":
    main()
