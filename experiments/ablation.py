"""The paper's Table I (its ablation) with many runs per cell: B, B+LO, B+SS, full (and full+level)
on each robot in each world, on the same simulated logs.

    python experiments/ablation.py --runs 100 --robots go2 badger --worlds house warehouse --seconds 60
        [--variants B B+LO B+SS full full+level] [--contacts mixed] [--style aggressive] [--seed 0]
        [--scan-hz 10] [--json table.json] [--figures DIR]
    python experiments/ablation.py --merge go2_house.json go2_warehouse.json ... [--json table.json]

Per robot x world cell: one fleet of `--runs` robots, each in its own generated world with its own
seed (`jaxquad.sim.rollout`, depth on), is simulated once; the estimator runs once (leg-inertial
odometry and attitude, `--contacts`); the depth odometry runs once per leg-odometry coupling the
variants need and the scans are sliced once per scan kind; then the online SLAM (`jaxquad.slam`,
slam.yaml's parameters, scans at `--scan-hz`) runs once per variant (`jaxquad.slam.variants` says
what each switches) on the same logs. Robots that fell are left out of every variant and counted.

Scores per run are those of the final SLAM trajectory against ground truth at the scans (evo's
definitions, SE(3)-aligned, RMSE): ATE (m), ARE (deg), APE (m) and RPE at 2/5/10 m (m; a length is
scored where the walk is over twice as long). Printed as Markdown: mean +- std over the runs with the
95 % confidence interval of the mean (Student t), and for each variant the paired tests of `full`
against it on the runs both scored (paired t-test and Wilcoxon signed-rank, two-sided). --json saves
every run's scores and the statistics; --figures writes per cell the maps of run 0 with and without
stabilization (B+LO and full, beside the true map) and run 0's trajectories.

--merge prints the one table of cells run separately (one cell per job where a job's time is limited);
their variants must agree, and the wall time printed is the sum of theirs.
"""

from __future__ import annotations

import argparse
import platform
import sys
import time
from pathlib import Path

import jax
import numpy as np

METRICS = ("ate", "are_deg", "ape", "rpe_2m", "rpe_5m", "rpe_10m")


def _score(rep: dict, metric: str) -> float:
    entry = rep.get("scores", {}).get("final", {}).get(metric)
    return float(entry["rmse"]) if isinstance(entry, dict) and entry.get("rmse") is not None else float("nan")


def statistics(values: np.ndarray) -> dict:
    """mean, std (n - 1), n and the 95 % confidence interval of the mean of the finite `values`."""
    from scipy import stats

    v = values[np.isfinite(values)]
    n = int(v.size)
    if n == 0:
        return {"n": 0, "mean": None, "std": None, "ci95": None}
    std = float(v.std(ddof=1)) if n > 1 else float("nan")
    half = float(stats.t.ppf(0.975, n - 1) * std / np.sqrt(n)) if n > 1 else float("nan")
    return {"n": n, "mean": float(v.mean()), "std": std, "ci95": [float(v.mean() - half), float(v.mean() + half)]}


def paired_tests(a: np.ndarray, b: np.ndarray) -> dict:
    """Two-sided paired t-test and Wilcoxon signed-rank test of a against b on the runs both scored;
    `mean_difference` is mean(a - b)."""
    from scipy import stats

    ok = np.isfinite(a) & np.isfinite(b)
    d = a[ok] - b[ok]
    out = {
        "n": int(ok.sum()),
        "mean_difference": float(d.mean()) if d.size else None,
        "t_test_p": None,
        "wilcoxon_p": None,
    }
    if d.size >= 2 and np.any(d != 0):
        out["t_test_p"] = float(stats.ttest_rel(a[ok], b[ok]).pvalue)
        out["wilcoxon_p"] = float(stats.wilcoxon(a[ok], b[ok]).pvalue)
    return out


def _variant_inputs(log, est, robot, variants, values: dict, every: int) -> dict:
    """Per variant the SLAM inputs of every robot: shared leg-odometry inputs, the variant's scans and
    odometry (each scan kind and each coupling computed once)."""
    from jaxquad.estimate.laser import every_nth_frame, leg_laser_inputs, scan_ranges, visual_odometry_2d
    from jaxquad.slam import map_max_range
    from jaxquad.slam.variants import VARIANTS

    rmax = map_max_range(values)
    # The paper's scans keep the minimum of the band (as `jaxquad slam --variant` does).
    base = leg_laser_inputs(log, est, "stabilized", 5, 0.2, rmax, values["leg_yaw_rate_std"], "min")
    # `base` already holds the stabilized scans and the leg-inertial odometry: each is computed once.
    scans, odom = {"stabilized": (base["ranges"], base["bearings"])}, {"lo": base["odom"]}
    for name in variants:
        v = VARIANTS[name]
        if v.scans not in scans:
            scans[v.scans] = scan_ranges(log, est, v.scans, 5, 0.2, rmax, "min")
        key = "lo" if v.odometry == "lo" else v.vo_coupling
        if key not in odom:
            odom[key] = visual_odometry_2d(log, est, robot, v.vo_coupling)
    out = {}
    for name in variants:
        v = VARIANTS[name]
        ranges, bearings = scans[v.scans]
        x = {
            **base,
            "ranges": ranges,
            "bearings": bearings,
            "odom": odom["lo" if v.odometry == "lo" else v.vo_coupling],
        }
        out[name] = every_nth_frame(x, every)
    return out


def run_cell(args, robot_name: str, world: str) -> dict:
    """Simulate, estimate and run every variant's SLAM on one robot x world cell; returns the cell's
    record (settings, wall times, per-run scores, statistics, tests) and what the figures need."""
    from jaxquad.estimate.inputs import check_log
    from jaxquad.estimate.run import estimate_log
    from jaxquad.robots import load
    from jaxquad.sim.fleet import FleetConfig
    from jaxquad.sim.rollout import rollout
    from jaxquad.slam import final_poses, load_params, map_grid, map_max_range, run_fleet, slam_config
    from jaxquad.slam.report import robot_report, robot_slice
    from jaxquad.slam.variants import VARIANTS

    wall = {}
    t0 = time.perf_counter()
    config = FleetConfig(
        robot=robot_name,
        world=world,
        n_robots=args.runs,
        n_worlds=args.runs,
        style=args.style,
        seed=args.seed,
        depth=True,
    )
    log = rollout(config, args.seconds, progress=not args.quiet)
    wall["simulate_s"] = time.perf_counter() - t0
    maps, world_index = log.maps(), np.asarray(log["world_index"])
    fallen = np.asarray(log["fallen"], bool)
    t0 = time.perf_counter()
    robot = load(robot_name)
    check_log(robot, log, args.contacts)
    _, _, est = estimate_log(log, args.contacts, None, robot)
    values = load_params()
    every = max(1, round(config.camera_hz / args.scan_hz))
    xs = _variant_inputs(log, est, robot, args.variants, values, every)
    wall["estimate_vo_scans_s"] = time.perf_counter() - t0
    # One map extent for every variant (so one compiled SLAM per constraint kind): all their odometries.
    grid = map_grid(
        {"odom": np.concatenate([x["odom"] for x in xs.values()])}, values["resolution"], map_max_range(values)
    )
    scores, figure = {}, {"grid": grid, "true_map": maps[world_index[0] % len(maps)], "runs": {}}
    for name, x in xs.items():
        t0 = time.perf_counter()
        spec, params = slam_config(values, grid, VARIANTS[name].lo_constraints, x["T_base_laser"])
        state, out, _ = run_fleet(spec, params, x)
        final = final_poses(state, out)
        wall[f"slam_{name}_s"] = time.perf_counter() - t0
        t = np.asarray(x["t"], np.float64)
        reps = [
            robot_report(spec, t, robot_slice(state, i), robot_slice(out, i), final[i], x, i) for i in range(args.runs)
        ]
        scores[name] = {m: [None if fallen[i] else _score(r, m) for i, r in enumerate(reps)] for m in METRICS}
        figure["runs"][name] = {
            "state": robot_slice(state, 0),
            "final": final[0],
            "odom": x["odom"][0],
            "gt": x["gt"][0],
        }
        if not args.quiet:
            ate = np.array([s for s in scores[name]["ate"] if s is not None], float)
            print(
                f"{robot_name} {world} {name}: ATE {np.nanmean(ate):.3f} m over {np.isfinite(ate).sum()} runs, "
                f"{wall[f'slam_{name}_s']:.1f} s",
                file=sys.stderr,
            )
    as_array = lambda name, m: np.array([np.nan if s is None else s for s in scores[name][m]], float)  # noqa: E731
    stats = {name: {m: statistics(as_array(name, m)) for m in METRICS} for name in xs}
    tests = {}
    if "full" in xs:
        tests = {
            name: {m: paired_tests(as_array("full", m), as_array(name, m)) for m in METRICS}
            for name in xs
            if name != "full"
        }
    record = {
        "robot": robot_name,
        "world": world,
        "runs": args.runs,
        "fallen": int(fallen.sum()),
        "seconds": args.seconds,
        "wall": wall,
        "scores": scores,
        "statistics": stats,
        "full_vs": tests,
    }
    return record, figure


def _fmt(s: dict, digits: int = 2) -> str:
    if not s["n"]:
        return "-"
    if s["n"] < 2:
        return f"{s['mean']:.{digits}f} (n=1)"
    lo, hi = s["ci95"]
    return f"{s['mean']:.{digits}f} +- {s['std']:.{digits}f} [{lo:.{digits}f}, {hi:.{digits}f}]"


def _p(p) -> str:
    return "-" if p is None else f"{p:.1e}" if p < 1e-3 else f"{p:.3f}"


def markdown(records: list[dict], variants: list[str]) -> str:
    """The table (mean +- std [95 % CI] per metric and variant) and the paired tests of full."""
    lines = [
        "| robot | world | runs | metric | " + " | ".join(variants) + " |",
        "|---|---|---:|---|" + "---:|" * len(variants),
    ]
    for r in records:
        n = r["runs"] - r["fallen"]
        for m in METRICS:
            cells = " | ".join(_fmt(r["statistics"][v][m], 1 if m == "are_deg" else 2) for v in variants)
            lines.append(f"| {r['robot']} | {r['world']} | {n} | {m} | {cells} |")
    others = [v for v in variants if v != "full"]
    if "full" in variants and others:
        lines += [
            "",
            "Paired tests of full against each variant, ATE (mean difference full - variant, m; p of the "
            "paired t-test / Wilcoxon signed-rank):",
            "",
            "| robot | world | " + " | ".join(f"full vs {v}" for v in others) + " |",
            "|---|---|" + "---|" * len(others),
        ]
        for r in records:
            cells = []
            for v in others:
                t = r["full_vs"][v]["ate"]
                diff = "-" if t["mean_difference"] is None else f"{t['mean_difference']:+.3f}"
                cells.append(f"{diff} (p {_p(t['t_test_p'])} / {_p(t['wilcoxon_p'])})")
            lines.append(f"| {r['robot']} | {r['world']} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def draw_figures(folder: Path, record: dict, figure: dict) -> None:
    """Run 0's maps with and without stabilization (B+LO, full) beside the true map, and its final
    trajectories of every variant against the truth."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from jaxquad.io.atomic import atomic_open
    from jaxquad.slam.report import draw_map_vs_truth

    cell = f"{record['robot']}_{record['world']}"
    for name in ("B+LO", "full"):
        if name in figure["runs"]:
            run = figure["runs"][name]
            draw_map_vs_truth(
                folder / f"map_{cell}_{name.replace('+', '_')}.png",
                figure["grid"],
                run["state"],
                run["final"],
                run["odom"],
                run["gt"],
                figure["true_map"],
            )
    fig, ax = plt.subplots(figsize=(7, 6), constrained_layout=True)
    gt = next(iter(figure["runs"].values()))["gt"]
    ax.plot(gt[:, 0], gt[:, 1], "k-", lw=2, label="truth")
    for name, run in figure["runs"].items():
        ax.plot(
            run["final"][:, 0], run["final"][:, 1], lw=1, label=f"{name} (ATE {record['scores'][name]['ate'][0]:.2f} m)"
        )
    ax.set_aspect("equal")
    ax.set_xlabel("x (m)")
    ax.set_ylabel("y (m)")
    ax.set_title(f"{record['robot']} in the {record['world']}, run 0: final SLAM trajectories (unaligned)")
    ax.legend(fontsize=8)
    with atomic_open(folder / f"trajectories_{cell}.png", "wb") as f:
        fig.savefig(f, format="png", dpi=110)
    plt.close(fig)


def merge(paths: list[str]) -> dict:
    """The cells of several saved results as one result (variants checked alike, wall times summed)."""
    import json

    results = []
    for path in paths:
        try:
            results.append(json.loads(Path(path).read_text()))
        except (OSError, ValueError) as e:
            raise ValueError(f"{path}: not a saved ablation result ({e})") from None
        if not isinstance(results[-1], dict) or "cells" not in results[-1] or "settings" not in results[-1]:
            raise ValueError(f"{path}: not a saved ablation result (no 'cells' or 'settings')")
    variants = results[0]["settings"]["variants"]
    for path, r in zip(paths, results):
        if r["settings"]["variants"] != variants:
            raise ValueError(f"{path}: variants {r['settings']['variants']} differ from {paths[0]}'s {variants}")
    return {
        "merged": list(paths),
        "device": sorted({r["device"] for r in results}),
        "wall_s": float(sum(r["wall_s"] or 0.0 for r in results)),
        "settings": results[0]["settings"],
        "cells": [c for r in results for c in r["cells"]],
    }


def _merge_main(paths: list[str], json_path: str | None) -> dict:
    from jaxquad.io import write_json

    result = merge(paths)
    if json_path:
        write_json(json_path, result)
    print(markdown(result["cells"], result["settings"]["variants"]))
    runs = sorted({c["runs"] for c in result["cells"]})
    seconds = sorted({c["seconds"] for c in result["cells"]})
    print(
        f"\nwall time {result['wall_s']:.0f} s (summed) for {len(result['cells'])} cell(s) x "
        f"{len(result['settings']['variants'])} variants x {runs} runs x {seconds} s on {', '.join(result['device'])}"
    )
    return result


def main(argv: list[str] | None = None) -> dict:
    from jaxquad.slam.variants import VARIANTS

    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--runs", type=int, default=4, help="runs (robots, each in its own world) per cell (default 4)")
    p.add_argument("--robots", nargs="+", choices=("go2", "badger"), default=["go2"], help="robots (default go2)")
    p.add_argument(
        "--worlds", nargs="+", choices=("house", "warehouse"), default=["house"], help="worlds (default house)"
    )
    p.add_argument("--seconds", type=float, default=20.0, help="simulated time per run, s (default 20)")
    p.add_argument(
        "--variants", nargs="+", choices=tuple(VARIANTS), default=list(VARIANTS), help="variants (default all)"
    )
    p.add_argument(
        "--contacts",
        choices=("mixed", "observer", "sensor", "truth"),
        default="mixed",
        help="contact source of the leg odometry (default mixed)",
    )
    p.add_argument("--style", choices=("calm", "aggressive"), default="aggressive", help="gait (default aggressive)")
    p.add_argument("--seed", type=int, default=0, help="simulation seed (default 0)")
    p.add_argument("--scan-hz", type=float, default=10.0, help="scans per second fed to the SLAM (default 10)")
    p.add_argument("--json", default=None, help="write every run's scores and the statistics here")
    p.add_argument("--figures", default=None, help="folder for the map and trajectory figures")
    p.add_argument("--quiet", action="store_true", help="no progress output on stderr")
    p.add_argument("--merge", nargs="+", default=None, metavar="JSON", help="print one table of saved results")
    args = p.parse_args(argv)
    if args.merge:
        try:
            return _merge_main(args.merge, args.json)
        except ValueError as e:
            p.error(str(e))
    if args.runs < 2:
        p.error("--runs must be >= 2 (a standard deviation and a paired test need two runs)")
    if not (args.seconds > 0 and args.scan_hz > 0):
        p.error("--seconds and --scan-hz must be positive")
    from jaxquad.io import write_json
    from jaxquad.io.atomic import check_output_file

    if args.json:
        check_output_file(args.json, "--json")  # before hours of simulation, not after
    if args.figures:
        Path(args.figures).mkdir(parents=True, exist_ok=True)
    print(f"command: python experiments/ablation.py {' '.join(sys.argv[1:] if argv is None else argv)}")
    print(
        f"machine: {platform.node()}, {jax.devices()[0].device_kind} ({jax.default_backend()}), jax {jax.__version__}"
    )
    t0 = time.perf_counter()
    result = {
        "command": sys.argv if argv is None else ["experiments/ablation.py", *argv],
        "device": jax.devices()[0].device_kind,
        "backend": jax.default_backend(),
        "wall_s": None,
        "settings": {k: v for k, v in vars(args).items() if k not in ("json", "figures", "quiet")},
        "cells": [],
    }
    for robot in args.robots:
        for world in args.worlds:
            record, figure = run_cell(args, robot, world)
            result["cells"].append(record)
            result["wall_s"] = time.perf_counter() - t0
            if args.json:  # after every cell: a run stopped later keeps the cells it finished
                write_json(args.json, result)
            if args.figures:
                draw_figures(Path(args.figures), record, figure)
            del figure
            jax.clear_caches()  # the next cell's robot and world compile their own programs
    print(markdown(result["cells"], args.variants))
    print(
        f"\nwall time {result['wall_s']:.0f} s for {len(result['cells'])} cell(s) x {len(args.variants)} variants x "
        f"{args.runs} runs x {args.seconds:g} s"
    )
    return result


if __name__ == "__main__":
    main()
