"""What a navigation run is asked to do, drawn on the host (NumPy, seeded): the map the robots navigate
on, a pool of reachable goal poses, start poses, each robot's goal sequence, and its footprint.

Maps come from `MAP_SOURCES` (name -> function of the run's `NavConfig` and its world -> an
`OccupancyMap` in the world frame, on the cells of the world's true map): "truth" is the world's
ground-truth map, "slam" the map the variant's SLAM builds on a route-following walk of the world.

Poses (starts and goals) are drawn on cells that are free in the navigation map (known, below the
map format's free threshold of 0.196), reachable by the planner from one another (its largest
connected open region) and at least `clearance` from every box and the outer walls of the true
world, with a uniform heading. Consecutive goals of a robot (and its first goal and
its start) are at least `min_separation` apart.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from jaxquad.io.maps import OccupancyMap
from jaxquad.sim.worlds import World, box_signed_distance, occupancy_map

FREE_BELOW = 20  # occupancy (0..100) below which a known cell is free: the map format's free_thresh 0.196


def known_free(values):
    """The cells a map (-1 unknown, else occupancy 0..100; NumPy or JAX) calls free: known and below FREE_BELOW."""
    return (values >= 0) & (values < FREE_BELOW)


def truth_map(cfg, world: World) -> OccupancyMap:
    """The world's ground-truth occupancy map (0.05 m cells)."""
    del cfg  # the truth does not depend on how the world would be walked
    return occupancy_map(world)


def slam_map(cfg, world: World) -> OccupancyMap:
    """The map the run's variant builds with the online SLAM (`jaxquad.slam`) on a route-following walk of
    the world, as the paper's authors mapped by teleoperation: one robot of the run's kind and gait
    (`jaxquad.sim.rollout`, same seed: same world) walks `cfg.map_walk_seconds` (default: one lap of its
    loop at 60 % of the route speed) from a waypoint of the loop; the estimator gives the leg-inertial
    odometry and the variant's scans (stabilized or fixed rows); the SLAM adds leg-odometry constraints
    (`preintegrated`) with leg odometry, none (`off`) otherwise. The odometry starts at the walk's true
    first pose, so the map lies in the world frame; it is copied onto the true map's cells (unknown
    where the SLAM map has none)."""
    from jaxquad.estimate.laser import laser_inputs
    from jaxquad.sim import FleetConfig, rollout
    from jaxquad.sim.routes import plan_loop
    from jaxquad.slam import load_params, map_grid, map_max_range, run_fleet, slam_config, to_occupancy_map
    from jaxquad.slam.report import robot_slice

    loop = cfg.loop_config()
    seconds = cfg.map_walk_seconds
    if seconds is None:
        waypoints = plan_loop(world)
        length = float(np.sum(np.linalg.norm(np.roll(waypoints, -1, 0) - waypoints, axis=1)))
        seconds = length / (0.6 * (0.4 if cfg.style == "calm" else 0.8))  # the fleet's route speeds
    walk = FleetConfig(robot=cfg.robot, world=cfg.world, n_robots=1, style=cfg.style, seed=cfg.seed)
    log = rollout(walk, seconds, progress=False)
    values = load_params()
    x = laser_inputs(
        log,
        loop.scans,
        cfg.contacts,
        loop.band_height,
        0.2,
        map_max_range(values),
        None,
        values["leg_yaw_rate_std"],
    )
    grid = map_grid(x, values["resolution"], map_max_range(values))
    spec, params = slam_config(values, grid, "preintegrated" if loop.odometry == "leg" else "off", x["T_base_laser"])
    state, _, _ = run_fleet(spec, params, x)
    built = to_occupancy_map(spec.grid, robot_slice(state, 0).grid)  # robot 0: the walk that built the map
    return resample_map(built, occupancy_map(world))


def resample_map(source: OccupancyMap, like: OccupancyMap) -> OccupancyMap:
    """`source`'s values at the cell centres of `like` (its geometry, yaw 0), -1 outside `source`."""
    rc = source.world_to_cell(like.cell_centers())
    rows, cols = source.grid.shape
    inside = (rc[..., 0] >= 0) & (rc[..., 0] < rows) & (rc[..., 1] >= 0) & (rc[..., 1] < cols)
    grid = np.where(inside, source.grid[np.clip(rc[..., 0], 0, rows - 1), np.clip(rc[..., 1], 0, cols - 1)], -1)
    return OccupancyMap(grid.astype(np.int8), like.resolution, like.origin)


# name -> (NavConfig, World) -> OccupancyMap in the world frame
MAP_SOURCES: dict[str, Callable[[object, World], OccupancyMap]] = {"truth": truth_map, "slam": slam_map}


def reachable_cells(weight: np.ndarray) -> np.ndarray:
    """(rows, cols) bool: the largest 8-connected region of cells the planner may cross (finite weight)."""
    from scipy import ndimage

    labels, n = ndimage.label(np.isfinite(weight), structure=np.ones((3, 3)))
    if n == 0:
        raise ValueError("the navigation map has no open cell")
    sizes = np.bincount(labels.ravel())[1:]
    return labels == 1 + int(np.argmax(sizes))


def draw_poses(
    rng: np.random.Generator, occ: OccupancyMap, open_cells: np.ndarray, world: World, count: int, clearance: float
) -> np.ndarray:
    """(count, 3) poses x, y (m), yaw (rad) on open cells, `clearance` (m) from every box of the world."""
    centers = occ.cell_centers()
    ok = open_cells & known_free(occ.grid)
    ok &= box_signed_distance(world, centers) >= clearance
    # Inside the outer walls too (a map built from scans may show free space leaking through them).
    xmin, ymin, xmax, ymax = world.bounds
    ok &= (centers[..., 0] > xmin + clearance) & (centers[..., 0] < xmax - clearance)
    ok &= (centers[..., 1] > ymin + clearance) & (centers[..., 1] < ymax - clearance)
    rc = np.argwhere(ok)
    if rc.shape[0] == 0:
        raise ValueError(f"no free cell of the {world.kind} map has {clearance} m clearance")
    pick = rc[rng.integers(rc.shape[0], size=count)]
    jitter = rng.uniform(-0.5, 0.5, (count, 2)) * occ.resolution
    xy = centers[pick[:, 0], pick[:, 1]] + jitter
    return np.column_stack([xy, rng.uniform(-np.pi, np.pi, count)])


def missions(
    rng: np.random.Generator, pool: np.ndarray, starts: np.ndarray, n_goals: int, min_separation: float
) -> np.ndarray:
    """(N, n_goals) indices into `pool` (K, 3): each robot's goals in turn, consecutive ones (and the first
    and the robot's start) at least `min_separation` (m) apart."""
    n, k = starts.shape[0], pool.shape[0]
    out = np.zeros((n, n_goals), np.int32)
    for i in range(n):
        here = starts[i, :2]
        for g in range(n_goals):
            far = np.flatnonzero(np.hypot(*(pool[:, :2] - here).T) >= min_separation)
            if far.size == 0:
                raise ValueError(f"no goal of the pool of {k} lies {min_separation} m from {here.tolist()}")
            out[i, g] = far[rng.integers(far.size)]
            here = pool[out[i, g], :2]
    return out


def footprint(robot) -> tuple[np.ndarray, np.ndarray]:
    """The robot's planform at its home pose (every geom's bounding box, legs included), as a rectangle
    in the base frame: its centre (2,) and half length and width (2,), m."""
    import mujoco

    m = robot.mj_model
    d = mujoco.MjData(m)
    d.qpos[:] = robot.qpos_home
    a = robot.base_qpos_adr
    d.qpos[a : a + 7] = [0.0, 0.0, d.qpos[a + 2], 1.0, 0.0, 0.0, 0.0]
    mujoco.mj_kinematics(m, d)
    mine = np.flatnonzero(m.body_rootid[m.geom_bodyid] == robot.base_body_id)
    signs = np.array([[sx, sy, sz] for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)], float)
    corners = []
    for g in mine:
        local = m.geom_aabb[g, :3] + signs * m.geom_aabb[g, 3:]
        corners.append(d.geom_xpos[g] + local @ d.geom_xmat[g].reshape(3, 3).T)
    xy = np.concatenate(corners)[:, :2]
    lo, hi = xy.min(axis=0), xy.max(axis=0)
    return (lo + hi) / 2, (hi - lo) / 2
