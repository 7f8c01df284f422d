"""`jaxquad bench --sim`: fleet simulation throughput (robot-steps/s), with and without depth.

One row per (robots, depth): building the fleet (worlds, routes, compiling the chunk at the length
that fits the device's free memory) is the compile time; the steady chunk time is the median of a
few chunks after a first one (state carried between them). A size that does not fit is reported with
the reason and the largest fleet that fits, and the other rows still run. `--devices 1 2` runs every
row on 1 and on 2 devices in the same process (robots split over the devices, `jaxquad.parallel`).
"""

from __future__ import annotations

import argparse


def add_arguments(parser: argparse._ArgumentGroup) -> None:  # the bench command's group for this section
    parser.add_argument(
        "--robots",
        type=int,
        nargs="+",
        metavar="N",
        help="fleet sizes for --sim (default: 1 64 on CPU, 1024 4096 16384 on GPU)",
    )
    parser.add_argument("--sim-robot", default="go2", help="robot for --sim (default go2)")
    parser.add_argument(
        "--sim-world", default="house", choices=["house", "warehouse"], help="generated world for --sim (default house)"
    )
    parser.add_argument(
        "--sim-chunk-frames",
        type=int,
        default=None,
        help="camera frames per chunk for --sim (default: the most that fit in free memory, <= 30)",
    )
    parser.add_argument("--sim-repeats", type=int, default=3, help="steady chunks timed per row (default 3)")
    parser.add_argument(
        "--sim-depth",
        choices=("both", "on", "off"),
        default="both",
        help="rows with the depth camera on, off or both (default both)",
    )


def run(args: argparse.Namespace) -> dict:
    import time

    import jax

    from jaxquad import parallel
    from jaxquad.sim.fleet import FleetConfig, build_fleet, init, run_chunk

    sizes = args.robots or ([1, 64] if jax.default_backend() == "cpu" else [1024, 4096, 16384])
    if any(n < 1 for n in sizes):
        raise ValueError(f"--robots sizes must be >= 1, got {sizes}")
    rows = []
    grid = [
        (d, n, depth)
        for d in (getattr(args, "devices", None) or [None])
        for n in sizes
        for depth in {"both": (True, False), "on": (True,), "off": (False,)}[getattr(args, "sim_depth", "both")]
    ]
    for devices, n, depth in grid:
        cfg = FleetConfig(
            robot=args.sim_robot,
            world=args.sim_world,
            n_robots=n,
            n_worlds=min(n, 4),
            depth=depth,
            frames_per_chunk=args.sim_chunk_frames,
            devices=devices,
        )
        label = f"{cfg.width}x{cfg.height}" if depth else "off"
        t0 = time.perf_counter()
        try:
            fleet = build_fleet(cfg)
            state = jax.block_until_ready(init(fleet))
            compile_s = time.perf_counter() - t0
            state, out = run_chunk(fleet, state)
            jax.block_until_ready(out)
            times = []
            for _ in range(max(1, args.sim_repeats)):
                del out  # a chunk's outputs must not outlive it: the next chunk's plan has no room for them
                t0 = time.perf_counter()
                state, out = run_chunk(fleet, state)
                jax.block_until_ready(out)
                times.append(time.perf_counter() - t0)
        except (ValueError, jax.errors.JaxRuntimeError) as e:  # does not fit: say so, keep the other rows
            rows.append(
                {
                    "devices": devices or jax.device_count(),
                    "robots": n,
                    "depth": label,
                    "error": str(e).splitlines()[0][:300],
                }
            )
            fleet = state = out = None
            jax.clear_caches()
            continue
        times.sort()
        steady = times[len(times) // 2]
        steps = fleet.samples_per_chunk * cfg.log_every
        rows.append(
            {
                "devices": fleet.mesh.size,
                "robots": n,
                "depth": f"{label}@{1 / fleet.frame_dt:.2f}Hz" if depth else label,
                "compile_s": compile_s,
                "frames_per_chunk": fleet.frames_per_chunk,
                "chunk_gib": fleet.chunk_bytes / 2**30,  # per device
                "chunk_ms": 1e3 * steady,
                "sim_s_per_chunk": steps * fleet.dt,
                "robot_steps_per_s": n * steps / steady,  # real robots only (padding copies not counted)
                "fallen": int(parallel.gather(state.fallen)[:n].sum()),
            }
        )
        del fleet, state, out
    return {"rows": rows}
