"""`jaxquad eval REF.tum EST.tum`: the paper's trajectory metrics (ATE, ARE, APE, RPE) as evo computes them,
and KITTI's segment drift."""

from __future__ import annotations

import argparse
import math


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("ref", help="reference trajectory (TUM: timestamp tx ty tz qx qy qz qw)")
    parser.add_argument("est", help="estimated trajectory (TUM)")
    parser.add_argument(
        "--align",
        default="se3",
        choices=("se3", "sim3", "scale", "origin", "none"),
        help="alignment of the estimate to the reference (default: se3 Umeyama)",
    )
    parser.add_argument(
        "--delta",
        type=float,
        nargs="+",
        default=[2.0, 5.0, 10.0],
        metavar="D",
        help="RPE deltas (default: 2 5 10), in travelled metres unless --delta-unit frames",
    )
    parser.add_argument("--delta-unit", default="m", choices=("m", "frames"), help="unit of --delta (default: m)")
    parser.add_argument(
        "--all-pairs", action="store_true", help="RPE over all pairs instead of consecutive ones (default: consecutive)"
    )
    parser.add_argument(
        "--max-diff",
        type=float,
        default=0.01,
        metavar="S",
        help="max. time difference in seconds when associating stamps (default: 0.01)",
    )
    parser.add_argument(
        "--drift-length",
        type=float,
        nargs="+",
        default=[2.0, 5.0, 10.0],
        metavar="L",
        help="segment lengths of the KITTI drift, metres of reference path (default: 2 5 10). drift_pct is "
        "|t((gt_i^-1 gt_j)^-1 (est_i^-1 est_j))| / L in %%, drift_deg_per_m its rotation angle / L, with j the "
        "first pose whose reference path from i exceeds L, averaged over every segment of every length. Uses "
        "relative poses of the unaligned estimate, so --align does not change it; null with 0 segments when "
        "the reference path is shorter than L",
    )
    parser.add_argument(
        "--drift-step",
        type=int,
        default=10,
        metavar="N",
        help="poses between segment starts of the drift (default: 10, as KITTI)",
    )
    parser.add_argument(
        "--json",
        action="store_true",
        help="print one JSON object (NaN written as null): ate, are, are_deg, ape, ape_rotation_part, rpe_<D>, "
        "drift_pct and drift_deg_per_m (mean, per_length, lengths_m, n_segments, n_segments_per_length, "
        "step_poses), n_pairs, alignment, ok",
    )
    parser.add_argument(
        "--plot", metavar="OUT.png", help="write a PNG of the xy trajectories and the error over time (default: none)"
    )


def _table(d: dict) -> str:
    cols = ("rmse", "mean", "median", "std", "min", "max")
    names = {"ate": "ATE (m)", "are": "ARE (rad)", "are_deg": "ARE (deg)", "ape": "APE (full)"}
    rows = [(names[k], d[k]) for k in names]
    rows += [(f"RPE {k[4:]}", v) for k, v in d.items() if k.startswith("rpe_")]
    width = max(len(r[0]) for r in rows)
    lines = [" " * width + "".join(f"{c:>12}" for c in cols)]
    lines += [name.ljust(width) + "".join(f"{s[c]:12.6g}" for c in cols) for name, s in rows]
    a = d["alignment"]
    lines.append(f"{d['n_pairs']} associated poses; alignment {a['mode']}, scale {a['scale']:.9g}")
    t, r = d["drift_pct"], d["drift_deg_per_m"]
    fmt = lambda x: "n/a" if x is None or math.isnan(x) else f"{x:.4g}"
    per = lambda s: ", ".join(f"{length:g} m: {fmt(v)}" for length, v in zip(s["lengths_m"], s["per_length"]))
    lines.append(
        f"drift (KITTI, unaligned) {fmt(t['mean'])} % ({per(t)}), {fmt(r['mean'])} deg/m ({per(r)}); "
        f"{t['n_segments']} segments ({', '.join(map(str, t['n_segments_per_length']))}), "
        f"starts every {t['step_poses']} poses"
    )
    return "\n".join(lines)


def run(args: argparse.Namespace) -> int:
    from jaxquad.io.atomic import check_output_file
    from jaxquad.io.jsonfile import to_json
    from jaxquad.io.tum import read_tum
    from jaxquad.metrics._evaluate import evaluate

    if args.plot:
        check_output_file(args.plot, "--plot")
    ev = evaluate(
        read_tum(args.ref),
        read_tum(args.est),
        align=args.align,
        deltas=args.delta,
        delta_unit=args.delta_unit,
        all_pairs=args.all_pairs,
        max_diff_s=args.max_diff,
        drift_lengths_m=args.drift_length,
        drift_step=args.drift_step,
    )
    d = ev.to_dict()
    print(to_json(d) if args.json else _table(d))
    if args.plot:
        from jaxquad.metrics.plot import plot_evaluation

        plot_evaluation(ev, args.plot)
    return 0
