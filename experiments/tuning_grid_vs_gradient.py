"""Grid search vs gradient tuning of the contact observer on one fleet log, next to the paper's
defaults: prints a Markdown table (F1, touchdown / lift-off delays, force RMSE, wall time) on the
training and held-out robots, and the JSON of both runs with --json.

    python experiments/tuning_grid_vs_gradient.py --log runs/fleet.npz [--mode mixed] [--grid-size 4] [--steps 200]
"""

from __future__ import annotations

import argparse
import json
import time


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--log", required=True, help="fleet log with tau, qd and ground truth")
    parser.add_argument("--mode", choices=("mixed", "plain"), default="mixed")
    parser.add_argument("--grid-size", type=int, default=4, help="points per grid axis (5 axes)")
    parser.add_argument("--chunk", type=int, default=256, help="grid configurations per vmapped call")
    parser.add_argument("--steps", type=int, default=200, help="maximum gradient steps")
    parser.add_argument("--holdout", type=float, default=0.25)
    parser.add_argument("--json", action="store_true", help="also print both summaries as JSON")
    args = parser.parse_args()

    from jaxquad.estimate import tune as tn
    from jaxquad.io import load_log
    from jaxquad.robots import load

    log = load_log(args.log)
    robot = load(str(log["robot"]))
    t0 = time.perf_counter()
    inputs, truth, t = tn.observer_inputs(robot, log)
    inputs_s = time.perf_counter() - t0
    runs = {
        "grid": tn.tune_fleet(
            "grid",
            inputs,
            truth,
            t,
            args.mode,
            args.holdout,
            spec=tn.GridSpec.default(args.grid_size),
            chunk=args.chunk,
        )[1],
        "gradient": tn.tune_fleet("gradient", inputs, truth, t, args.mode, args.holdout, steps=args.steps)[1],
    }
    splits = [s for s in ("train", "heldout") if f"paper_{s}" in runs["grid"]]
    print(
        f"{robot.name}, {args.mode} mode, {runs['grid']['robots_train']} training + "
        f"{runs['grid']['robots_heldout']} held-out robot(s), {runs['grid']['duration_s']:.1f} s; "
        f"observer inputs {inputs_s:.1f} s\n"
    )
    print(
        "| parameters | robots | F1 | touchdown ms (mean, abs) | lift-off ms (mean, abs) | missed edges "
        "| force RMSE N | wall s |"
    )
    print("|---|---|---|---|---|---|---|---|")
    rows = [("paper defaults", "paper", runs["grid"], None)]
    rows += [
        (f"grid ({runs['grid']['configurations']} configs)", "tuned", runs["grid"], runs["grid"]["wall_s"]),
        (
            f"gradient ({runs['gradient']['steps']} steps, {runs['gradient']['stopped']})",
            "tuned",
            runs["gradient"],
            runs["gradient"]["wall_s"],
        ),
    ]
    for name, prefix, run, wall in rows:
        for split in splits:
            s = run[f"{prefix}_{split}"]
            print(
                f"| {name} | {split} | {s['f1']:.4f} | "
                f"{s['touchdown_mean_ms']:.1f}, {s['touchdown_mean_abs_ms']:.1f} | "
                f"{s['liftoff_mean_ms']:.1f}, {s['liftoff_mean_abs_ms']:.1f} | "
                f"{s['touchdown_missed'] + s['liftoff_missed']} | {s['force_rmse_n']:.1f} | "
                f"{'' if wall is None else f'{wall:.1f}'} |"
            )
    for method in ("grid", "gradient"):
        print(f"\n{method}: {json.dumps(runs[method]['params'])}")
    if args.json:
        print(json.dumps(runs))


if __name__ == "__main__":
    main()
