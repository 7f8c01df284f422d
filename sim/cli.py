"""`jaxquad simulate`: run a fleet and write its log, ground-truth TUM files and world maps."""

from __future__ import annotations

import argparse
import shutil
import tempfile
from pathlib import Path


def parse_resolution(text: str) -> tuple[int, int]:
    """argparse type for a depth image size WxH in pixels, e.g. 160x120."""
    try:
        w, h = (int(v) for v in text.lower().split("x"))
    except ValueError:
        raise argparse.ArgumentTypeError(f"resolution must look like 160x120, got {text!r}") from None
    if w < 8 or h < 8:
        raise argparse.ArgumentTypeError(f"resolution too small: {text}")
    return w, h


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--robot", default="go2", help="go2, badger, or a path to an MJCF file")
    parser.add_argument("--world", default="house", choices=["house", "warehouse"])
    parser.add_argument("--robots", type=int, default=4, help="number of robots (default 4)")
    parser.add_argument("--worlds", type=int, default=1, help="distinct worlds; robot i walks world i %% worlds")
    parser.add_argument("--seconds", type=float, default=10.0, help="simulated time (rounded up to whole chunks)")
    parser.add_argument("--style", default="calm", choices=["calm", "aggressive"])
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--out", required=True, help="output folder")
    parser.add_argument("--no-depth", action="store_true", help="skip the depth camera")
    parser.add_argument("--resolution", type=parse_resolution, default=(160, 120), help="depth image WxH (default 160x120)")
    parser.add_argument("--no-randomize", action="store_true", help="nominal masses, friction, motors and noise levels")


def simulate(config, seconds: float, out: str | Path, progress: bool = True) -> Path:
    """Run the fleet and write `fleet.npz`, `gt_<i>.tum` per robot and `map_<world>_<k>.yaml/.pgm`.

    Chunks stream into memory-mapped arrays in a temporary folder inside `out`; the log is packed
    and renamed only when the run is complete, so nothing half-written is ever left at a final path.
    """
    import jax
    import numpy as np
    from tqdm import tqdm

    from jaxquad.io import TumTrajectory, save_log, save_map, write_tum
    from jaxquad.sim.fleet import build_fleet, init, n_chunks, run_chunk
    from jaxquad.sim.worlds import occupancy_map

    if not (seconds > 0):
        raise ValueError(f"--seconds must be positive, got {seconds}")
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    fleet = build_fleet(config)
    chunks = n_chunks(fleet, seconds)
    n, T = config.n_robots, chunks * fleet.samples_per_chunk
    F = chunks * config.frames_per_chunk
    tmp = Path(tempfile.mkdtemp(dir=out, prefix=".simulate."))
    try:
        arrays: dict[str, np.ndarray] = {}
        state = init(fleet)
        for c in tqdm(range(chunks), desc=f"simulate {n} x {config.robot}", unit="chunk", disable=not progress):
            state, outs = run_chunk(fleet, state)
            outs = jax.device_get(outs)
            for key, value in outs.items():
                if key not in arrays:
                    total = F if key == "depth" else T
                    shape = (n, total) + value.shape[2:]
                    arrays[key] = np.lib.format.open_memmap(tmp / f"{key}.npy", mode="w+", dtype=value.dtype, shape=shape)
                step = value.shape[1]
                arrays[key][:, c * step : (c + 1) * step] = value
        state = jax.device_get(state)
        t = (np.arange(T) + 1) * fleet.log_dt
        log = dict(arrays)
        log.update(
            t=t,
            robot=np.array(config.robot),
            joint_names=np.array(fleet.robot.joint_names),
            fallen=np.asarray(state.fallen),
            collided=np.asarray(state.collided),
            world_index=np.arange(n) % config.n_worlds,
        )
        if config.depth:
            log.update(depth_t=(np.arange(F) + 1) * fleet.frame_dt, K=fleet.K, T_base_camera=fleet.T_base_camera)
        save_log(out / "fleet.npz", log)
        for i in range(n):
            pose = np.asarray(arrays["gt_pose"][i], np.float64)
            traj = TumTrajectory(t, pose[:, :3], np.c_[pose[:, 4:7], pose[:, 3:4]])
            write_tum(out / f"gt_{i:04d}.tum", traj, header=f"ground truth base pose, robot {i} of {config.robot} in {config.world}")
        for k, world in enumerate(fleet.worlds):
            save_map(out / f"map_{config.world}_{k}.yaml", occupancy_map(world))
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    return out / "fleet.npz"


def run(args: argparse.Namespace) -> int:
    from jaxquad.sim.fleet import FleetConfig

    if args.robots < 1 or args.worlds < 1:
        raise ValueError("--robots and --worlds must be >= 1")
    config = FleetConfig(
        robot=args.robot,
        world=args.world,
        n_robots=args.robots,
        n_worlds=min(args.worlds, args.robots),
        style=args.style,
        seed=args.seed,
        depth=not args.no_depth,
        width=args.resolution[0],
        height=args.resolution[1],
        randomize=not args.no_randomize,
    )
    path = simulate(config, args.seconds, args.out)
    print(f"wrote {path} and {args.robots} ground-truth TUM file(s), map(s) in {args.out}")
    return 0
