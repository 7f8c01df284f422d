"""How a scan ray's range is taken from its band of pixel rows (the band's minimum against the median), and
what the map's inverse sensor model makes of the scans.

    python experiments/scan_band.py [--robot go2] [--world house] [--robots 2] [--seconds 40] [--seed 0]
        [--map-models 0.7/0.4 0.8/0.35 0.8/0.3] [--hit-offsets 0 0.5 1] [--clamp-mins 0.1192 0.05] [--scan-every 1]

It simulates a fleet with depth (aggressive gait, in memory), runs the estimator with true contacts,
and slices stabilized scans three ways: a 5-row band reduced by its minimum (the paper's rule, ROS
depthimage_to_laserscan's), a 1-row band, and a 5-row band reduced by its median. Two tables
(Markdown, stdout):

- the range error against the true map by true range (every 10th frame of robot 0): each beam's
  true range is marched on the true map from the true laser pose in steps of 0.01 m;
- the map of each kind drawn from the true laser poses (`jaxquad.kernels.occupancy`, readings beyond
  8 m as no-returns) scored against the true map (`jaxquad.metrics.map_scores`, in view of the true
  path), mean over robots: the scans' own error, with no pose error in it;
- with --map-models HIT/MISS ...: maps drawn with each inverse sensor model (`occupancy_hit_probability` /
  `occupancy_miss_probability`) from the 5-row median scans out to 8 m (what `jaxquad slam` maps) and from
  the 1-row scans out to 4 m (what exploration maps), at the true laser poses and at the leg-inertial
  odometry's: precision, in-view IoU and recall, and `free seen`, the share of the true free cells that
  the rays from the true path crossed which the map calls free (below occupancy 0.196; what exploration's
  coverage counts). Mean over robots. With --hit-offsets, each model's maps for each hit offset
  (a return's end cell taken that many cells beyond it along the ray; slam.yaml's `occupancy_hit_offset_cells`),
  with --clamp-mins for each lower clamp of a cell's occupancy (`occupancy_clamp_min_probability`; the upper
  stays OctoMap's 0.971), and with --scan-every N from every Nth depth frame (frames come at 31.25 Hz; the online
  SLAM draws its map from its node scans, about 2 per second while the robot walks: N = 16)
"""

from __future__ import annotations

import argparse
import math
import platform
import sys

import jax
import jax.numpy as jnp
import numpy as np

KINDS = (("5 rows, minimum (the paper's rule)", 5, "min"), ("1 row", 1, "min"), ("5 rows, median", 5, "median"))
RANGE_BINS = ((0, 1), (1, 2), (2, 3), (3, 4), (4, 5), (5, 6), (6, 8))


def _true_ranges(truth, pose: np.ndarray, bearings: np.ndarray, range_max: float = 10.0) -> np.ndarray:
    """Range (m) to the first occupied cell of `truth` along each beam from `pose` (x y yaw), inf if none."""
    steps = np.arange(0.0, range_max, 0.01)
    a = pose[2] + bearings
    xy = pose[None, None, :2] + np.stack([np.cos(a), np.sin(a)], -1)[:, None] * steps[None, :, None]
    rc = truth.world_to_cell(xy)
    rows, cols = truth.grid.shape
    inside = (rc[..., 0] >= 0) & (rc[..., 0] < rows) & (rc[..., 1] >= 0) & (rc[..., 1] < cols)
    hit = np.zeros(inside.shape, bool)
    hit[inside] = truth.grid[rc[inside][:, 0], rc[inside][:, 1]] > 65
    return np.where(hit.any(1), steps[hit.argmax(1)], np.inf)


def main() -> int:
    from jaxquad.slam.params import load_params

    clamp_min = load_params()["occupancy_clamp_min_probability"]
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--robot", choices=("go2", "badger"), default="go2", help="robot (default go2)")
    p.add_argument("--world", choices=("house", "warehouse"), default="house", help="world (default house)")
    p.add_argument("--robots", type=int, default=2, help="robots in the fleet (default 2)")
    p.add_argument("--seconds", type=float, default=40.0, help="simulated time, s (default 40)")
    p.add_argument("--seed", type=int, default=0, help="simulation seed (default 0)")
    p.add_argument(
        "--map-models",
        nargs="+",
        default=[],
        metavar="HIT/MISS",
        help="inverse sensor models to compare, e.g. 0.8/0.35 (slam.yaml's) 0.8/0.3 (default: none)",
    )
    p.add_argument(
        "--hit-offsets",
        nargs="+",
        type=float,
        default=[0.0],
        metavar="CELLS",
        help="with --map-models: the hit offsets to compare, in cells, 0-1 (default 0)",
    )
    p.add_argument(
        "--clamp-mins",
        nargs="+",
        type=float,
        default=[clamp_min],
        metavar="P",
        help=f"with --map-models: the lower clamps of a cell's occupancy to compare, 0-MISS (default {clamp_min:.4g}: "
        "slam.yaml's, OctoMap's)",
    )
    p.add_argument(
        "--scan-every",
        type=int,
        default=1,
        metavar="N",
        help="with --map-models: maps from every Nth depth frame (default 1; 16: about the online SLAM's node rate)",
    )
    args = p.parse_args()
    if args.scan_every < 1:
        p.error(f"--scan-every must be >= 1, got {args.scan_every}")
    if not all(0.0 <= h <= 1.0 for h in args.hit_offsets):
        p.error(f"--hit-offsets must lie in [0, 1] cells, got {args.hit_offsets}")
    if args.robots < 1 or not args.seconds > 0:
        p.error("--robots must be >= 1 and --seconds positive")
    try:
        models = [tuple(float(v) for v in m.split("/")) for m in args.map_models]
    except ValueError:
        p.error(f"--map-models takes HIT/MISS probabilities such as 0.8/0.35, got {args.map_models}")
    if any(len(m) != 2 or not (0.5 < m[0] < 1.0 and 0.0 < m[1] < 0.5) for m in models):
        p.error(f"--map-models: each HIT/MISS needs 0.5 < HIT < 1 and 0 < MISS < 0.5, got {args.map_models}")
    if any(not 0.0 < c < m[1] for c in args.clamp_mins for m in models):
        p.error(f"--clamp-mins must lie in (0, MISS) of every model, got {args.clamp_mins}")
    from jaxquad.estimate import estimate_log
    from jaxquad.estimate.laser import leg_laser_inputs, scan_ranges
    from jaxquad.kernels.lie import se2, xy_theta
    from jaxquad.kernels.occupancy import OccupancyParams
    from jaxquad.metrics import cells_in_view, map_scores
    from jaxquad.sim.fleet import FleetConfig
    from jaxquad.sim.rollout import rollout
    from jaxquad.slam.mapping import fleet_maps, grid_spec_like, to_occupancy_map

    print(f"command: python {' '.join(sys.argv)}")
    print(f"machine: {platform.node()}, {jax.devices()[0].device_kind} ({jax.default_backend()})\n")
    config = FleetConfig(
        robot=args.robot,
        world=args.world,
        n_robots=args.robots,
        n_worlds=1,
        style="aggressive",
        seed=args.seed,
        depth=True,
    )
    log = rollout(config, args.seconds, progress=True)
    truth = log.maps()[0]
    _, _, est = estimate_log(log, "truth")
    x = leg_laser_inputs(log, est, "stabilized", 5, 0.2, 8.0, band_reduce="min")
    T = se2(jnp.asarray(x["gt"], jnp.float32)) @ se2(jnp.asarray(x["T_base_laser"], jnp.float32))
    laser = np.asarray(xy_theta(T))  # (N, F, 3) true laser poses
    scans = {name: scan_ranges(log, est, "stabilized", h, 0.2, 8.0, reduce) for name, h, reduce in KINDS}

    errors = {}
    for name, (ranges, bearings) in scans.items():
        err, true = [], []
        for f in range(0, ranges.shape[1], 10):
            t = _true_ranges(truth, laser[0, f], bearings)
            ok = np.isfinite(ranges[0, f]) & np.isfinite(t)
            err.append(ranges[0, f][ok] - t[ok])
            true.append(t[ok])
        errors[name] = (np.concatenate(err), np.concatenate(true))
    print("| true range m | " + " | ".join(f"{n}: mean error m" for n, _, _ in KINDS) + " |")
    print("|---|" + "---:|" * len(KINDS))
    for lo, hi in RANGE_BINS:
        cells = []
        for name, _, _ in KINDS:
            e, t = errors[name]
            m = (t >= lo) & (t < hi)
            cells.append(f"{e[m].mean():+.3f} (n {m.sum()})" if m.any() else "-")
        print(f"| {lo}-{hi} | " + " | ".join(cells) + " |")

    spec = grid_spec_like(truth, 10.0)
    occ = OccupancyParams(range_max=jnp.asarray(8.0))
    in_view = [cells_in_view(truth, laser[i], scans[KINDS[0][0]][1], 8.0) for i in range(args.robots)]
    print("\n| band | map precision | map IoU | IoU in view |\n|---|---:|---:|---:|")
    for name, (ranges, bearings) in scans.items():
        grids = fleet_maps(spec, occ, jnp.asarray(laser, jnp.float32), jnp.asarray(ranges), jnp.asarray(bearings))
        s = [
            map_scores(to_occupancy_map(spec, jax.tree.map(lambda a, i=i: a[i], grids)), truth, in_view[i])
            for i in range(args.robots)
        ]
        mean = lambda key, s=s: np.mean([getattr(v, key) for v in s])  # noqa: E731
        print(f"| {name} | {mean('precision'):.2f} | {mean('iou'):.2f} | {mean('iou_in_view'):.2f} |")
    if models:
        T_odom = se2(jnp.asarray(x["odom"], jnp.float32)) @ se2(jnp.asarray(x["T_base_laser"], jnp.float32))
        poses = {"true": laser, "leg odometry": np.asarray(xy_theta(T_odom))}
        every = slice(None, None, args.scan_every)
        poses = {kind: laser_poses[:, every] for kind, laser_poses in poses.items()}
        median_scans, row_scans = ((r[:, every], b) for r, b in (scans[KINDS[2][0]], scans[KINDS[1][0]]))
        _map_models(models, args.hit_offsets, args.clamp_mins, truth, spec, poses, median_scans, row_scans)
    return 0


def _map_models(models, offsets, clamp_mins, truth, spec, poses: dict, median_scans, row_scans) -> None:
    """The third table (module docstring): each model's maps at each kind of pose, for both scan uses."""
    from jaxquad.io.maps import FREE_THRESH
    from jaxquad.kernels.occupancy import OccupancyParams
    from jaxquad.metrics import cells_in_view, map_scores
    from jaxquad.slam.mapping import fleet_maps, to_occupancy_map

    logit = lambda q: jnp.asarray(math.log(q / (1.0 - q)))  # noqa: E731
    true_free = (truth.grid >= 0) & (truth.grid < 100 * FREE_THRESH)
    print(
        "\n| scans | map range m | hit / miss | hit offset cells | clamp min | poses | precision | IoU in view "
        "| recall in view | free seen |"
    )
    print("|---|---:|---|---:|---:|---|---:|---:|---:|---:|")
    for label, (ranges, bearings), map_range in (("5 rows, median", median_scans, 8.0), ("1 row", row_scans, 4.0)):
        n = ranges.shape[0]
        in_view = [cells_in_view(truth, poses["true"][i], bearings, map_range) for i in range(n)]
        # The true free cells that rays from the true path crossed (with no hit offset): one set for every model.
        crossed = true_free & np.asarray(
            fleet_maps(
                spec,
                OccupancyParams(range_max=jnp.asarray(map_range)),
                jnp.asarray(poses["true"], jnp.float32),
                jnp.asarray(ranges),
                jnp.asarray(bearings),
            ).observed
        )
        for (hit, miss), offset, clamp in ((m, o, c) for m in models for o in offsets for c in clamp_mins):
            params = OccupancyParams(
                l_free=logit(miss),
                l_occ=logit(hit),
                l_min=logit(clamp),
                range_max=jnp.asarray(map_range),
                hit_offset=jnp.asarray(offset * spec.resolution),
            )
            for kind, laser in poses.items():
                grids = fleet_maps(
                    spec, params, jnp.asarray(laser, jnp.float32), jnp.asarray(ranges), jnp.asarray(bearings)
                )
                rows = []
                for i in range(n):
                    occ = to_occupancy_map(spec, jax.tree.map(lambda a, i=i: a[i], grids))
                    s = map_scores(occ, truth, in_view[i])
                    free = (occ.grid >= 0) & (occ.grid < 100 * FREE_THRESH)
                    seen_free = (free & crossed[i]).sum() / max(crossed[i].sum(), 1)
                    rows.append((s.precision, s.iou_in_view, s.recall_in_view, seen_free))
                m = np.mean(rows, 0)
                print(
                    f"| {label} | {map_range:g} | {hit:g} / {miss:g} | {offset:g} | {clamp:.4g} | {kind} | {m[0]:.3f} "
                    f"| {m[1]:.3f} | {m[2]:.3f} | {m[3]:.3f} |",
                    flush=True,
                )


if __name__ == "__main__":
    sys.exit(main())
