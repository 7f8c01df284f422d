"""Seeded generators of static box worlds: a furnished three-room `house` and a `warehouse` hall.

A world is a set of boxes standing on the floor plane z = 0 (each rotated about z only), the
rectangle its outer walls enclose, and a loop of anchor points through its rooms or aisles that
the route planner visits in order. Every world of one kind has the same number of boxes, so N
different worlds stack into one batch for the depth caster.

The boxes are obstacles for the camera and the map only: they are not put into the physics model
(only the feet and the floor collide there). Robots walk collision-free routes planned on the
inflated ground-truth map; the fleet runner flags a robot whose base enters a box footprint.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from jaxquad.io.maps import OccupancyMap

KINDS = ("house", "warehouse")
_WALL_T = 0.12  # wall thickness, m
_HOUSE_WALL_H, _HALL_WALL_H = 2.5, 4.0  # m, both well above any camera
_DOOR = 1.2  # door gap width, m


@dataclasses.dataclass(frozen=True)
class World:
    kind: str
    seed: int
    center: np.ndarray  # (B, 3) box centres, world frame, m
    half: np.ndarray  # (B, 3) half extents along the box axes, m
    yaw: np.ndarray  # (B,) rad about z
    bounds: tuple[float, float, float, float]  # xmin, ymin, xmax, ymax of the walls' outer faces, m
    anchors: np.ndarray  # (A, 2) loop through the rooms, visited in order, m

    @property
    def n_boxes(self) -> int:
        return self.center.shape[0]


class _Boxes:
    """Accumulates boxes; `fits` rejects a footprint overlapping any box or keep-out region."""

    def __init__(self):
        self.center, self.half, self.yaw = [], [], []
        self.keep_out: list[tuple[float, float, float, float]] = []
        self.n_walls = 0  # pieces are placed against walls, so `fits` checks only later boxes

    def add(self, x, y, sx, sy, h, yaw=0.0):
        self.center.append((x, y, h / 2))
        self.half.append((sx / 2, sy / 2, h / 2))
        self.yaw.append(yaw)

    def wall(self, x0, y0, x1, y1, h):
        """Axis-aligned wall segment between two points on its centre line."""
        self.add((x0 + x1) / 2, (y0 + y1) / 2, abs(x1 - x0) + _WALL_T, abs(y1 - y0) + _WALL_T, h)

    def fits(self, x, y, sx, sy, yaw, clearance) -> bool:
        c, s = abs(np.cos(yaw)), abs(np.sin(yaw))
        ex, ey = (c * sx + s * sy) / 2 + clearance, (s * sx + c * sy) / 2 + clearance
        placed = slice(self.n_walls, None)
        for (cx, cy, _), (hx, hy, _), byaw in zip(self.center[placed], self.half[placed], self.yaw[placed]):
            bc, bs = abs(np.cos(byaw)), abs(np.sin(byaw))
            bx, by = bc * hx + bs * hy, bs * hx + bc * hy
            if abs(x - cx) < ex + bx and abs(y - cy) < ey + by:
                return False
        return all(not (abs(x - kx) < ex + kw and abs(y - ky) < ey + kh) for kx, ky, kw, kh in self.keep_out)

    def place_along_wall(self, rng, room, size, h, clearance=0.15, tries=200):
        """Put a (length, depth) piece against a random wall of `room` = (x0, y0, x1, y1)."""
        x0, y0, x1, y1 = room
        inner = _WALL_T / 2 + 0.02
        for _ in range(tries):
            side = rng.integers(4)
            length, depth = size
            if side < 2:  # along a horizontal wall (bottom, top)
                sx, sy = length, depth
                x = rng.uniform(x0 + inner + sx / 2, x1 - inner - sx / 2)
                y = y0 + inner + sy / 2 if side == 0 else y1 - inner - sy / 2
            else:
                sx, sy = depth, length
                y = rng.uniform(y0 + inner + sy / 2, y1 - inner - sy / 2)
                x = x0 + inner + sx / 2 if side == 2 else x1 - inner - sx / 2
            if self.fits(x, y, sx, sy, 0.0, clearance):
                self.add(x, y, sx, sy, h)
                return
        raise RuntimeError("furniture placement failed")  # layouts leave ample room; a bug if hit

    def place_free(self, rng, region, size, h, clearance, yaw_range=0.0, tries=2000):
        x0, y0, x1, y1 = region
        for _ in range(tries):
            yaw = rng.uniform(-yaw_range, yaw_range)
            x, y = rng.uniform(x0, x1), rng.uniform(y0, y1)
            if self.fits(x, y, size[0], size[1], yaw, clearance):
                self.add(x, y, size[0], size[1], h, yaw)
                return
        raise RuntimeError("obstacle placement failed")


def _house(rng: np.random.Generator) -> tuple[_Boxes, tuple, np.ndarray]:
    w, d = 10.0, 8.0
    a = rng.uniform(4.5, 5.5)  # living room | bedrooms
    b = rng.uniform(3.5, 4.5)  # bedroom 1 (bottom) | bedroom 2 (top)
    h = _HOUSE_WALL_H
    bx = _Boxes()
    for x0, y0, x1, y1 in ((0, 0, w, 0), (0, d, w, d), (0, 0, 0, d), (w, 0, w, d)):
        bx.wall(x0, y0, x1, y1, h)
    # Wall x = a with a door into each bedroom; wall y = b (bedrooms) with one door.
    g1 = rng.uniform(1.0, b - 1.0 - _DOOR)
    g2 = rng.uniform(b + 1.0, d - 1.0 - _DOOR)
    bx.wall(a, 0, a, g1, h), bx.wall(a, g1 + _DOOR, a, g2, h), bx.wall(a, g2 + _DOOR, a, d, h)
    g3 = rng.uniform(a + 1.0, w - 1.0 - _DOOR)
    bx.wall(a, b, g3, b, h), bx.wall(g3 + _DOOR, b, w, b, h)
    # Keep doorways (and a corridor of 1 m each side) clear of furniture.
    bx.keep_out += [(a, g1 + _DOOR / 2, 1.1, _DOOR / 2 + 0.3), (a, g2 + _DOOR / 2, 1.1, _DOOR / 2 + 0.3)]
    bx.keep_out += [(g3 + _DOOR / 2, b, _DOOR / 2 + 0.3, 1.1)]
    bx.n_walls = len(bx.center)
    living, bed1, bed2 = (0, 0, a, d), (a, 0, w, b), (a, b, w, d)
    bx.place_along_wall(rng, living, (2.0, 0.9), 0.8)  # sofa
    bx.place_along_wall(rng, living, (1.2, 0.4), 1.8)  # shelf
    bx.place_along_wall(rng, living, (1.0, 0.4), 1.6)  # shelf
    bx.place_along_wall(rng, living, (1.6, 0.9), 0.75)  # dining table
    for room in (bed1, bed2):
        bx.place_along_wall(rng, room, (1.6, 2.0), 0.5)  # bed, head against a wall
        bx.place_along_wall(rng, room, (1.0, 0.6), 2.0)  # wardrobe
        bx.place_along_wall(rng, room, (0.45, 0.4), 0.5)  # nightstand
    # Coffee table free in the living room, any heading, away from the route through the middle.
    bx.place_free(rng, (1.0, 1.0, a - 1.0, d - 1.0), (1.0, 0.6), 0.45, clearance=0.7, yaw_range=np.pi)
    # The loop visits the most open point of each room.
    boxes = (np.asarray(bx.center), np.asarray(bx.half), np.asarray(bx.yaw))
    anchors = np.array([_most_open(boxes, room) for room in (living, bed1, bed2)])
    return bx, (0.0, 0.0, w, d), anchors


def _warehouse(rng: np.random.Generator) -> tuple[_Boxes, tuple, np.ndarray]:
    w, d = 15.0, 20.0
    h = _HALL_WALL_H
    bx = _Boxes()
    for x0, y0, x1, y1 in ((0, 0, w, 0), (0, d, w, d), (0, 0, 0, d), (w, 0, w, d)):
        bx.wall(x0, y0, x1, y1, h)
    bx.n_walls = len(bx.center)
    # Three rows of racks (long axis along y) split by a cross aisle, leaving 2.5 m perimeter aisles.
    xs = np.array([4.0, 7.5, 11.0]) + rng.uniform(-0.3, 0.3, 3)
    y_aisle = d / 2 + rng.uniform(-1.5, 1.5)
    for x in xs:
        for y0, y1 in ((3.0, y_aisle - 1.2), (y_aisle + 1.2, d - 3.0)):
            shorten = rng.uniform(0.0, 0.8, 2)
            lo, hi = y0 + shorten[0], y1 - shorten[1]
            bx.add(x, (lo + hi) / 2, 1.0, hi - lo, rng.uniform(2.2, 3.2))
    # Pillars in the aisles between rack rows (the route keeps to the perimeter and cross aisles).
    for px in ((xs[0] + xs[1]) / 2, (xs[1] + xs[2]) / 2):
        for py in (d / 4, 3 * d / 4):
            bx.add(px, py + rng.uniform(-1.0, 1.0), 0.4, 0.4, h)
    # Pallets (stacked to random heights, any heading) in the free floor between racks and walls.
    x_lane = (xs[0] - 0.5) / 2 + 0.25  # middle of the west perimeter aisle
    x_lane_e = (xs[-1] + 0.5 + w) / 2 - 0.25
    # Around the south half, west through the cross aisle, around the north half.
    anchors = np.array(
        [[x_lane, 1.6], [x_lane_e, 1.6], [x_lane_e, y_aisle], [x_lane, y_aisle], [x_lane, d - 1.6], [x_lane_e, d - 1.6]]
    )
    bx.keep_out += [(w / 2, y_aisle, w / 2, 1.3)]  # the cross aisle stays open
    bx.keep_out += [(x, y, 0.6, 0.6) for x, y in anchors]
    for _ in range(8):
        bx.place_free(
            rng, (1.0, 1.0, w - 1.0, d - 1.0), (1.2, 0.8), rng.uniform(0.15, 1.4), clearance=0.8, yaw_range=0.4
        )
    return bx, (0.0, 0.0, w, d), anchors


def make_world(kind: str, seed: int) -> World:
    """A `house` (~10 x 8 m, three rooms) or `warehouse` (~15 x 20 m hall) from a seed."""
    if kind not in KINDS:
        raise ValueError(f"unknown world kind {kind!r}; choose one of {list(KINDS)}")
    rng = np.random.default_rng([seed, KINDS.index(kind)])
    bx, bounds, anchors = (_house if kind == "house" else _warehouse)(rng)
    return World(
        kind=kind,
        seed=int(seed),
        center=np.asarray(bx.center, np.float32),
        half=np.asarray(bx.half, np.float32),
        yaw=np.asarray(bx.yaw, np.float32),
        bounds=tuple(float(v) for v in bounds),
        anchors=anchors.astype(np.float64),
    )


def _most_open(boxes: tuple, region: tuple, step: float = 0.1) -> np.ndarray:
    x0, y0, x1, y1 = region
    xy = np.stack(np.meshgrid(np.arange(x0 + step, x1, step), np.arange(y0 + step, y1, step)), -1).reshape(-1, 2)
    return xy[np.argmax(_signed_distance(*boxes, xy))]


def rectangle_distances(center, half, yaw, xy) -> np.ndarray:
    """(…, B) planar signed distance (m) from points `xy` (…, 2) to B rectangles of centres `center` (B, >= 2),
    half extents `half` (B, >= 2) along their own axes and yaws `yaw` (B,) (< 0 inside)."""
    p = np.asarray(xy, np.float64)[..., None, :] - center[:, :2]  # (…, B, 2)
    c, s = np.cos(yaw), np.sin(yaw)
    local = np.stack([c * p[..., 0] + s * p[..., 1], -s * p[..., 0] + c * p[..., 1]], -1)
    q = np.abs(local) - half[:, :2]
    outside = np.linalg.norm(np.maximum(q, 0.0), axis=-1)
    inside = np.minimum(np.max(q, axis=-1), 0.0)
    return outside + inside


def _signed_distance(center, half, yaw, xy):
    return np.min(rectangle_distances(center, half, yaw, xy), axis=-1)


def box_distances(world: World, xy: np.ndarray) -> np.ndarray:
    """(…, B) planar signed distance (m) from points `xy` (…, 2) to each box footprint (< 0 inside)."""
    return rectangle_distances(world.center, world.half, world.yaw, xy)


def box_signed_distance(world: World, xy: np.ndarray) -> np.ndarray:
    """(…,) planar signed distance (m) from points `xy` (…, 2) to the nearest box footprint."""
    return _signed_distance(world.center, world.half, world.yaw, xy)


def occupancy_map(world: World, resolution: float = 0.05, margin: float = 0.5) -> OccupancyMap:
    """Ground-truth map: cells whose centre lies in a box footprint are occupied (100), the rest
    inside the outer walls free (0), outside them unknown (-1)."""
    xmin, ymin, xmax, ymax = world.bounds
    origin = (xmin - margin, ymin - margin, 0.0)
    cols = int(np.ceil((xmax - xmin + 2 * margin) / resolution))
    rows = int(np.ceil((ymax - ymin + 2 * margin) / resolution))
    grid = np.zeros((rows, cols), np.int8)
    occ = OccupancyMap(grid, resolution, origin)
    xy = occ.cell_centers()
    inside = (xy[..., 0] > xmin) & (xy[..., 0] < xmax) & (xy[..., 1] > ymin) & (xy[..., 1] < ymax)
    grid[~inside] = -1
    grid[box_signed_distance(world, xy) <= 0.0] = 100
    return occ


def world_xml(world: World) -> str:
    """MJCF of the world alone (floor plane named `floor` + boxes, no collisions), for viewing and
    for checking the caster against MuJoCo's own ray casting."""
    geoms = "".join(
        f'<geom name="box{i}" type="box" pos="{c[0]:.6f} {c[1]:.6f} {c[2]:.6f}" '
        f'size="{h[0]:.6f} {h[1]:.6f} {h[2]:.6f}" '
        f'euler="0 0 {y:.9f}" contype="0" conaffinity="0" rgba="0.7 0.7 0.65 1"/>'
        for i, (c, h, y) in enumerate(zip(world.center, world.half, world.yaw))
    )
    return (
        f'<mujoco model="{world.kind}_{world.seed}"><compiler angle="radian"/><worldbody>'
        f'<geom name="floor" type="plane" size="0 0 0.05"/>{geoms}</worldbody></mujoco>'
    )
