"""Scaling over devices, measured in one run: the simulator's robot-steps/s with depth (`jaxquad bench
--sim` rows, robots split over the devices) and the grid tuner's configurations/s (configurations
split over the devices, every device scoring all robots), on each device count given, with the
speedup over the first. Prints the command, the machine, one Markdown table, and with --json the rows.

    python experiments/scaling.py [--parts sim grid] [--devices 1 2] [--robots 16384 65536 131072] [--sim-repeats 3]
        [--grid-log fleet.npz | --grid-robots 48 --grid-seconds 20] [--grid-size 8,8,4,4,4] [--chunk 4096] [--json]

A fleet size that does not fit on a device count is reported with the reason (the largest that
fits). Grid counts are checked equal across device counts (`same_counts`).
"""

from __future__ import annotations

import argparse
import sys
import time


def _sim_rows(args) -> list[dict]:
    from jaxquad import _bench_sim

    ns = argparse.Namespace(
        robots=args.robots,
        sim_robot=args.robot,
        sim_world="house",
        sim_chunk_frames=None,
        sim_repeats=args.sim_repeats,
        sim_depth="on",
        devices=args.devices,
    )
    return _bench_sim.run(ns)["rows"]


def _grid_rows(args) -> tuple[list[dict], str]:
    import numpy as np

    from jaxquad.estimate import tune as tn
    from jaxquad.io import load_log
    from jaxquad.kernels import ObserverParams
    from jaxquad.robots import load

    if args.grid_log:
        log = load_log(args.grid_log)
    else:
        from jaxquad.sim import FleetConfig, rollout

        cfg = FleetConfig(robot=args.robot, n_robots=args.grid_robots, style="aggressive", seed=1, depth=False)
        log = rollout(cfg, args.grid_seconds, progress=False)
    robot = load(str(log["robot"]))
    inputs, truth, t = tn.observer_inputs(robot, log)
    sizes = tuple(int(v) for v in args.grid_size.split(","))
    spec = tn.GridSpec.default(sizes[0] if len(sizes) == 1 else sizes)
    params = spec.params(ObserverParams.paper(inputs.n_feet, "mixed"))
    what = f"{spec.size} configurations x {inputs.p.shape[0]} robots x {t[-1] - t[0]:.0f} s"
    rows, first = [], None
    for d in args.devices:
        t0 = time.perf_counter()
        tn.grid_counts(params, inputs, truth, args.chunk, devices=d)  # compiles
        compile_s = time.perf_counter() - t0
        t0 = time.perf_counter()
        counts = tn.grid_counts(params, inputs, truth, args.chunk, devices=d)
        wall = time.perf_counter() - t0
        first = counts if first is None else first
        same = all(np.array_equal(getattr(counts, k), getattr(first, k)) for k in ("tp", "fp", "fn", "samples"))
        rows.append(
            {
                "devices": d,
                "configurations": spec.size,
                "first_call_s": compile_s,
                "wall_s": wall,
                "configurations_per_s": spec.size / wall,
                "same_counts": same,
            }
        )
    return rows, what


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument(
        "--parts",
        nargs="+",
        choices=("sim", "grid"),
        default=["sim", "grid"],
        help="what to measure (default: sim grid)",
    )
    parser.add_argument("--devices", type=int, nargs="+", default=None, help="device counts (default: 1 and all)")
    parser.add_argument("--robot", default="go2", help="robot (default go2)")
    parser.add_argument(
        "--robots",
        type=int,
        nargs="+",
        default=None,
        help="fleet sizes, depth on (default: 8 on CPU, 16384 65536 131072 on GPU)",
    )
    parser.add_argument("--sim-repeats", type=int, default=3, help="steady chunks timed per size (default 3)")
    parser.add_argument("--grid-log", default=None, help="fleet log to tune on (default: simulate one)")
    parser.add_argument(
        "--grid-robots", type=int, default=None, help="robots of the simulated log (default 4 CPU, 48 GPU)"
    )
    parser.add_argument("--grid-seconds", type=float, default=None, help="its length, s (default 2 CPU, 20 GPU)")
    parser.add_argument(
        "--grid-size", default=None, help="points per axis, N or N,N,N,N,N (default 3 CPU, 8,8,4,4,4 GPU)"
    )
    parser.add_argument("--chunk", type=int, default=None, help="configurations per call (default 64 CPU, 4096 GPU)")
    parser.add_argument("--json", action="store_true", help="also print the rows as JSON")
    args = parser.parse_args()

    import jax

    from jaxquad.bench import _environment
    from jaxquad.io.jsonfile import to_json

    cpu = jax.default_backend() == "cpu"
    args.devices = args.devices or sorted({1, jax.device_count()})
    args.robots = args.robots or ([8] if cpu else [16384, 65536, 131072])
    args.grid_robots = args.grid_robots or (4 if cpu else 48)
    args.grid_seconds = args.grid_seconds or (2.0 if cpu else 20.0)
    args.grid_size = args.grid_size or ("3" if cpu else "8,8,4,4,4")
    args.chunk = args.chunk or (64 if cpu else 4096)
    env = _environment()
    print(f"python {' '.join(sys.argv)}\n{env['device']} x {env['n_devices']}, jax {env['jax_version']}\n", flush=True)
    grid, what = _grid_rows(args) if "grid" in args.parts else ([], "")
    sim = _sim_rows(args) if "sim" in args.parts else []

    base = {(r["robots"]): r.get("robot_steps_per_s") for r in sim if r["devices"] == args.devices[0]}
    print("| what | size | devices | throughput | speedup | notes |")
    print("|---|---|---:|---:|---:|---|")
    for r in sim:
        if "error" in r:
            print(f"| simulator, depth on | {r['robots']} robots | {r['devices']} | does not fit | | {r['error']} |")
            continue
        speed = f"{r['robot_steps_per_s'] / base[r['robots']]:.2f}x" if base.get(r["robots"]) else ""
        print(
            f"| simulator, depth {r['depth']} | {r['robots']} robots | {r['devices']} | "
            f"{r['robot_steps_per_s']:,.0f} robot-steps/s | {speed} | {r['frames_per_chunk']} frames/chunk, "
            f"{r['chunk_gib']:.1f} GiB/device, compile {r['compile_s']:.0f} s |"
        )
    for r in grid:
        speed = r["configurations_per_s"] / grid[0]["configurations_per_s"]
        print(
            f"| grid tuning | {what} | {r['devices']} | {r['configurations_per_s']:,.0f} configurations/s | "
            f"{speed:.2f}x | {r['wall_s']:.1f} s, first call {r['first_call_s']:.1f} s, "
            f"counts {'equal' if r['same_counts'] else 'DIFFER'} |"
        )
    if args.json:
        print(to_json({**env, "simulator": sim, "grid": {"what": what, "rows": grid}}))


if __name__ == "__main__":
    main()
