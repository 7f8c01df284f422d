"""The online SLAM's heading on synthetic warehouse walks, with and without wall-heading priors.

    python experiments/heading_replay.py [--robots 4] [--seconds 60] [--seed 0]
        [--variants belief measurement none] [--params slam.yaml] [--json rows.json]

No legs, no planner: each robot walks a drawn warehouse (`jaxquad.sim.worlds`, seed 1000 * seed + robot) on a
scripted path (a turn in place at 0.6 rad/s for 10.5 s, then 0.2 m/s in 2.1 s of every 3 s, turning at random
and away from boxes and walls), so a SLAM setting is compared on the same inputs without the simulator's cost.
Each 0.1 s it gets a level scan (160 beams over +-0.75 rad, `--scan-height` above the floor, cast at the true
pose by `kernels.raycast`, range noise 1 % of r^2, no return beyond 8 m) and an odometry pose whose steps are
the true body-frame steps (+ 2 mm noise) turned by a heading that drifts as the simulated IMU's yaw does (a
random walk of `SensorNoise.default().yaw_walk` times a per-robot factor drawn in 0.5-1.5). The SLAM runs
with exploration's settings (`ExploreConfig(world="warehouse").slam_values()`) and preintegrated
leg-odometry constraints (a `--params` file overrides any of them for every variant), one variant at a time:

  belief       wall-heading priors gated on the heading's own variance (the default)
  measurement  priors gated with the measurement's variance R counted too (`wall_heading_gate_with_r: 1`)
  none         no priors

It prints the command, the machine and one Markdown row per variant: robots; runs whose heading error ever
passed 4 deg ("runaways") and the median time that first happened; runs lost (position error above 0.5 m for
more than 2 s in all); the median over runs of the final and of the largest heading error; the odometry's
median final heading error; loops closed and heading priors used per run (means).
"""

from __future__ import annotations

import argparse
import os
import platform
import shlex
import sys
import time

import numpy as np

DT = 0.1  # s between scans
BEARINGS = np.linspace(0.75, -0.75, 160)  # rad, left to right
MAX_RANGE_M = 8.0
VARIANTS = {
    "belief": {"wall_heading": 1, "wall_heading_gate_with_r": 0},
    "measurement": {"wall_heading": 1, "wall_heading_gate_with_r": 1},
    "none": {"wall_heading": 0},
}
RUNAWAY_DEG = 4.0
LOST_M, LOST_S = 0.5, 2.0


def walk(world, rng: np.random.Generator, seconds: float) -> np.ndarray:
    """True base poses (S, 3) of one scripted walk (see the module docstring)."""
    from jaxquad.sim.worlds import box_signed_distance

    while True:
        p = np.array([rng.uniform(1, 14), rng.uniform(1, 19)])
        if box_signed_distance(world, p[None])[0] > 0.75:
            break
    th = target = rng.uniform(-np.pi, np.pi)
    poses = []
    for k in range(round(seconds / DT)):
        t = k * DT
        if t < 10.5:
            th += 0.6 * DT
        else:
            if rng.random() < 0.02:
                target = th + rng.normal(0, 1.0)
            th += np.clip(target - th, -0.08, 0.08)
            speed = 0.2 if (t % 3.0) < 2.1 else 0.0
            q = p + speed * DT * np.array([np.cos(th), np.sin(th)])
            inside = 0.6 < q[0] < 14.4 and 0.6 < q[1] < 19.4
            if box_signed_distance(world, q[None])[0] < 0.55 or not inside:
                target = th + np.pi / 2 * rng.choice([-1, 1])
            else:
                p = q
        poses.append([*p, th])
    return np.array(poses)


def drifting_odometry(truth: np.ndarray, rng: np.random.Generator, yaw_walk: float) -> np.ndarray:
    """Odometry poses (S, 3): the true body-frame steps (+ 2 mm noise) integrated with a heading that is the
    truth plus a random walk of `yaw_walk` rad per sqrt(s)."""
    S = len(truth)
    drift = np.concatenate([[0.0], np.cumsum(rng.normal(0, yaw_walk * np.sqrt(DT), S - 1))])
    c, s = np.cos(truth[:-1, 2]), np.sin(truth[:-1, 2])
    d = truth[1:, :2] - truth[:-1, :2]
    body = np.stack([c * d[:, 0] + s * d[:, 1], -s * d[:, 0] + c * d[:, 1]], 1) + rng.normal(0, 0.002, (S - 1, 2))
    heading = truth[:, 2] + drift
    ck, sk = np.cos(heading[:-1]), np.sin(heading[:-1])
    step = np.stack([ck * body[:, 0] - sk * body[:, 1], sk * body[:, 0] + ck * body[:, 1]], 1)  # in the odometry frame
    odom = np.array(truth, np.float64)
    odom[1:, :2] = truth[0, :2] + np.cumsum(step, axis=0)
    odom[:, 2] = heading
    return odom


def inputs(robots: int, seconds: float, seed: int, scan_height: float) -> tuple[dict, np.ndarray]:
    """The SLAM's fleet inputs (`jaxquad.slam.run_fleet`'s dict) and the true poses (N, S, 3)."""
    import jax
    import jax.numpy as jnp

    from jaxquad.kernels import Boxes
    from jaxquad.kernels.raycast import ray_distance
    from jaxquad.sim.sensors import SensorNoise
    from jaxquad.sim.worlds import make_world

    rng = np.random.default_rng(seed)
    yaw_walk = float(SensorNoise.default().yaw_walk)

    @jax.jit
    def cast(boxes, poses):
        def one(pose):
            a = pose[2] + jnp.asarray(BEARINGS, jnp.float32)
            d = jnp.stack([jnp.cos(a), jnp.sin(a), jnp.zeros_like(a)], -1)
            return ray_distance(jnp.stack([pose[0], pose[1], jnp.asarray(scan_height, jnp.float32)]), d, boxes)

        return jax.vmap(one)(poses)

    truths, odoms, ranges = [], [], []
    for i in range(robots):
        world = make_world("warehouse", 1000 * seed + i)
        # Padded with empty boxes far under the floor (never hit) to a multiple of 64: one compile for most worlds.
        pad = -len(world.yaw) % 64
        center = np.concatenate([world.center, np.tile([0.0, 0.0, -100.0], (pad, 1))])
        half = np.concatenate([world.half, np.zeros((pad, 3))])
        yaw = np.concatenate([world.yaw, np.zeros(pad)])
        boxes = Boxes(*(jnp.asarray(a, jnp.float32) for a in (center, half, yaw)))
        truth = walk(world, rng, seconds)
        odoms.append(drifting_odometry(truth, rng, yaw_walk * rng.uniform(0.5, 1.5)))
        r = np.asarray(cast(boxes, jnp.asarray(truth, jnp.float32)), np.float64)
        r = np.where(
            r <= MAX_RANGE_M, r + 0.01 * np.minimum(r, MAX_RANGE_M) ** 2 * rng.standard_normal(r.shape), np.inf
        )
        truths.append(truth)
        ranges.append(r)
    n, S = robots, len(truths[0])
    odom = np.array(odoms)
    x = {
        "t": np.arange(S) * DT,
        "odom": odom,
        "lo_pose": odom,
        "ranges": np.array(ranges, np.float32),
        "bearings": BEARINGS,
        "T_base_laser": np.zeros(3),
        "valid": np.ones((n, S), bool),
        "lo_twist": np.zeros((n, S, 3)),
        "lo_twist_cov": np.broadcast_to(np.diag([1e-3, 1e-3, 4e-4]), (n, S, 3, 3)),
        "lo_valid": np.ones((n, S), bool),
    }
    return x, np.array(truths)


def heading_error_deg(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """|a - b| wrapped to [0, 180] deg, in float64 (`kernels.lie.wrap_angle` is float32 where x64 is off)."""
    return np.rad2deg(np.abs((a - b + np.pi) % (2 * np.pi) - np.pi))


def score(variant: str, state, out, x: dict, truths: np.ndarray, wall_s: float) -> dict:
    """One table row from a variant's run (see the module docstring)."""
    pose = np.asarray(out.pose, np.float64)
    heading = heading_error_deg(pose[..., 2], truths[..., 2])
    position = np.linalg.norm(pose[..., :2] - truths[..., :2], axis=-1)
    runaway = heading.max(axis=1) > RUNAWAY_DEG
    first = np.argmax(heading > RUNAWAY_DEG, axis=1) * DT
    return {
        "variant": variant,
        "robots": int(len(truths)),
        "runaways": int(runaway.sum()),
        "runaway_first_s_median": float(np.median(first[runaway])) if runaway.any() else None,
        "lost": int(((position > LOST_M).sum(axis=1) * DT > LOST_S).sum()),
        "heading_final_deg_median": float(np.median(heading[:, -1])),
        "heading_max_deg_median": float(np.median(heading.max(axis=1))),
        "odometry_heading_final_deg_median": float(np.median(heading_error_deg(x["odom"][:, -1, 2], truths[:, -1, 2]))),
        "position_final_m_median": float(np.median(position[:, -1])),
        "loops_mean": float(np.mean(state.loops)),
        "priors_mean": float(np.mean(state.headings)),
        "wall_s": wall_s,
    }


def run(args) -> list[dict]:
    from jaxquad.cli import progress_bar
    from jaxquad.explore.config import ExploreConfig
    from jaxquad.slam import grid_spec, map_max_range, run_fleet, slam_config

    x, truths = inputs(args.robots, args.seconds, args.seed, args.scan_height)
    base = ExploreConfig(world="warehouse", seconds=args.seconds, slam_params=args.params).slam_values()
    grid = grid_spec((-0.5, -0.5, 15.5, 20.5), base["resolution"], map_max_range(base))
    rows = []
    for variant in args.variants:
        spec, params = slam_config(base | VARIANTS[variant], grid, "preintegrated")
        t0 = time.perf_counter()
        with progress_bar(variant, "scan") as progress:
            _, out, state = run_fleet(spec, params, x, progress)
        rows.append(score(variant, state, out, x, truths, time.perf_counter() - t0))
    return rows


def table(rows: list[dict]) -> str:
    lines = [
        "| variant | robots | runaways (> 4 deg) | first at (median s) | lost | heading final / largest deg (medians) "
        "| odometry heading final deg | position final m | loops | priors |",
        "|---|---:|---:|---:|---:|---|---:|---:|---:|---:|",
    ]
    for r in rows:
        first = "-" if r["runaway_first_s_median"] is None else f"{r['runaway_first_s_median']:.0f}"
        lines.append(
            f"| {r['variant']} | {r['robots']} | {r['runaways']} | {first} | {r['lost']} "
            f"| {r['heading_final_deg_median']:.2f} / {r['heading_max_deg_median']:.2f} "
            f"| {r['odometry_heading_final_deg_median']:.2f} | {r['position_final_m_median']:.3f} "
            f"| {r['loops_mean']:.1f} | {r['priors_mean']:.0f} |"
        )
    return "\n".join(lines)


def add_walk_arguments(p: argparse.ArgumentParser, robots: int) -> None:
    """--robots, --seconds and --seed: the walks (this script's and heading_association.py's)."""
    p.add_argument("--robots", type=int, default=robots, help="walks (robots)")
    p.add_argument("--seconds", type=float, default=60.0, help="simulated time of each walk (s)")
    p.add_argument("--seed", type=int, default=0, help="draws the worlds (1000 * seed + robot), walks and noise")


def check_walk_arguments(p: argparse.ArgumentParser, args) -> None:
    """One line, before any work, for walks that cannot be drawn."""
    if args.robots < 1 or args.seconds < 12.0:
        p.error("--robots must be at least 1 and --seconds at least 12 (the walk turns in place for 10.5 s)")
    if args.seed < 0:
        p.error(f"--seed must be >= 0, got {args.seed}")


def main(argv=None) -> None:
    p = argparse.ArgumentParser(
        description=__doc__.split("\n\n")[0], formatter_class=argparse.ArgumentDefaultsHelpFormatter
    )
    add_walk_arguments(p, robots=4)
    p.add_argument("--scan-height", type=float, default=0.32, help="height of the level scan plane (m)")
    p.add_argument(
        "--variants",
        nargs="+",
        choices=list(VARIANTS),
        default=list(VARIANTS),
        help="belief: priors gated on the heading's variance; measurement: R counted too; none: no priors",
    )
    p.add_argument("--params", help="SLAM parameter file over jaxquad/slam/slam.yaml, for every variant")
    p.add_argument("--json", help="write the rows here as JSON")
    args = p.parse_args(argv)
    check_walk_arguments(p, args)
    if not args.scan_height > 0:
        p.error(f"--scan-height must be > 0 m, got {args.scan_height}")
    if args.json and not os.access(os.path.dirname(os.path.abspath(args.json)), os.W_OK):
        p.error(f"--json {args.json}: its folder is not writable")
    if args.params:
        from jaxquad.slam import load_params

        try:  # a missing or bad file: one line before the walks are drawn
            load_params(args.params)
        except (ValueError, OSError) as e:
            p.error(str(e))
    import jax

    print(f"command: python {shlex.join(['experiments/heading_replay.py', *(argv or sys.argv[1:])])}")
    machine = platform.processor() or platform.machine()
    print(f"machine: {platform.node()} {machine}, jax {jax.__version__} on {jax.default_backend()}")
    rows = run(args)
    print(table(rows))
    if args.json:
        from jaxquad.io import write_json

        write_json(args.json, rows)


if __name__ == "__main__":
    main()
