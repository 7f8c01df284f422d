"""Map scores against hand-counted cases, a brute-force resampling loop, and a simulated house."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy.ndimage import binary_dilation

from jaxquad.io.maps import OccupancyMap
from jaxquad.kernels.occupancy import OccupancyParams, map_from_scans
from jaxquad.kernels.raycast import Boxes, ray_distance
from jaxquad.metrics import cells_in_view, map_scores, narrow_gaps, resample_map
from jaxquad.sim.worlds import box_signed_distance, make_world, occupancy_map
from jaxquad.slam.mapping import grid_spec_like, to_occupancy_map


def _room() -> OccupancyMap:
    """40 x 40 cells: unknown border, free inside, 1-cell walls around a 30 x 30 room, a 4 x 4 pillar."""
    g = np.full((40, 40), -1, np.int8)
    g[5:35, 5:35] = 100
    g[6:34, 6:34] = 0
    g[18:22, 18:22] = 100
    return OccupancyMap(g, 0.05, (1.0, -2.0, 0.0))


def test_identical_map_scores_perfectly():
    s = map_scores(_room(), _room())
    assert (s.precision, s.recall, s.iou, s.free_coverage, s.phantom_fraction) == (1.0, 1.0, 1.0, 1.0, 0.0)
    # Visible occupied cells: the wall ring (4 * 30 - 4) less its 4 corners (no free 4-neighbour), and the
    # pillar's 12 edge cells.
    assert s.n_true_visible_occupied == 112 + 12


def test_one_cell_shift_is_tolerated_and_phantoms_are_counted():
    truth = _room()
    shifted = OccupancyMap(np.roll(truth.grid, 1, axis=1), truth.resolution, truth.origin)
    s = map_scores(shifted, truth)
    assert s.precision == 1.0 and s.recall == 1.0
    g = truth.grid.copy()
    g[10:12, 10:13] = 90  # 6 phantom cells, >= 3 cells from every true wall
    g[18:22, 18:22] = 0  # the pillar missed: 12 visible cells unmatched
    s = map_scores(OccupancyMap(g, truth.resolution, truth.origin), truth)
    n_occ = 30 * 30 - 28 * 28 + 6
    assert s.n_estimated_occupied == n_occ
    assert s.phantom_fraction == pytest.approx(6 / n_occ) and s.precision == pytest.approx((n_occ - 6) / n_occ)
    assert s.recall == pytest.approx(112 / 124) and s.iou == pytest.approx((n_occ - 6) / (n_occ + 12))
    assert s.free_coverage == pytest.approx((28 * 28 - 16 - 6) / (28 * 28 - 16))


def test_a_gap_one_cell_wide_is_neither_free_nor_a_visible_face():
    truth = _room()
    g = truth.grid.copy()
    g[10:20, 7:9] = 100  # a box one cell off the left wall (column 6 free between them)
    g[24:30, 8:10] = 100  # a box two cells off it (columns 6-7)
    gapped = OccupancyMap(g, truth.resolution, truth.origin)
    expect = np.zeros(g.shape, bool)
    expect[10:20, 6] = True
    assert np.array_equal(narrow_gaps(gapped), expect) and not narrow_gaps(truth).any()
    s = map_scores(gapped, gapped)
    # Visible: the room's 124, less the 10 wall cells behind the first box, plus the first box's right face and
    # the other ends of its top and bottom rows (10 + 2 cells; its face on the gap not) and the second box's 12.
    assert s.n_true_visible_occupied == 124 - 10 + 12 + 12 and s.recall == 1.0 and s.free_coverage == 1.0
    # A map with the gap's row occupied matches it within a cell; with the gap free its free cells still count.
    filled = OccupancyMap(np.where(expect, 100, g), truth.resolution, truth.origin)
    assert map_scores(filled, gapped).iou == 1.0


def test_a_perfect_sensor_maps_nearly_every_visible_face_of_the_house():
    """Independent reference: noise-free 360 deg scans ray-cast on the world's boxes from poses 0.4 m apart over
    its free floor. Faces across the gaps a cell wide behind the furniture are out of their sight; counted as
    visible, they would hold recall and IoU to 0.72 and 0.71."""
    world = make_world("house", 0)
    truth = occupancy_map(world, resolution=0.05)
    spec = grid_spec_like(truth, max_range=8.0)
    boxes = Boxes(jnp.asarray(world.center), jnp.asarray(world.half), jnp.asarray(world.yaw))
    x0, y0, x1, y1 = world.bounds
    xy = np.stack(np.meshgrid(np.arange(x0 + 0.25, x1, 0.4), np.arange(y0 + 0.25, y1, 0.4)), -1).reshape(-1, 2)
    xy = xy[box_signed_distance(world, xy) > 0.3]
    poses = np.c_[xy, np.zeros(len(xy))].astype(np.float32)
    bearings = jnp.linspace(-jnp.pi, jnp.pi, 720, endpoint=False)
    d = jnp.stack([jnp.cos(bearings), jnp.sin(bearings), jnp.zeros_like(bearings)], -1)
    ranges = jax.jit(jax.vmap(lambda p: ray_distance(jnp.asarray([p[0], p[1], 0.3]), d, boxes)))(jnp.asarray(poses))
    params = OccupancyParams(range_max=jnp.asarray(8.0))
    est = to_occupancy_map(spec, jax.jit(map_from_scans)(spec, params, poses, ranges, bearings))
    s = map_scores(est, truth)
    assert narrow_gaps(truth).sum() > 100  # the generated house has such gaps
    assert s.precision == 1.0 and s.recall > 0.85 and s.iou > 0.85 and s.free_coverage > 0.95  # 0.91, 0.91, 0.96


def test_resampling_matches_a_cell_by_cell_loop():
    rng = np.random.default_rng(0)
    est = OccupancyMap(rng.choice(np.array([-1, 0, 100], np.int8), (23, 31)), 0.1, (0.93, -2.12, 0.0))
    like = _room()
    out = resample_map(est, like)
    ref = np.full(like.grid.shape, -1, np.int8)
    for r in range(40):
        for c in range(40):
            x, y = like.origin[0] + (c + 0.5) * 0.05, like.origin[1] + (r + 0.5) * 0.05
            i, j = int(np.floor((y - est.origin[1]) / 0.1)), int(np.floor((x - est.origin[0]) / 0.1))
            if 0 <= i < 23 and 0 <= j < 31:
                ref[r, c] = est.grid[i, j]
    assert np.array_equal(out.grid, ref)
    with pytest.raises(ValueError, match="yaw 0"):
        map_scores(OccupancyMap(like.grid, 0.05, (0.0, 0.0, 0.3)), like)


def _first_hit_dda(occ: OccupancyMap, x, y, angle, range_max):
    """The first occupied cell along one ray by exact grid traversal (Amanatides & Woo), or None."""
    res, (ox, oy, _) = occ.resolution, occ.origin
    dx, dy = np.cos(angle), np.sin(angle)
    c, r = int(np.floor((x - ox) / res)), int(np.floor((y - oy) / res))
    step_c, step_r = (1 if dx > 0 else -1), (1 if dy > 0 else -1)
    next_x = ox + (c + (dx > 0)) * res
    next_y = oy + (r + (dy > 0)) * res
    t_x = (next_x - x) / dx if dx != 0 else np.inf
    t_y = (next_y - y) / dy if dy != 0 else np.inf
    dt_x, dt_y = (res / abs(dx) if dx != 0 else np.inf), (res / abs(dy) if dy != 0 else np.inf)
    t = 0.0
    while t < range_max:
        if not (0 <= r < occ.grid.shape[0] and 0 <= c < occ.grid.shape[1]):
            return None
        if occ.grid[r, c] > 65:
            return r, c
        if t_x < t_y:
            t, t_x, c = t_x, t_x + dt_x, c + step_c
        else:
            t, t_y, r = t_y, t_y + dt_y, r + step_r
    return None


def test_cells_in_view_are_the_first_cells_hit():
    truth = _room()
    rng = np.random.default_rng(1)
    # Sensor poses inside the room, clear of the pillar; a 90 deg fan of 40 beams.
    xy = truth.origin[:2] + (np.array([6.5, 6.5]) + rng.uniform(0, 10, (6, 2))) * truth.resolution
    poses = np.c_[xy, rng.uniform(-np.pi, np.pi, 6)]
    bearings = np.linspace(-np.pi / 4, np.pi / 4, 40)
    got = cells_in_view(truth, poses, bearings, 1.0, step_cells=0.02)
    ref = np.zeros_like(got)
    for px, py, yaw in poses:
        for b in bearings:
            hit = _first_hit_dda(truth, px, py, yaw + b, 1.0)
            if hit is not None:
                ref[hit] = True
    assert ref.sum() > 30 and np.all(truth.grid[got] == 100)
    # Fine steps cut a cell corner only in rare ties: nearly the same cells, none far from the reference.
    assert (got ^ ref).sum() <= 0.03 * ref.sum()
    assert np.all(binary_dilation(ref, np.ones((3, 3), bool))[got])
    # A beam that does not reach a wall within range_max sees nothing.
    assert not cells_in_view(truth, poses[:1], bearings, 0.01).any()


def test_in_view_scores_count_only_the_walls_faced():
    truth = _room()
    left_wall = np.zeros(truth.grid.shape, bool)
    left_wall[6:34, 5] = True
    est = np.full(truth.grid.shape, -1, np.int8)
    est[6:34, 6:12] = 0
    est[6:34, 5] = 100  # the one wall it faced, drawn exactly
    s = map_scores(OccupancyMap(est, truth.resolution, truth.origin), truth, in_view=left_wall)
    # Whole-map recall also credits the two cells of the floor and ceiling walls next to its ends.
    assert s.precision == 1.0 and s.recall == pytest.approx(30 / 124) and s.iou == pytest.approx(28 / (28 + 94))
    assert (s.recall_in_view, s.iou_in_view, s.n_true_in_view) == (1.0, 1.0, 28)
    # Drawing nothing scores 0, not NaN or 1; drawing a phantom costs precision and in-view IoU alike.
    empty = map_scores(OccupancyMap(np.where(est == 100, 0, est), truth.resolution, truth.origin), truth, left_wall)
    assert empty.iou_in_view == 0.0 and empty.recall_in_view == 0.0
    est[20, 9] = 100
    s = map_scores(OccupancyMap(est, truth.resolution, truth.origin), truth, in_view=left_wall)
    assert s.iou_in_view == pytest.approx(28 / 29)
    assert np.isnan(map_scores(truth, truth).iou_in_view)
    with pytest.raises(ValueError, match="in_view"):
        map_scores(truth, truth, in_view=left_wall[:10])


def test_simulated_house_map_and_pose_errors():
    world = make_world("house", 0)
    truth = occupancy_map(world, resolution=0.05)
    spec = grid_spec_like(truth, max_range=8.0)
    boxes = Boxes(jnp.asarray(world.center), jnp.asarray(world.half), jnp.asarray(world.yaw))
    a = world.anchors
    t = np.linspace(0.0, 1.0, 6, endpoint=False)
    xy = np.concatenate([p + t[:, None] * (q - p) for p, q in zip(a, np.roll(a, -1, 0))])
    poses = np.concatenate([xy, np.zeros((len(xy), 1))], 1).astype(np.float32)
    bearings = jnp.linspace(-jnp.pi, jnp.pi, 360, endpoint=False)
    d = jnp.stack([jnp.cos(bearings), jnp.sin(bearings), jnp.zeros_like(bearings)], -1)

    def scan(pose):
        return ray_distance(
            jnp.asarray([pose[0], pose[1], 0.3]),
            d
            @ jnp.asarray(
                [[jnp.cos(pose[2]), jnp.sin(pose[2]), 0], [-jnp.sin(pose[2]), jnp.cos(pose[2]), 0], [0, 0, 1.0]]
            ),
            boxes,
        )

    ranges = jax.jit(jax.vmap(scan))(jnp.asarray(poses))
    build = jax.jit(map_from_scans)
    good = map_scores(
        to_occupancy_map(spec, build(spec, OccupancyParams(range_max=jnp.asarray(8.0)), poses, ranges, bearings)), truth
    )
    assert good.precision > 0.97 and good.phantom_fraction < 0.01 and good.free_coverage > 0.6
    assert good.recall > 0.5
    noisy = poses + np.random.default_rng(1).normal(size=poses.shape).astype(np.float32) * [0.15, 0.15, 0.05]
    bad = map_scores(
        to_occupancy_map(spec, build(spec, OccupancyParams(range_max=jnp.asarray(8.0)), noisy, ranges, bearings)), truth
    )
    assert bad.precision < good.precision - 0.1 and bad.phantom_fraction > good.phantom_fraction
