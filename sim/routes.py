"""Collision-free waypoint loops through a world, planned on its inflated ground-truth map.

Cells closer than `robot_radius` to an occupied or unknown cell are blocked. The loop visits the
world's anchors in order (each snapped to the nearest open cell) by shortest paths on the
8-connected grid, whose step cost grows near obstacles so paths keep to the middle of doors and
aisles. The cell path is then shortened by straight shortcuts that never come closer to an
obstacle than the path they replace, and padded with points on its own segments to exactly
`n_waypoints`, so loops of one world kind stack into one batch.
"""

from __future__ import annotations

import numpy as np

from jaxquad.io.maps import OccupancyMap

from .worlds import World, occupancy_map


def clearance(occ: OccupancyMap) -> np.ndarray:
    """(rows, cols) distance (m) from each cell centre to the nearest occupied or unknown cell."""
    from scipy import ndimage

    free = occ.grid == 0
    return ndimage.distance_transform_edt(free) * occ.resolution


def _grid_graph(cost: np.ndarray, open_: np.ndarray):
    from scipy import sparse

    rows, cols = cost.shape
    idx = np.arange(rows * cols).reshape(rows, cols)
    src, dst, w = [], [], []
    for dr, dc in ((0, 1), (1, 0), (1, 1), (1, -1)):
        r0, r1 = max(0, -dr), rows - max(0, dr)
        c0, c1 = max(0, -dc), cols - max(0, dc)
        a = idx[r0:r1, c0:c1]
        b = idx[r0 + dr : r1 + dr, c0 + dc : c1 + dc]
        ok = open_[r0:r1, c0:c1] & open_[r0 + dr : r1 + dr, c0 + dc : c1 + dc]
        step = np.hypot(dr, dc) * 0.5 * (cost[r0:r1, c0:c1] + cost[r0 + dr : r1 + dr, c0 + dc : c1 + dc])
        src.append(a[ok]), dst.append(b[ok]), w.append(step[ok])
    src, dst, w = np.concatenate(src), np.concatenate(dst), np.concatenate(w)
    n = rows * cols
    return sparse.csr_matrix((np.r_[w, w], (np.r_[src, dst], np.r_[dst, src])), shape=(n, n))


def _segment_clearance(clear: np.ndarray, occ: OccupancyMap, a: np.ndarray, b: np.ndarray) -> float:
    n = int(np.ceil(np.linalg.norm(b - a) / (0.5 * occ.resolution))) + 2
    pts = a + np.linspace(0.0, 1.0, n)[:, None] * (b - a)
    rc = occ.world_to_cell(pts)
    return float(np.min(clear[rc[:, 0], rc[:, 1]]))


def _shortcut(path: np.ndarray, cell_clear: np.ndarray, clear: np.ndarray, occ: OccupancyMap, prefer: float):
    out, i = [path[0]], 0
    while i < len(path) - 1:
        j = i + 1
        while j + 1 < len(path):
            need = min(prefer, float(np.min(cell_clear[i : j + 2])))
            if _segment_clearance(clear, occ, path[i], path[j + 1]) < need - 1e-9:
                break
            j += 1
        out.append(path[j])
        i = j
    return np.asarray(out)


def _pad(loop: np.ndarray, n: int) -> np.ndarray:
    """Insert points on the longest segments of the closed loop until it has n vertices."""
    pts = list(loop)
    while len(pts) < n:
        seg = np.linalg.norm(np.roll(np.asarray(pts), -1, axis=0) - np.asarray(pts), axis=1)
        k = int(np.argmax(seg))
        pts.insert(k + 1, 0.5 * (pts[k] + pts[(k + 1) % len(pts)]))
    return np.asarray(pts)


def plan_loop(
    world: World,
    robot_radius: float = 0.35,
    prefer_clearance: float = 0.8,
    n_waypoints: int = 96,
    occ: OccupancyMap | None = None,
) -> np.ndarray:
    """(n_waypoints, 2) closed loop (m, world frame; the last point connects back to the first)."""
    from scipy.sparse import csgraph

    occ = occupancy_map(world) if occ is None else occ
    clear = clearance(occ)
    open_ = clear >= robot_radius + occ.resolution  # one cell of margin for the rasterization
    if not open_.any():
        raise ValueError(f"no cell of the {world.kind} map has {robot_radius} m clearance")
    # Step cost 1 far from obstacles, rising to 4 at the blocking radius.
    cost = 1.0 + 3.0 * np.clip((prefer_clearance - clear) / max(prefer_clearance - robot_radius, 1e-6), 0.0, 1.0)
    graph = _grid_graph(cost, open_)
    open_idx = np.flatnonzero(open_)
    centers = occ.cell_centers().reshape(-1, 2)
    goals = [int(open_idx[np.argmin(np.sum((centers[open_idx] - a) ** 2, axis=1))]) for a in world.anchors]
    _, pred = csgraph.dijkstra(graph, indices=goals, return_predecessors=True)
    legs = []
    for k, g in enumerate(goals):
        nxt = goals[(k + 1) % len(goals)]
        leg, c = [nxt], nxt
        while c != g:
            c = pred[k, c]
            if c < 0:
                raise ValueError(
                    f"{world.kind} world (seed {world.seed}): anchors {k} and {(k + 1) % len(goals)} are not connected"
                )
            leg.append(c)
        cells = leg[::-1]
        # Each leg is shortened on its own, so every anchor stays a vertex of the loop.
        legs.append(_shortcut(centers[cells], clear.reshape(-1)[cells], clear, occ, prefer_clearance)[:-1])
    loop = np.concatenate(legs)
    if len(loop) > n_waypoints:
        raise ValueError(f"route needs {len(loop)} waypoints, more than n_waypoints={n_waypoints}")
    return _pad(loop, n_waypoints)
