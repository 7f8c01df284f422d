"""Map scores against hand-counted cases, a brute-force resampling loop, and a simulated house."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxquad.io.maps import OccupancyMap
from jaxquad.kernels.occupancy import OccupancyParams, map_from_scans
from jaxquad.kernels.raycast import Boxes, ray_distance
from jaxquad.metrics import map_scores, resample_map
from jaxquad.sim.worlds import make_world, occupancy_map
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
