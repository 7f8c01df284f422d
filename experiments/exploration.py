"""Coverage of autonomous exploration against time, baseline against full, for both robots and worlds.

For each robot, world and variant it runs `jaxquad.explore.explore` with a fleet of `--runs` robots,
each from its own drawn start in the same generated world (seed `--seed`), and reports coverage
(known-free area of each robot's map over the true reachable free area) every `--every` s: the mean,
std, 10th and 90th percentiles over the runs; the final coverage, the share of runs reaching 95 %,
the occupied-cell IoU of the final maps, what the maps call the reachable cells they miss (unknown,
uncertain, occupied; and how many lie on boxes' faces), outcome counts (explored, collided, lost, fallen) and
speed. It prints the rows as JSON (`--json` also writes them) and a Markdown table, and draws
`coverage_vs_time.png` in `--figures` (mean and 10-90 % band per variant; a panel per robot and world).
`--traces DIR` also keeps every run's path and writes `<robot>_<world>_<variant>.npz` per cell (times,
SLAM position error, true and SLAM poses, goals, control modes, outcomes, loop closures, every loop candidate of
every tick with its chi-square and what an accepted one did to the error, the final maps beside the
true map with its reachable and clear cells; `--trace-every S` keeps one sample of the time series every S s,
so that long cells' traces stay small): `experiments/exploration_errors.py`
draws the SLAM's error over time from it. Runs longer than one sitting: with `--checkpoint DIR --wall-budget S`
the script saves the running cell to DIR after S s of wall time and exits with status 75; the same command
again goes on from there (finished cells are kept in DIR as `<cell>.json` and not run again).

    python experiments/exploration.py [--runs 100] [--robots go2 badger] [--worlds house warehouse]
        [--variants baseline full] [--seconds T] [--seed 0] [--samples 256] [--horizon 30]
        [--slam-params FILE] [--map-miss-probability P] [--json rows.json] [--figures DIR] [--traces DIR]
        [--trace-every S] [--checkpoint DIR --wall-budget S]

Without `--seconds` each world runs its target time: 600 s in the house, 900 s in the warehouse.
"""

from __future__ import annotations

import argparse
import json
import platform
import sys
import time
from pathlib import Path

import numpy as np

TARGET_S = {"house": 600.0, "warehouse": 900.0}
GOAL = 0.95  # coverage a run should reach


def _file_gate(slam: dict | None) -> float:
    """The SLAM file's loop_consistency_chi2 (`slam` the --slam-params values, None: slam.yaml's): the baseline's
    gate, and the full variant's before --loop-consistency-chi2."""
    from jaxquad.slam import load_params

    return (slam or load_params())["loop_consistency_chi2"]


def _cell_settings(args, robot: str, world: str, variant: str) -> dict:
    """What a cell's row depends on: a finished row in --checkpoint is reused only for the same settings."""
    from jaxquad.explore.config import leg_bias_sideways
    from jaxquad.slam import load_params

    keep = ("runs", "seconds", "seed", "samples", "horizon", "every", "band_height", "band_reduce")
    keep += ("map_miss_probability", "map_hit_offset_cells", "revisit_after", "footprint_padding", "wall_heading")
    keep += ("map_clear_range", "loop_consistency_chi2", "frontier_gain", "max_speed", "near_obstacle_speed")
    keep += ("outline_padding",)
    slam = load_params(args.slam_params) if args.slam_params else None  # the values: an edited file is another cell
    settings = {"robot": robot, "world": world, "variant": variant, "traces": args.traces, "slam_params": slam}
    settings |= {k: getattr(args, k) for k in keep}
    settings["low_obstacles"] = args.low_obstacles == "on"  # rows kept before "on"/"off" hold a bool
    settings["view_goals"] = args.view_goals == "on"
    settings["leg_bias_sideways"] = leg_bias_sideways(robot, args.leg_bias_sideways)  # the value the robot runs with
    if variant != "full":  # the baseline never takes wall-heading priors, marks low obstacles or seeks views
        settings |= {"wall_heading": "off", "low_obstacles": False, "view_goals": False, "leg_bias_sideways": 0.0}
        settings["loop_consistency_chi2"] = _file_gate(slam)
    return settings


def _finished_row(args, robot: str, world: str, variant: str) -> Path | None:
    """Where a cell's finished row is kept (`--checkpoint DIR`/<cell>.json), None without --checkpoint."""
    return Path(args.checkpoint) / f"{robot}_{world}_{variant}.json" if args.checkpoint else None


def run_cell(args, robot: str, world: str, variant: str, wall_budget_s: float | None = None) -> dict:
    """One cell's row. With `--checkpoint DIR` a finished row is read from DIR/<cell>.json when its settings
    match, and the run is saved to DIR/<cell>.npz (and `checkpoint.Paused` raised) once `wall_budget_s` run out."""
    import jax

    from jaxquad.cli import progress_bar
    from jaxquad.explore import ExploreConfig, explore
    from jaxquad.explore.checkpoint import CheckpointError
    from jaxquad.explore.report import coverage_samples, summarize
    from jaxquad.io.atomic import atomic_write_text
    from jaxquad.io.jsonfile import to_json

    name = f"{robot}_{world}_{variant}"
    settings = _cell_settings(args, robot, world, variant)
    done = _finished_row(args, robot, world, variant)
    if done is not None and done.exists():
        saved = json.loads(done.read_text())
        # rows kept before --slam-params and the options below it had none: the values they ran with
        old = {"slam_params": None, "revisit_after": 0.0, "footprint_padding": 0.1, "low_obstacles": False}
        old |= {"wall_heading": "off", "map_hit_offset_cells": 0.0, "view_goals": False, "map_clear_range": 0.0}
        old |= {"leg_bias_sideways": 0.0, "loop_consistency_chi2": _file_gate(settings["slam_params"])}
        old |= {"frontier_gain": 0.0, "max_speed": 0.26, "near_obstacle_speed": None, "outline_padding": 0.0}
        if old | saved.get("settings", {}) != settings:
            raise CheckpointError(f"{done}: a finished cell of other settings; remove it or choose another folder")
        print(f"{name}: finished earlier ({done})", file=sys.stderr, flush=True)
        return saved["row"]

    seconds = args.seconds or TARGET_S[world]
    cfg = ExploreConfig(
        robot=robot,
        world=world,
        n_robots=args.runs,
        seconds=seconds,
        variant=variant,
        seed=args.seed,
        samples=args.samples,
        horizon=args.horizon,
        band_height=args.band_height,
        band_reduce=args.band_reduce,
        slam_params=args.slam_params,
        map_miss_probability=args.map_miss_probability,
        map_hit_offset_cells=args.map_hit_offset_cells,
        wall_heading=args.wall_heading == "on",
        revisit_after=args.revisit_after,
        footprint_padding=args.footprint_padding,
        outline_padding=args.outline_padding,
        map_clear_range=args.map_clear_range,
        leg_bias_sideways=args.leg_bias_sideways,
        loop_consistency_chi2=args.loop_consistency_chi2,
        low_obstacles=args.low_obstacles == "on",
        view_goals=args.view_goals == "on",
        frontier_gain=args.frontier_gain,
        max_speed=args.max_speed,
        near_obstacle_speed=args.near_obstacle_speed,
        trace_robots=args.runs if args.traces else 4,
        devices=args.devices,
    )
    t0 = time.perf_counter()
    checkpoint = done.with_suffix(".npz") if done is not None else None
    with progress_bar(name, "sim s") as progress:
        result = explore(cfg, checkpoint=checkpoint, wall_budget_s=wall_budget_s, progress=progress)
    print(f"{robot} {world} {variant}: {time.perf_counter() - t0:.0f} s", file=sys.stderr, flush=True)
    if args.traces:
        save_traces(Path(args.traces) / f"{name}.npz", result, args.trace_every)
    summary = summarize(result, args.every)
    times, cov = coverage_samples(result, args.every)
    final = np.asarray(summary["coverage"]["per_robot"])
    row = {
        "robot": robot,
        "world": world,
        "variant": variant,
        "runs": args.runs,
        "seconds": seconds,
        "t_s": times.tolist(),
        "coverage_mean": cov.mean(1).tolist(),
        "coverage_std": cov.std(1).tolist(),
        "coverage_p10": np.percentile(cov, 10, axis=1).tolist(),
        "coverage_p90": np.percentile(cov, 90, axis=1).tolist(),
        "final_coverage": summary["coverage"],
        "share_reaching_95": float(np.mean(final >= GOAL)),
        "final_coverage_clear": summary["coverage_clear"],
        "share_clear_reaching_95": float(np.mean(np.asarray(summary["coverage_clear"]["per_robot"]) >= GOAL)),
        "time_to_95_s_median": _time_to(times, cov, GOAL),
        "map_iou": summary["map_iou"],
        "uncovered": summary["uncovered"],
        "outcomes": summary["outcomes"],
        "distance_m": summary["distance_m"],
        "revisits": summary["revisits"],
        "revisits_closed": summary["revisits_closed"],
        "view_s": summary["view_s"],
        "slam_error_m": summary["slam_error_m"],
        # the SLAM's last estimate of each run's leg-odometry velocity bias (base frame; 0 when not estimated)
        "leg_bias_mps_median": np.median(result.lo_bias, axis=0).tolist(),
        "leg_bias_mps_p10_p90": np.percentile(result.lo_bias, [10, 90], axis=0).tolist(),
        "compile_s": result.compile_s,
        "run_s": result.run_s,
        "chunk_s": summary["timing"]["chunk_s"],
        "devices": args.devices or jax.local_device_count(),
        "robot_seconds_per_s": summary["timing"]["robot_seconds_per_s"],
    }
    if checkpoint is not None:
        atomic_write_text(done, to_json({"settings": settings, "row": row}) + "\n")
        checkpoint.unlink(missing_ok=True)
    return row


# `ExploreResult`'s (ticks, ...) arrays, which --trace-every thins
SERIES = ("t", "error", "active", "coverage", "true_pose", "pose", "goal", "mode", "revisiting", "viewing")


def trace_ticks(t: np.ndarray, every_s: float) -> np.ndarray:
    """Indices of the ticks (end times `t`, evenly spaced) kept at one sample every `every_s` s: every k-th tick, k
    the whole number of ticks nearest `every_s` (at least 1; 0 s keeps every tick), and the last tick."""
    tick = float(t[1] - t[0]) if len(t) > 1 else 0.0
    step = max(1, round(every_s / tick)) if tick > 0 else 1
    idx = np.arange(step - 1, len(t), step)
    return idx if idx.size and idx[-1] == len(t) - 1 else np.append(idx, len(t) - 1).astype(idx.dtype)


def loop_events(result) -> dict:
    """Every loop candidate that passed the SLAM's match tests, at each tick (whatever the traces keep): `loop_t`
    (s), `loop_run`, `loop_chi2` (its consistency chi-square), `loop_accepted`, and the run's SLAM position error
    on the tick before and on the tick itself (`loop_error_before_m`, `loop_error_after_m`): what an accepted
    closure did to the pose."""
    chi2 = np.asarray(result.loop_chi2)
    k, run = np.nonzero(np.isfinite(chi2))
    err = np.asarray(result.error)
    return {
        "loop_t": np.asarray(result.t)[k],
        "loop_run": run.astype(np.int32),
        "loop_chi2": chi2[k, run],
        "loop_accepted": np.asarray(result.loop_closed)[k, run].astype(bool),
        "loop_error_before_m": np.where(k > 0, err[np.maximum(k - 1, 0), run], np.nan),
        "loop_error_after_m": err[k, run],
    }


def save_traces(path: Path, result, every_s: float = 0.0) -> None:
    """Every run's traces of one cell (arrays of `ExploreResult`, the time series at `trace_ticks(t, every_s)`, the
    loop candidates of every tick (`loop_events`), the final maps with the true map, its reachable and clear cells,
    origin and resolution; the cell's settings as 0-d strings and numbers)."""
    from jaxquad.io.atomic import atomic_open

    cfg = result.config
    ticks = trace_ticks(np.asarray(result.t), every_s)
    arrays = {k: np.asarray(getattr(result, k))[ticks] for k in SERIES}
    keep = ("outcome", "end_t", "distance", "nodes", "loops", "revisits", "revisits_closed", "starts", "lo_bias")
    arrays |= {k: np.asarray(getattr(result, k)) for k in keep}
    arrays |= loop_events(result)
    arrays |= {"maps": result.maps, "reachable": result.reachable, "clear": result.clear, "true_map": result.truth.grid}
    arrays |= {"map_origin": np.asarray(result.truth.origin), "map_resolution": result.truth.resolution}
    arrays |= {"robot": cfg.robot, "world": cfg.world}
    arrays |= {"variant": cfg.variant, "seed": cfg.seed, "randomize": cfg.randomize}
    path.parent.mkdir(parents=True, exist_ok=True)
    with atomic_open(path, "wb") as f:
        np.savez_compressed(f, **arrays)


def _time_to(times: np.ndarray, cov: np.ndarray, level: float) -> float | None:
    """Median over the runs of the first sampled time at which coverage reached `level` (None if half never did)."""
    reached = cov >= level
    first = np.where(reached.any(0), times[np.argmax(reached, axis=0)], np.inf)
    med = float(np.median(first))
    return med if np.isfinite(med) else None


def plot(rows: list[dict], folder: Path) -> Path:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from jaxquad.io.atomic import atomic_open

    robots = sorted({r["robot"] for r in rows})
    worlds = sorted({r["world"] for r in rows})
    fig, axes = plt.subplots(len(robots), len(worlds), figsize=(5 * len(worlds), 3.6 * len(robots)), squeeze=False)
    colors = {"baseline": "tab:orange", "full": "tab:blue"}
    for i, robot in enumerate(robots):
        for j, world in enumerate(worlds):
            ax = axes[i, j]
            for r in (r for r in rows if r["robot"] == robot and r["world"] == world):
                t, c = np.asarray(r["t_s"]) / 60.0, colors.get(r["variant"], "k")
                ax.plot(t, 100 * np.asarray(r["coverage_mean"]), color=c, lw=2, label=f"{r['variant']} (mean)")
                ax.fill_between(t, 100 * np.asarray(r["coverage_p10"]), 100 * np.asarray(r["coverage_p90"]),
                                color=c, alpha=0.2, lw=0, label=f"{r['variant']} (10-90 %)")  # fmt: skip
                runs = r["runs"]
            ax.axhline(100 * GOAL, color="k", ls=":", lw=0.8)
            ax.set_title(f"{robot}, {world} ({runs} runs)", fontsize=9)
            ax.set_xlabel("time (min)")
            ax.set_ylabel("coverage (%)")
            ax.set_ylim(0, 100)
            ax.grid(alpha=0.3)
            ax.legend(fontsize=7, loc="lower right")
    fig.tight_layout()
    folder.mkdir(parents=True, exist_ok=True)
    path = folder / "coverage_vs_time.png"
    with atomic_open(path, "wb") as f:
        fig.savefig(f, format="png", dpi=110)
    plt.close(fig)
    return path


def main() -> int:
    from jaxquad.cli import add_band_reduce_argument
    from jaxquad.explore.checkpoint import PAUSED_STATUS, CheckpointError, Paused
    from jaxquad.explore.cli import add_loop_arguments, check_loop_arguments

    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--runs", type=int, default=4, help="robots per cell, each from its own start (default 4)")
    p.add_argument("--robots", nargs="+", default=["go2", "badger"], choices=["go2", "badger"], help="(default both)")
    p.add_argument("--worlds", nargs="+", default=["house", "warehouse"], choices=["house", "warehouse"],
                   help="(default both)")  # fmt: skip
    p.add_argument("--variants", nargs="+", default=["baseline", "full"], choices=["baseline", "full"],
                   help="(default both)")  # fmt: skip
    p.add_argument("--seconds", type=float, default=None, help="simulated time per run, s (default 600 / 900)")
    p.add_argument("--seed", type=int, default=0, help="world and starts (default 0)")
    p.add_argument("--samples", type=int, default=256, help="MPPI samples (default 256)")
    p.add_argument("--horizon", type=int, default=30, help="MPPI horizon in ticks (default 30)")
    p.add_argument("--every", type=float, default=5.0, help="coverage sampling period, s (default 5)")
    p.add_argument("--band-height", type=int, default=1, help="scan band height in px (default 1)")
    add_band_reduce_argument(p)
    p.add_argument(
        "--slam-params", default=None, help="SLAM parameter file overriding jaxquad/slam/slam.yaml (default: none)"
    )
    add_loop_arguments(p)
    p.add_argument(
        "--devices", type=int, default=None, help="split each cell's robots over the first N devices (default all)"
    )
    p.add_argument("--json", default=None, help="write the rows as JSON here (default: stdout only)")
    p.add_argument("--figures", default=None, help="folder for coverage_vs_time.png (default: none)")
    p.add_argument("--traces", default=None, help="folder for every run's traces, an .npz per cell (default: none)")
    p.add_argument(
        "--trace-every",
        type=float,
        default=0.0,
        help="with --traces: one sample of the time series every this many s (default 0: every control tick)",
    )
    p.add_argument("--checkpoint", default=None,
                   help="folder for runs saved when --wall-budget runs out and for finished cells; the same command "
                        "again goes on from them (default: none)")  # fmt: skip
    p.add_argument("--wall-budget", type=float, default=None,
                   help=f"wall-clock seconds after which the running cell is saved to --checkpoint and the script "
                        f"exits with status {PAUSED_STATUS} (default: no limit)")  # fmt: skip
    args = p.parse_args()
    if min(args.runs, args.band_height) < 1 or not (args.seconds is None or args.seconds > 0) or not args.every > 0:
        p.error("--runs and --band-height must be >= 1 and --seconds, --every positive")
    if not args.trace_every >= 0:
        p.error(f"--trace-every must be >= 0 s, got {args.trace_every}")
    try:
        check_loop_arguments(args)
    except ValueError as e:
        p.error(str(e))
    if args.wall_budget is not None and not (args.checkpoint and args.wall_budget > 0):
        p.error("--wall-budget must be positive and needs --checkpoint")
    from jaxquad.io.atomic import atomic_write_text, check_output_dir, check_output_file
    from jaxquad.io.jsonfile import to_json

    try:  # the outputs checked before any work: one-line errors
        if args.json:
            check_output_file(args.json, "--json")
        for flag, folder in (("--figures", args.figures), ("--traces", args.traces), ("--checkpoint", args.checkpoint)):
            if folder:
                check_output_dir(folder, flag, kind=None)
        if args.checkpoint:  # finished rows go there, also from a cell that ends in its first sitting
            Path(args.checkpoint).mkdir(parents=True, exist_ok=True)
        if args.slam_params:
            from jaxquad.slam import load_params

            load_params(args.slam_params)  # a missing or bad file: one line now, not a traceback later
    except (ValueError, OSError) as e:
        p.error(str(e))

    import jax

    print(f"`python {' '.join(sys.argv)}`  ", file=sys.stderr)
    print(f"machine: {platform.node()}, {jax.devices()[0].device_kind}, jax {jax.__version__}", file=sys.stderr)
    t_start, rows, ran = time.perf_counter(), [], False
    try:
        for r in args.robots:
            for w in args.worlds:
                for v in args.variants:
                    left = None if args.wall_budget is None else args.wall_budget - (time.perf_counter() - t_start)
                    row_file = _finished_row(args, r, w, v)
                    finished = row_file is not None and row_file.exists()
                    if left is not None and left <= 0 and ran and not finished:
                        # the budget went to a cell run in this sitting: the next one starts (and compiles) in the next
                        print(f"paused before {r} {w} {v}; the finished cells are kept in {args.checkpoint}: run the "
                              "same command again to go on", file=sys.stderr)  # fmt: skip
                        return PAUSED_STATUS
                    rows.append(run_cell(args, r, w, v, left if left is None or left > 0 else 1e-9))
                    ran = ran or not finished
    except Paused as e:
        print(f"{e}; the finished cells are kept in {args.checkpoint}", file=sys.stderr)
        return PAUSED_STATUS
    except CheckpointError as e:
        p.error(str(e))
    print("| robot | world | variant | runs | s | coverage final mean (min) | runs >= 95 % | median time to 95 % s "
          "| coverage_clear mean | runs clear >= 95 % | IoU | explored | collided | lost | fallen |",
          file=sys.stderr)  # fmt: skip
    print("|---|---|---|---:|---:|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|", file=sys.stderr)
    for r in rows:
        c, o, t95 = r["final_coverage"], r["outcomes"], r["time_to_95_s_median"]
        print(
            f"| {r['robot']} | {r['world']} | {r['variant']} | {r['runs']} | {r['seconds']:.0f} | "
            f"{100 * c['mean']:.1f} % ({100 * c['min']:.1f} %) | {100 * r['share_reaching_95']:.0f} % | "
            f"{'-' if t95 is None else f'{t95:.0f}'} | {100 * r['final_coverage_clear']['mean']:.1f} % | "
            f"{100 * r['share_clear_reaching_95']:.0f} % | {r['map_iou']['mean']:.2f} | {o['explored']} | "
            f"{o['collided']} | {o['lost']} | {o['fallen']} |",
            file=sys.stderr,
        )
    text = to_json(rows)
    print(text)
    if args.json:
        atomic_write_text(args.json, text + "\n")
    if args.figures:
        print(f"figure: {plot(rows, Path(args.figures))}", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
