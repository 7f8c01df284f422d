"""`jaxquad slam INPUT --out DIR`: online 2D graph SLAM with leg-odometry constraints over a robot log
(the estimator's scans and odometry) or a 2D laser log (CARMEN text or the `.npz` laser-log form).

A fleet log writes one folder per robot (DIR/robot_000, ...); a single robot or laser log writes into
DIR. Every folder holds trajectory.tum, trajectory_final.tum, map.pgm + map.yaml and graph.g2o
(`jaxquad.slam.report`); DIR/summary.json holds the parameters used and per robot the node, edge and
loop-closure counts and, with ground truth, the trajectory and map scores.
"""

from __future__ import annotations

import argparse
import re
from pathlib import Path

import numpy as np

SUMMARY_KIND = "jaxquad slam"
FORMATS = ("auto", "robot", "carmen", "laser-npz")
MAP_SCANS = ("every", "nodes")  # the scans that draw the written map (`jaxquad.slam.redraw_maps`, or the nodes')


def add_arguments(parser: argparse.ArgumentParser) -> None:
    from jaxquad.cli import add_band_reduce_argument, add_devices_argument

    parser.add_argument("input", help="robot log (.npz), CARMEN log (text, .gz too) or laser log (.npz)")
    parser.add_argument("--out", required=True, help="output folder (created; an earlier SLAM output is replaced)")
    parser.add_argument(
        "--format", choices=FORMATS, default="auto", help="input kind (default auto: found from the file's content)"
    )
    parser.add_argument(
        "--variant",
        choices=("B", "B+LO", "B+SS", "full", "full+level"),
        default=None,
        help="robot logs: the paper's ablation variant, setting --scans, --odometry, "
        "--vo-leg-odometry and --lo-constraints together (see jaxquad.slam.variants; default: none, "
        "those options as given)",
    )
    parser.add_argument(
        "--scans",
        choices=("stabilized", "baseline", "level"),
        default=None,
        help="robot logs: which 2D scan of the depth images (default stabilized)",
    )
    parser.add_argument(
        "--odometry",
        choices=("lo", "vo"),
        default=None,
        help="robot logs: odometry of the scans, lo (the leg-inertial odometry) or vo (depth odometry; default lo)",
    )
    parser.add_argument(
        "--vo-leg-odometry",
        choices=("off", "guess", "guess+restart"),
        default=None,
        help="with --odometry vo: how the leg odometry guides it (default guess+restart)",
    )
    parser.add_argument(
        "--lo-constraints",
        choices=("off", "velocity", "preintegrated"),
        default=None,
        help="leg-odometry edges between consecutive nodes (default preintegrated; laser logs: off)",
    )
    parser.add_argument(
        "--params",
        default=None,
        help="SLAM parameters (YAML; any subset of jaxquad/slam/slam.yaml) over the defaults: slam.yaml "
        "for robot logs, slam.yaml with jaxquad/slam/laser.yaml's overrides for 2D laser logs",
    )
    parser.add_argument(
        "--contacts",
        choices=("observer", "mixed", "sensor", "truth"),
        default="mixed",
        help="robot logs: contact source of the leg odometry (default mixed)",
    )
    parser.add_argument(
        "--observer-params",
        default=None,
        help="robot logs: contact-observer parameters (as `jaxquad estimate --params`; default: the paper's)",
    )
    parser.add_argument("--band-height", type=int, default=5, help="robot logs: scan band height in px (default 5)")
    add_band_reduce_argument(parser, None, "median; min with --variant", "robot logs: ")
    parser.add_argument(
        "--map-scans",
        choices=MAP_SCANS,
        default=None,
        help="the scans that draw the written map: every scan at its pose after the last optimization, or the "
        "nodes' scans alone (slam_toolbox's map, and the online map) (default every; nodes with --variant)",
    )
    parser.add_argument(
        "--true-map",
        nargs="+",
        default=None,
        help="ground-truth map YAML(s) for map scores, robot i on map world_index[i] (default: the "
        "map_<world>_<k>.yaml files beside a simulated log, if any)",
    )
    parser.add_argument(
        "--flaser-fov-deg",
        type=float,
        default=180.0,
        help="CARMEN FLASER lines: field of view of the beams (deg, default 180)",
    )
    add_devices_argument(parser, "robots (the leg-odometry estimator's and the SLAM's)")


def detect_format(path: Path) -> str:
    """robot / laser-npz from an .npz's keys, else carmen (text)."""
    import zipfile

    with open(path, "rb") as f:
        head = f.read(4)
    if not head:
        raise ValueError(f"input {path}: the file is empty")
    if head != b"PK\x03\x04":
        return "carmen"
    try:
        with np.load(path, allow_pickle=False) as z:
            keys = set(z.files)
    except (OSError, EOFError, zipfile.BadZipFile, ValueError) as e:
        raise ValueError(f"input {path}: not a readable .npz ({type(e).__name__}: {e})") from None
    if {"scan_t", "ranges", "bearings"} <= keys:
        return "laser-npz"
    return "robot"


def resolve_variant(args) -> None:
    """Fill --scans, --odometry, --vo-leg-odometry and --lo-constraints from --variant (which may not be
    combined with them) or from their defaults; --band-reduce and --map-scans, when not given, are the paper's
    min and nodes with a variant, median and every without."""
    from jaxquad.slam.variants import VARIANTS

    keys = ("scans", "odometry", "vo_leg_odometry", "lo_constraints")
    if args.variant is not None:
        given = [f"--{k.replace('_', '-')}" for k in keys if getattr(args, k) is not None]
        if given:
            raise ValueError(f"--variant sets {', '.join(given)} itself; give one or the other")
        v = VARIANTS[args.variant]
        args.scans, args.odometry, args.vo_leg_odometry, args.lo_constraints = (
            v.scans,
            v.odometry,
            v.vo_coupling,
            v.lo_constraints,
        )
        if args.band_reduce is None:
            args.band_reduce = "min"  # the paper's scans
        if args.map_scans is None:
            args.map_scans = "nodes"  # the paper's map (slam_toolbox draws its nodes' scans)
        return
    if args.band_reduce is None:
        args.band_reduce = "median"
    if args.map_scans is None:
        args.map_scans = "every"
    for key, default in zip(keys, ("stabilized", "lo", "guess+restart", "preintegrated"), strict=True):
        if getattr(args, key) is None:
            setattr(args, key, default)
    if args.vo_leg_odometry != "guess+restart" and args.odometry != "vo":
        raise ValueError("--vo-leg-odometry needs --odometry vo")


def _true_maps(args, log_path: Path):
    from jaxquad.io import load_map

    paths = args.true_map
    if paths is None:
        found = [(p, re.fullmatch(r"map_.+_(\d+)\.yaml", p.name)) for p in log_path.parent.glob("map_*_*.yaml")]
        paths = [p for p, m in sorted(((p, m) for p, m in found if m), key=lambda pm: int(pm[1].group(1)))]
    return [load_map(p) for p in paths]


def _load(args, path: Path, fmt: str, values: dict, progress=None):
    """(inputs dict, robot names, true maps per robot or None, lo_constraints used); every input is
    read and checked before the estimator runs (which reports `progress(0, frames)` as it starts)."""
    from jaxquad.io.carmen import load_laser_log, read_carmen

    if fmt in ("carmen", "laser-npz"):
        from jaxquad.slam.run import laser_log_inputs

        if args.variant is not None or args.odometry == "vo":
            raise ValueError(f"--variant and --odometry vo need a robot log with depth images, not a {fmt} log")
        log = read_carmen(path, args.flaser_fov_deg) if fmt == "carmen" else load_laser_log(path)
        return laser_log_inputs(log), ["robot"], None, "off"
    from jaxquad.estimate.laser import laser_inputs
    from jaxquad.io import load_log
    from jaxquad.slam.params import map_max_range

    log = load_log(path)
    maps = _true_maps(args, path)
    x = laser_inputs(
        log,
        args.scans,
        args.contacts,
        args.band_height,
        0.2,
        map_max_range(values),
        args.observer_params,
        values["leg_yaw_rate_std"],
        progress,
        args.odometry,
        args.vo_leg_odometry,
        args.devices,
        args.band_reduce,
    )
    n = x["odom"].shape[0]
    fleet = "fallen" in log
    names = [f"robot_{i:03d}" for i in range(n)] if fleet else ["robot"]
    per_robot = None
    if maps:
        world = np.asarray(log["world_index"]) if "world_index" in log else np.zeros(n, int)
        per_robot = [maps[int(w) % len(maps)] for w in world]
    return x, names, per_robot, args.lo_constraints


def run(args: argparse.Namespace) -> int:
    from jaxquad import parallel
    from jaxquad.cli import progress_bar
    from jaxquad.io import atomic_dir, check_output_dir, to_json, write_json
    from jaxquad.io.carmen import in_time_order
    from jaxquad.slam import report
    from jaxquad.slam.params import DEFAULTS_FILE, LASER_FILE, load_params, map_max_range, slam_config
    from jaxquad.slam.run import final_poses, map_grid, nodes_needed, redraw_maps, run_fleet

    path = Path(args.input)
    if not path.is_file():
        raise FileNotFoundError(f"input not found: {path}")
    if args.band_height < 1:
        raise ValueError(f"--band-height must be >= 1, got {args.band_height}")
    resolve_variant(args)
    check_output_dir(args.out, kind=SUMMARY_KIND)
    fmt = detect_format(path) if args.format == "auto" else args.format
    laser = fmt in ("carmen", "laser-npz")
    values = load_params(args.params, laser=laser)
    # The bar appears once the inputs are checked: the estimator's start, or the first SLAM chunk.
    with progress_bar("slam", "scan") as progress:
        x, names, true_maps, lo_constraints = _load(args, path, fmt, values, progress)
        grid = map_grid(x, values["resolution"], map_max_range(values))
        spec, params = slam_config(values, grid, lo_constraints, x["T_base_laser"])
        # Enough node slots for every node the scans add (a long log needs more than the default).
        needed = nodes_needed(params, x)
        if needed > spec.nodes:
            values["node_capacity"] = -(-needed // 256) * 256
            spec, params = slam_config(values, grid, lo_constraints, x["T_base_laser"])
        state, out, _ = run_fleet(spec, params, x, progress, args.devices)
    if not parallel.is_main():  # every process ran the same SLAM and holds every robot's results
        return 0
    final = final_poses(state, out)
    if args.map_scans == "every":
        state = redraw_maps(spec, params, state, out, x)
    t = np.asarray(x["t"], np.float64)
    stamp = np.asarray(x.get("stamp", t), np.float64)  # each scan's own time, for the files
    summary = {
        "kind": SUMMARY_KIND,
        "input": str(path),
        "format": fmt,
        "scans": args.scans if fmt == "robot" else "laser",
        "band_reduce": args.band_reduce if fmt == "robot" else None,
        "variant": args.variant,
        "odometry": args.odometry if fmt == "robot" else "log",
        "vo_leg_odometry": args.vo_leg_odometry if fmt == "robot" and args.odometry == "vo" else None,
        "lo_constraints": lo_constraints,
        "map_scans": args.map_scans,
        "params_defaults": [str(DEFAULTS_FILE)] + ([str(LASER_FILE)] if laser else []),  # in order
        "params_file": None if args.params is None else str(args.params),
        "params": values,
        # Scans whose stamp is out of time order (they keep it in the files; jaxquad.io.carmen).
        "scans_out_of_time_order": int((~in_time_order(stamp)).sum()),
        # Scans stamped as the scan before (a log written with few digits); spread in the files (jaxquad.io.carmen).
        "scans_with_repeated_stamps": int(x.get("stamps_repeated", 0)),
        "grid": {k: getattr(grid, k) for k in ("rows", "cols", "resolution", "origin_x", "origin_y", "max_range")},
        "robots": [],
    }
    with atomic_dir(args.out) as tmp:
        for i, name in enumerate(names):
            folder = tmp if len(names) == 1 else tmp / name
            folder.mkdir(exist_ok=True)
            s_i, o_i = (report.robot_slice(a, i) for a in (state, out))
            report.write_robot(folder, grid, stamp, s_i, o_i, final[i])
            true_map = None if true_maps is None else true_maps[i]
            # in view: the walls within the grid's rays, the longest reading the map reads (map_max_range)
            rep = report.robot_report(spec, t, s_i, o_i, final[i], x, i, true_map)
            summary["robots"].append({"name": name, **rep})
            if true_maps is not None:
                gt = x["gt"][i] if "gt" in x else None
                report.draw_map_vs_truth(
                    folder / "map_vs_truth.png", grid, s_i, final[i], x["odom"][i], gt, true_maps[i]
                )
        write_json(tmp / "summary.json", summary)
    print(to_json(_brief(summary, args.out)))
    return 0


def _brief(summary: dict, out) -> dict:
    robots = summary["robots"]
    brief = {
        "robots": len(robots),
        "out": str(out),
        "lo_constraints": summary["lo_constraints"],
        "nodes": [r["nodes"] for r in robots],
        "loop_closures": [r["loop_closures"] for r in robots],
    }
    for key in ("scans_out_of_time_order", "scans_with_repeated_stamps"):  # a laser log's stamps, read as said
        if summary[key]:
            brief[key] = summary[key]
    for which in ("odometry", "online", "final"):
        ate = [r["scores"][which]["ate"]["rmse"] for r in robots if "ate" in r.get("scores", {}).get(which, {})]
        if ate:
            brief[f"ate_{which}_m_mean"] = float(np.mean(ate))
    iou = [r["map_scores"]["iou"] for r in robots if "map_scores" in r]
    if iou:
        brief["map_iou_mean"] = float(np.mean(iou))
    return brief
