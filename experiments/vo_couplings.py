"""Visual odometry with and without leg-odometry coupling, and its batched throughput.

    python experiments/vo_couplings.py --log sim/fleet.npz [--contacts mixed truth] [--throughput 1 1024]
    python experiments/vo_couplings.py --robot go2 --robot badger --world house --world warehouse
        [--robots 32] [--seconds 60] [--seed 1] [--contacts mixed truth]
        [--params jaxquad/demo/tuned/{robot}_aggressive.yaml]

The log is a simulated fleet with depth and ground truth (`jaxquad simulate ... --out sim/`), or, with
--robot and --world, fleets simulated in memory (aggressive gait, depth on; no multi-GB log is written),
one per robot and world. Per log and contact source the estimator runs once (leg odometry); the visual
odometry then runs with each coupling (off, guess, guess+restart). Printed as Markdown: per coupling the
mean and max ATE over robots (SE(3)-aligned, evo's definition), the RPE translation RMSE over 2 m / 5 m
segments (in % of the segment), the segment drift (`drift_pct`, KITTI's t_rel over 2, 5 and 10 m
segments, pooled over robots as KITTI does; and the worst robot's), the rotation drift (deg/m) and the
tracking-loss rate; the leg odometry's row at the same stamps for comparison. --params: the estimator's
parameters file (`jaxquad tune` output), `{robot}` replaced by the log's robot; default the paper's
numbers. With --throughput B...:
frames/s of B robots' odometry in one jitted vmapped call (the first robot's first --frames frames
repeated), compile time apart.
"""

from __future__ import annotations

import argparse
import platform
import sys
import time

import jax
import numpy as np


def _table(log, est, R_base_imu) -> list[str]:
    from jaxquad.vo import COUPLINGS, score_vo, visual_odometry

    rows = [
        "| odometry | mean ATE m | max ATE m | RPE 2 m % | RPE 5 m % | drift % | max drift % | drift deg/m "
        "| loss rate | wall s |",
        "|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|",
    ]
    leg_rows = None
    for coupling in COUPLINGS:
        t0 = time.perf_counter()
        res = visual_odometry(log, est.p_world_base, est.q_world_base, R_base_imu, coupling)
        wall = time.perf_counter() - t0
        robots = score_vo(log, res, est.p_world_base, est.q_world_base)
        rows.append(_row(f"vo, {coupling}", [r["scores"]["vo"] for r in robots], robots, wall))
        leg_rows = [r["scores"]["leg_odometry"] for r in robots]
    rows.append(_row("leg odometry alone", leg_rows, None, float("nan")))
    return rows


def _row(name, scores, robots, wall) -> str:
    def mean(key, scale=1.0):
        vals = [s["trajectory"][key]["rmse"] * scale for s in scores if key in s["trajectory"]]
        return f"{np.mean(vals):.2f}" if vals else "-"

    ate = [s["trajectory"]["ate"]["rmse"] for s in scores if "ate" in s["trajectory"]]
    drift = [s["drift"] for s in scores]
    count = np.array([d["drift_pct"]["n_segments"] for d in drift], float)
    pct = np.array([d["drift_pct"]["mean"] for d in drift], float)
    deg = np.array([d["drift_deg_per_m"]["mean"] for d in drift], float)
    has = count > 0  # segment drift of 2, 5, 10 m segments, pooled over robots (KITTI's t_rel, r_rel)
    pooled = lambda x: np.sum(x[has] * count[has]) / np.sum(count[has]) if has.any() else float("nan")  # noqa: E731
    worst = np.max(pct[has]) if has.any() else float("nan")
    loss = f"{np.mean([r['loss_rate'] for r in robots]) * 100:.2f} %" if robots else "-"
    return (
        f"| {name} | {np.mean(ate):.3f} | {np.max(ate):.3f} | {mean('rpe_2m', 50.0)} | {mean('rpe_5m', 20.0)} | "
        f"{pooled(pct):.2f} | {worst:.2f} | {pooled(deg):.3f} | {loss} | {wall:.1f} |"
    )


def _throughput(log, est, R_base_imu, batches, frames: int) -> list[str]:
    import jax.numpy as jnp

    from jaxquad.vo import VoParams, run, vo_inputs

    inp = vo_inputs(log, est.p_world_base, est.q_world_base, R_base_imu)
    inp = jax.tree.map(lambda a: a[:1, :frames], inp)  # depth is 77 kB a frame: bound the batch's memory
    params = VoParams.default(np.asarray(log["K"]), np.asarray(log["T_base_camera"]))
    fn = jax.jit(jax.vmap(run, in_axes=(None, 0)))
    rows = [
        "| robots | frames | compile s | run s | frames/s |",
        "|---:|---:|---:|---:|---:|",
    ]
    for b in batches:
        x = jax.tree.map(lambda a, b=b: jnp.repeat(a, b, 0), inp)
        t0 = time.perf_counter()
        jax.block_until_ready(fn(params, x))
        compile_s = time.perf_counter() - t0
        runs = []
        for _ in range(3):
            t0 = time.perf_counter()
            jax.block_until_ready(fn(params, x))
            runs.append(time.perf_counter() - t0)
        frames = b * x.depth.shape[1]
        run_s = float(np.median(runs))
        rows.append(f"| {b} | {frames} | {compile_s - run_s:.1f} | {run_s:.3f} | {frames / run_s:,.0f} |")
    return rows


def _logs(args, log):
    """(title, log) pairs: the --log file's (read already), or one in-memory fleet per --robot x --world."""
    if log is not None:
        yield args.log, log
        return
    from jaxquad.sim.fleet import FleetConfig
    from jaxquad.sim.rollout import rollout

    for robot in args.robot:
        for world in args.world:
            config = FleetConfig(
                robot=robot,
                world=world,
                n_robots=args.robots,
                n_worlds=min(4, args.robots),
                style="aggressive",
                seed=args.seed,
                depth=True,
            )
            yield (
                f"{robot} / {world}, {args.robots} robots x {args.seconds:g} s, seed {args.seed}",
                rollout(config, args.seconds, progress=True),
            )


def _observer_params(ap: argparse.ArgumentParser, template: str | None, robot, contacts: str):
    """(path, PipelineParams) for `robot` from the --params template ({robot} replaced), or the paper's
    numbers; a missing or malformed file is a one-line usage error."""
    from jaxquad.estimate.run import load_params

    path = None if template is None else template.replace("{robot}", robot.name)
    try:
        return path, load_params(path, len(robot.foot_names), contacts)
    except (OSError, ValueError) as e:
        ap.error(str(e))


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--log", default=None, help="fleet log with depth and gt_pose (.npz); or simulate with --robot")
    ap.add_argument("--robot", action="append", choices=("go2", "badger"), help="simulate this robot (repeatable)")
    ap.add_argument("--world", action="append", choices=("house", "warehouse"), help="in this world (repeatable)")
    ap.add_argument("--robots", type=int, default=32, help="simulated robots per fleet (default 32)")
    ap.add_argument("--seconds", type=float, default=60.0, help="simulated time per fleet, s (default 60)")
    ap.add_argument("--seed", type=int, default=1, help="simulation seed (default 1)")
    ap.add_argument(
        "--contacts",
        nargs="+",
        default=["mixed"],
        choices=("observer", "mixed", "sensor", "truth"),
        help="contact sources of the leg odometry, a table each (default mixed)",
    )
    ap.add_argument(
        "--throughput",
        type=int,
        nargs="*",
        default=[],
        help="batch sizes to time on the first log (default: none)",
    )
    ap.add_argument("--frames", type=int, default=64, help="frames per robot in the throughput runs (default 64)")
    ap.add_argument(
        "--params",
        default=None,
        help="estimator parameters (.yaml/.json, e.g. tuned), {robot} replaced by the robot (default: the paper's)",
    )
    args = ap.parse_args()
    if (args.log is None) == (args.robot is None):
        ap.error("give either --log or --robot (with --world)")
    if args.robot is not None and (args.world is None or args.robots < 1 or not args.seconds > 0):
        ap.error("--robot needs --world, --robots >= 1 and --seconds > 0")
    from jaxquad.estimate import estimate_log
    from jaxquad.estimate.inputs import R_base_imu
    from jaxquad.robots import load

    given = None
    if args.log is not None:  # a missing or malformed log is a usage error, before any work
        from jaxquad.io import load_log

        try:
            given = load_log(args.log)
        except (OSError, ValueError) as e:
            ap.error(str(e))
    # every params file read once, before any simulation
    names = args.robot or [str(np.asarray(given["robot"]))]
    robots = [load(n) for n in names]
    observer = {(r.name, c): _observer_params(ap, args.params, r, c) for r in robots for c in args.contacts}

    print(
        f"`python {' '.join(sys.argv)}`  \nmachine: {platform.processor() or platform.machine()}, "
        f"jax {jax.__version__} on {jax.devices()[0].device_kind}\n"
    )
    first = True
    for title, log in _logs(args, given):
        robot = load(str(np.asarray(log["robot"])))
        for contacts in args.contacts:
            path, params = observer[robot.name, contacts]
            robot, _, est = estimate_log(log, contacts, params, robot)
            source = "" if path is None else f" ({path})"
            print(f"\n{title}, {contacts} contacts{source}:\n")
            print("\n".join(_table(log, est, R_base_imu(robot))), flush=True)
            if args.throughput and first:
                print()
                print("\n".join(_throughput(log, est, R_base_imu(robot), args.throughput, args.frames)), flush=True)
            first = False
    return 0


if __name__ == "__main__":
    sys.exit(main())
