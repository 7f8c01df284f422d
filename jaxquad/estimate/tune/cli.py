"""`jaxquad tune`: tune the contact observer's bandwidth, filter constants and thresholds on a fleet
log with ground truth (grid search or gradient descent); write them for `jaxquad estimate --params`.

Prints one JSON summary (scores of the paper's defaults and of the result on the training and
held-out robots, wall times) and writes it beside the params file as <stem>.summary.json.
"""

from __future__ import annotations

import argparse

from jaxquad.cli import add_devices_argument


def _grid_size(text: str) -> int | tuple[int, ...]:
    try:
        sizes = tuple(int(v) for v in text.split(","))
    except ValueError:
        raise argparse.ArgumentTypeError(f"grid size must be N or five N,N,N,N,N, got {text!r}") from None
    if len(sizes) not in (1, 5) or min(sizes) < 1:
        raise argparse.ArgumentTypeError(f"grid size must be N or five N,N,N,N,N (each >= 1), got {text!r}")
    return sizes[0] if len(sizes) == 1 else sizes


def add_arguments(parser: argparse.ArgumentParser) -> None:
    src = parser.add_mutually_exclusive_group(required=True)
    src.add_argument("--log", help="fleet or single-robot log (.npz) with tau, qd, gt_pose, gt_contact, gt_force")
    src.add_argument("--simulate", action="store_true", help="simulate a fleet first (options below)")
    parser.add_argument(
        "--method",
        choices=("grid", "gradient"),
        required=True,
        help="grid search over five axes, or gradient descent on a smooth surrogate loss",
    )
    parser.add_argument("--out", required=True, help="params file to write (.yaml, .yml or .json)")
    parser.add_argument("--mode", choices=("mixed", "plain"), default="mixed", help="observer mode (default mixed)")
    parser.add_argument(
        "--holdout",
        type=float,
        default=0.25,
        help="fraction of robots held out for scoring (default 0.25; a single-robot log is tuned and scored on itself)",
    )
    grid = parser.add_argument_group("grid search")
    grid.add_argument(
        "--grid-size",
        type=_grid_size,
        default=4,
        help="points per axis (bandwidth, alpha front, alpha rear, threshold on, off/on ratio): N or N,N,N,N,N "
        "(default 4)",
    )
    grid.add_argument(
        "--chunk",
        type=int,
        default=256,
        help="configurations per vmapped call, rounded up to a multiple of the devices (default 256)",
    )
    add_devices_argument(grid, "grid's configurations (and with --simulate the robots)")
    grad = parser.add_argument_group("gradient tuning")
    grad.add_argument("--steps", type=int, default=200, help="maximum optimizer steps (default 200)")
    grad.add_argument("--lr", type=float, default=0.05, help="Adam learning rate (default 0.05)")
    grad.add_argument(
        "--patience", type=int, default=25, help="stop after this many steps without improvement (default 25)"
    )
    sim = parser.add_argument_group("with --simulate")
    sim.add_argument("--robot", default="go2", help="go2, badger, or a path to an MJCF file (default go2)")
    sim.add_argument("--world", default="house", choices=("house", "warehouse"), help="generated world (default house)")
    sim.add_argument("--robots", type=int, default=8, help="fleet size (default 8)")
    sim.add_argument("--seconds", type=float, default=10.0, help="simulated time per robot, s (default 10)")
    sim.add_argument(
        "--style", default="aggressive", choices=("calm", "aggressive"), help="gait style (default aggressive)"
    )
    sim.add_argument("--seed", type=int, default=0, help="random seed of worlds, routes and noise (default 0)")


def run(args: argparse.Namespace) -> int:
    import dataclasses
    import tempfile
    import time
    from pathlib import Path

    import jax
    from tqdm import tqdm

    from jaxquad import parallel
    from jaxquad.estimate import tune as tn
    from jaxquad.estimate.tune.run import call_options
    from jaxquad.io import check_output_file, load_log, to_json, write_json
    from jaxquad.robots import load

    out = Path(args.out)
    if out.suffix.lower() not in (".json", ".yaml", ".yml"):
        raise ValueError(f"--out must end in .json, .yaml or .yml, got {out.name}")
    if args.chunk < 1 or args.steps < 1 or args.patience < 1:
        raise ValueError("--chunk, --steps and --patience must be >= 1")
    if not 0 <= args.holdout < 1:
        raise ValueError(f"--holdout must lie in [0, 1), got {args.holdout}")
    # The search is long: a place it cannot write must fail now, not after it.
    check_output_file(out, "--out")
    check_output_file(out.with_name(f"{out.stem}.summary.json"), "--out summary")
    walls, simulated = {}, None
    t0 = time.perf_counter()
    with tempfile.TemporaryDirectory() as tmp:
        if args.simulate:
            from jaxquad.sim.cli import simulate
            from jaxquad.sim.fleet import FleetConfig

            if args.robots < 1 or not args.seconds > 0:
                raise ValueError("--robots must be >= 1 and --seconds positive")
            if jax.process_count() > 1:
                raise ValueError("--simulate runs in one process; simulate first, then tune --log in several")
            config = FleetConfig(
                robot=args.robot,
                world=args.world,
                n_robots=args.robots,
                style=args.style,
                seed=args.seed,
                depth=False,
                devices=args.devices,
            )
            log_path = simulate(config, args.seconds, tmp)
            simulated = {"config": dataclasses.asdict(config), "seconds": args.seconds}
            walls["simulate_s"] = time.perf_counter() - t0
        else:
            log_path = args.log
        log = load_log(log_path)
    robot = load(str(log["robot"]))
    t1 = time.perf_counter()
    input_options = call_options(tn.observer_inputs, {})
    inputs, truth, t = tn.observer_inputs(robot, log, **input_options)
    walls["observer_inputs_s"] = time.perf_counter() - t1

    if args.method == "grid":
        spec = tn.GridSpec.default(args.grid_size)
        bar = tqdm(total=spec.size, desc="grid", unit="config")
        progress = lambda done, total: bar.update(done - bar.n)  # noqa: E731
        kwargs = dict(spec=spec, chunk=args.chunk, devices=args.devices)
    else:
        bar = tqdm(total=args.steps, desc="gradient", unit="step")

        def progress(step: int, loss: float) -> None:
            bar.update(step - bar.n)
            bar.set_postfix(loss=f"{loss:.4f}")

        kwargs = dict(steps=args.steps, learning_rate=args.lr, patience=args.patience)
    try:
        # A single-robot log has no robot to hold out: it is tuned and scored on itself (said in the summary).
        holdout = args.holdout if inputs.p.shape[0] > 1 else 0.0
        best, tuned = tn.tune_fleet(args.method, inputs, truth, t, args.mode, holdout, progress=progress, **kwargs)
    finally:
        bar.close()
    walls["total_s"] = time.perf_counter() - t0
    if not parallel.is_main():  # every process searched the same grid; process 0 writes
        return 0
    summary = {
        "log": None if args.simulate else str(args.log),
        "simulated": simulated,
        "robot": robot.name,
        "holdout_requested": args.holdout,
        "observer_inputs": input_options,
    }
    summary |= tuned | {"walls": walls}
    header = (
        f"jaxquad tune --method {args.method}: F1 {summary['paper_train']['f1']:.4f} (paper defaults) -> "
        f"{summary['tuned_train']['f1']:.4f} on {summary['robots_train']} training robot(s)"
    )
    tn.save_params(out, best, header=header)
    write_json(out.with_name(f"{out.stem}.summary.json"), summary)
    print(to_json(summary))
    return 0
