"""What a navigation run is asked to do, drawn on the host (NumPy, seeded): the map the robots navigate
on, a pool of reachable goal poses, start poses, each robot's goal sequence, and its footprint.

Maps come from `MAP_SOURCES` (name -> function of the run's `NavConfig` and its world -> an
`OccupancyMap` in the world frame); "truth" is the world's ground-truth map. A map built by the
variant's SLAM on a route-following walk of the same world (`jaxquad.sim.rollout` with the run's
robot, world, style and seed) is another entry of the same signature.

Poses (starts and goals) are drawn on cells that are free in the navigation map, reachable by the
planner from one another (its largest connected open region) and at least `clearance` from every
box of the true world, with a uniform heading. Consecutive goals of a robot (and its first goal and
its start) are at least `min_separation` apart.
"""

from __future__ import annotations

from typing import Callable

import numpy as np

from jaxquad.io.maps import OccupancyMap
from jaxquad.sim.worlds import World, box_signed_distance, occupancy_map


def truth_map(cfg, world: World) -> OccupancyMap:
    """The world's ground-truth occupancy map (0.05 m cells)."""
    del cfg  # the truth does not depend on how the world would be walked
    return occupancy_map(world)


# name -> (NavConfig, World) -> OccupancyMap in the world frame
MAP_SOURCES: dict[str, Callable[[object, World], OccupancyMap]] = {"truth": truth_map}


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
    ok = open_cells & (occ.grid == 0)
    ok &= box_signed_distance(world, centers) >= clearance
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
