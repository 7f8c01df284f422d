"""`jaxquad simulate`: run a fleet and write its log, ground-truth TUM files and world maps."""

from __future__ import annotations

import argparse
import shutil
from pathlib import Path

from jaxquad.cli import add_devices_argument

SUMMARY_KIND = "jaxquad simulate"


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
    parser.add_argument("--robot", default="go2", help="go2, badger, or a path to an MJCF file (default go2)")
    parser.add_argument(
        "--world", default="house", choices=["house", "warehouse"], help="generated world (default house)"
    )
    parser.add_argument("--robots", type=int, default=4, help="number of robots (default 4)")
    parser.add_argument(
        "--worlds", type=int, default=1, help="distinct worlds; robot i walks world i %% worlds (default 1)"
    )
    parser.add_argument(
        "--seconds", type=float, default=10.0, help="simulated time, s, rounded up to whole chunks (default 10)"
    )
    parser.add_argument("--style", default="calm", choices=["calm", "aggressive"], help="gait style (default calm)")
    parser.add_argument(
        "--seed", type=int, default=0, help="random seed of worlds, routes, randomization and noise (default 0)"
    )
    parser.add_argument(
        "--out", required=True, help="output folder (created; replaced only if it holds an earlier simulation)"
    )
    parser.add_argument("--no-depth", action="store_true", help="skip the depth camera (default: record depth)")
    parser.add_argument(
        "--resolution", type=parse_resolution, default=(160, 120), help="depth image WxH, px (default 160x120)"
    )
    parser.add_argument(
        "--no-randomize",
        action="store_true",
        help="nominal masses, friction, motors and noise (default: randomized per robot)",
    )
    add_devices_argument(parser)


def write_fleet(log, folder: str | Path) -> Path:
    """Write a FleetLog into an existing folder: `fleet.npz`, `gt_<i>.tum` per robot,
    `map_<world>_<k>.yaml/.pgm` per world and a `summary.json` naming the configuration."""
    import dataclasses

    import numpy as np

    from jaxquad.io import TumTrajectory, save_log, save_map, write_json, write_tum

    folder, config = Path(folder), log.config
    save_log(folder / "fleet.npz", log)
    t = np.asarray(log["t"])
    for i in range(log.n_robots):
        pose = np.asarray(log["gt_pose"][i], np.float64)
        traj = TumTrajectory(t, pose[:, :3], np.c_[pose[:, 4:7], pose[:, 3:4]])
        write_tum(
            folder / f"gt_{i:04d}.tum",
            traj,
            header=f"ground truth base pose, robot {i} of {config.robot} in {config.world}",
        )
    for k, world_map in enumerate(log.maps()):
        save_map(folder / f"map_{config.world}_{k}.yaml", world_map)
    write_json(
        folder / "summary.json",
        {
            "kind": SUMMARY_KIND,
            "config": dataclasses.asdict(config),
            "samples": int(t.size),
            "fallen": np.asarray(log["fallen"]).tolist(),
        },
    )
    return folder / "fleet.npz"


def simulate(config, seconds: float, out: str | Path, progress: bool = True) -> Path | None:
    """Run the fleet (`jaxquad.sim.rollout`) and write it (`write_fleet`) into the folder `out`.

    The folder is built beside `out` and renamed into place when complete (an earlier simulation
    in `out` is replaced only then), so nothing half-written is ever left at a final path. Chunks
    stream into memory-mapped arrays inside it, so host memory stays bounded. In a multi-process
    run process 0 writes and the others return None.
    """
    from jaxquad import parallel
    from jaxquad.io import atomic_dir, check_output_dir
    from jaxquad.sim.rollout import rollout

    if not (seconds > 0):
        raise ValueError(f"--seconds must be positive, got {seconds}")
    check_output_dir(out, kind=SUMMARY_KIND)
    parallel.initialize()
    if not parallel.is_main():
        rollout(config, seconds, progress=False)
        return None
    with atomic_dir(out) as tmp:
        store = tmp / ".arrays"
        store.mkdir()
        log = rollout(config, seconds, progress, store=store, store_copies=2)  # the arrays, then fleet.npz
        write_fleet(log, tmp)
        del log
        shutil.rmtree(store)
    return Path(out) / "fleet.npz"


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
        devices=args.devices,
    )
    path = simulate(config, args.seconds, args.out)
    if path is not None:
        print(f"wrote {path} and {args.robots} ground-truth TUM file(s), map(s) in {args.out}")
    return 0
