"""Occupancy updates against a NumPy loop over integer Bresenham lines, and map conversion."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxquad.io.maps import load_map, save_map
from jaxquad.kernels.occupancy import GridSpec, OccupancyParams, init_grid, insert_scan, map_from_scans, scan_evidence
from jaxquad.slam.mapping import fleet_maps, grid_spec, to_occupancy_map

SPEC = GridSpec(rows=60, cols=80, resolution=0.1, origin_x=-4.0, origin_y=-3.0, max_range=5.0)
PARAMS = OccupancyParams(range_min=jnp.asarray(0.2), range_max=jnp.asarray(4.0))
_evidence = jax.jit(scan_evidence)
_insert = jax.jit(insert_scan)


def _bresenham(c0, r0, c1, r1):
    """The classic integer error-term loop (all octants)."""
    dc, dr = abs(c1 - c0), abs(r1 - r0)
    sc, sr = (1 if c1 >= c0 else -1), (1 if r1 >= r0 else -1)
    cells = []
    if dc >= dr:
        err, r = 2 * dr - dc, r0
        for k in range(dc + 1):
            cells.append((r, c0 + k * sc))
            if err > 0:
                r, err = r + sr, err - 2 * dc
            err += 2 * dr
    else:
        err, c = 2 * dc - dr, c0
        for k in range(dr + 1):
            cells.append((r0 + k * sr, c))
            if err > 0:
                c, err = c + sc, err - 2 * dr
            err += 2 * dc
    return cells


def _evidence_np(
    spec, pose, ranges, bearings, range_min, range_max, l_occ, l_free, hit_offset=0.0, clear_range=0.0, clear_margin=0.0
):
    """Per cell: the sum of the rays' evidence (l_occ at a return's end cell, `hit_offset` beyond the reading,
    l_free elsewhere on the ray; a far return in [range_max, clear_range) clears its ray to
    max(range_max, r - clear_margin r^2)) clipped to [l_free, l_occ], and whether a ray touched it."""
    total = np.zeros((spec.rows, spec.cols))
    touched = np.zeros((spec.rows, spec.cols), bool)
    cell = lambda x, y: (
        int(np.floor((y - spec.origin_y) / spec.resolution)),
        int(np.floor((x - spec.origin_x) / spec.resolution)),
    )
    r0, c0 = cell(pose[0], pose[1])
    for r, b in zip(ranges, bearings):
        if np.isnan(r) or r == -np.inf or r < range_min:
            continue
        hit = r < range_max
        d = min(np.float32(r) + np.float32(hit_offset), spec.max_range) if hit else range_max
        if range_max <= r < clear_range:
            d = min(max(range_max, np.float32(r) - np.float32(clear_margin) * np.float32(r) ** 2), spec.max_range)
        a = np.float32(pose[2]) + np.float32(b)
        r1, c1 = cell(np.float32(pose[0]) + np.float32(d) * np.cos(a), np.float32(pose[1]) + np.float32(d) * np.sin(a))
        line = _bresenham(c0, r0, c1, r1)
        for k, (row, col) in enumerate(line):
            if 0 <= row < spec.rows and 0 <= col < spec.cols:
                total[row, col] += l_occ if (hit and k == len(line) - 1) else l_free
                touched[row, col] = True
    return np.clip(total, l_free, l_occ), touched


def test_scan_evidence_equals_numpy_bresenham_sums():
    rng = np.random.default_rng(0)
    l_occ, l_free = float(PARAMS.l_occ), float(PARAMS.l_free)
    mixed = 0
    for trial in range(5):
        pose = np.array([rng.uniform(-3, 3), rng.uniform(-2, 2), rng.uniform(-np.pi, np.pi)], np.float32)
        bearings = np.linspace(-np.pi, np.pi, 181, endpoint=False).astype(np.float32)
        ranges = rng.uniform(0.0, 5.0, 181).astype(np.float32)
        ranges[::17] = np.inf
        ranges[5::23] = np.nan
        ranges[7::29] = -np.inf
        delta, touched = _evidence(SPEC, PARAMS, jnp.asarray(pose), jnp.asarray(ranges), jnp.asarray(bearings))
        # Endpoints that land within float32 rounding of a cell border may differ; there are none here
        # at this seed, so the cells compare exactly.
        ref_delta, ref_touched = _evidence_np(SPEC, pose, ranges, bearings, 0.2, 4.0, l_occ, l_free)
        assert np.array_equal(np.asarray(touched), ref_touched), f"trial {trial}"
        np.testing.assert_allclose(np.asarray(delta), ref_delta, atol=1e-5)
        # cells that rays both end in and cross, with a change strictly between the two bounds
        mixed += int(np.sum((ref_delta > l_free + 1e-6) & (ref_delta < l_occ - 1e-6) & (ref_delta != 0)))
    assert mixed > 10


def test_hit_offset_moves_the_end_cell_along_the_ray():
    """The end cell is taken `hit_offset` beyond the reading: against the NumPy lines for random scans, and in
    closed form for a face met square-on: with half a cell, the occupied cell is the one whose centre is behind
    the face, and the cell the face passes through with its centre in front is crossed (free)."""
    rng = np.random.default_rng(1)
    l_occ, l_free = float(PARAMS.l_occ), float(PARAMS.l_free)
    for offset in (0.05, 0.1):
        params = OccupancyParams(range_min=jnp.asarray(0.2), range_max=jnp.asarray(4.0), hit_offset=jnp.asarray(offset))
        pose = np.array([rng.uniform(-3, 3), rng.uniform(-2, 2), rng.uniform(-np.pi, np.pi)], np.float32)
        bearings = np.linspace(-np.pi, np.pi, 181, endpoint=False).astype(np.float32)
        ranges = rng.uniform(0.0, 5.0, 181).astype(np.float32)
        ranges[::13] = 3.98  # returns within the offset of range_max: still hits, drawn beyond it
        delta, touched = _evidence(SPEC, params, jnp.asarray(pose), jnp.asarray(ranges), jnp.asarray(bearings))
        ref_delta, ref_touched = _evidence_np(SPEC, pose, ranges, bearings, 0.2, 4.0, l_occ, l_free, offset)
        assert np.array_equal(np.asarray(touched), ref_touched), offset
        np.testing.assert_allclose(np.asarray(delta), ref_delta, atol=1e-5)
    # Returns within the offset of the grid's max_range end at max_range (the traversal's length), still hits.
    far = OccupancyParams(range_min=jnp.asarray(0.2), range_max=jnp.asarray(6.0), hit_offset=jnp.asarray(0.1))
    pose = np.array([-3.95, -2.95, 0.0], np.float32)  # a corner of the grid, the rays into it
    bearings = np.linspace(0.0, np.pi / 2, 181).astype(np.float32)
    ranges = rng.uniform(4.9, 5.0, 181).astype(np.float32)
    delta, touched = _evidence(SPEC, far, jnp.asarray(pose), jnp.asarray(ranges), jnp.asarray(bearings))
    ref_delta, ref_touched = _evidence_np(SPEC, pose, ranges, bearings, 0.2, SPEC.max_range, l_occ, l_free, 0.1)
    assert np.array_equal(np.asarray(touched), ref_touched)
    np.testing.assert_allclose(np.asarray(delta), ref_delta, atol=1e-5)
    assert (ref_delta > 0).sum() > 50  # the hits are kept
    # Square-on: the sensor at x = -3.95 (column 0's centre) looking along +x; column 40 spans x in [0, 0.1),
    # its centre at 0.05. A face at x = 0.02 puts that centre inside the obstacle, a face at x = 0.08 in front.
    plain = OccupancyParams(range_min=jnp.asarray(0.2), range_max=jnp.asarray(4.5))
    half = OccupancyParams(range_min=jnp.asarray(0.2), range_max=jnp.asarray(4.5), hit_offset=jnp.asarray(0.05))
    pose, bearing, row = jnp.asarray([-3.95, 0.05, 0.0]), jnp.asarray([0.0]), 30
    for face, centre_behind in ((0.02, 40), (0.08, 41)):
        for params, end_col in ((half, centre_behind), (plain, 40)):  # without the offset: the face's own cell
            delta = np.asarray(_evidence(SPEC, params, pose, jnp.asarray([face + 3.95]), bearing)[0])[row]
            assert delta[end_col] > 0 and np.all(delta[1:end_col] < 0) and np.all(delta[end_col + 1 :] == 0), face


def test_far_returns_clear_their_rays_short_of_the_reading():
    """Readings from range_max up to clear_range: free up to max(range_max, r - clear_margin r^2), no hit; against
    the NumPy lines for random scans, and in closed form along one row."""
    rng = np.random.default_rng(2)
    params = OccupancyParams(
        range_min=jnp.asarray(0.2),
        range_max=jnp.asarray(3.0),
        clear_range=jnp.asarray(4.5),
        clear_margin=jnp.asarray(0.03),
    )
    l_occ, l_free = float(params.l_occ), float(params.l_free)
    for trial in range(3):
        pose = np.array([rng.uniform(-3, 3), rng.uniform(-2, 2), rng.uniform(-np.pi, np.pi)], np.float32)
        bearings = np.linspace(-np.pi, np.pi, 181, endpoint=False).astype(np.float32)
        ranges = rng.uniform(0.0, 6.0, 181).astype(np.float32)
        ranges[::17] = np.inf
        delta, touched = _evidence(SPEC, params, jnp.asarray(pose), jnp.asarray(ranges), jnp.asarray(bearings))
        ref = _evidence_np(SPEC, pose, ranges, bearings, 0.2, 3.0, l_occ, l_free, 0.0, 4.5, 0.03)
        assert np.array_equal(np.asarray(touched), ref[1]), f"trial {trial}"
        np.testing.assert_allclose(np.asarray(delta), ref[0], atol=1e-5)
    # From column 0's centre along +x (column c spans x in [-4 + 0.1 c, -3.9 + 0.1 c)): a reading of 4 m clears to
    # 4 - 0.48 = 3.52 m, x = -0.43 (column 35); 3.2 m clears to range_max, 3 m (x = -0.95, column 30); 5 m, beyond
    # clear_range, is a no-return (column 30); 2 m is a hit (x = 1.95, column 20).
    pose, bearing, row = jnp.asarray([-3.95, 0.05, 0.0]), jnp.asarray([0.0]), 30
    for reading, end_col, hit in ((4.0, 35, False), (3.2, 30, False), (5.0, 30, False), (2.0, 20, True)):
        delta = np.asarray(_evidence(SPEC, params, pose, jnp.asarray([reading]), bearing)[0])[row]
        assert np.all(delta[: end_col + (0 if hit else 1)] < 0) and np.all(delta[end_col + 1 :] == 0), reading
        assert (delta[end_col] > 0) == hit, reading


def test_log_odds_update_and_clamping():
    pose = jnp.asarray([0.05, 0.05, 0.0])
    ranges, bearings = jnp.asarray([1.0, jnp.inf, jnp.nan]), jnp.asarray([0.0, jnp.pi / 2, jnp.pi])
    grid = init_grid(SPEC)
    for _ in range(10):
        grid = _insert(SPEC, PARAMS, grid, pose, ranges, bearings)
    delta, touched = (np.asarray(a) for a in _evidence(SPEC, PARAMS, pose, ranges, bearings))
    lo = np.asarray(grid.log_odds)
    hit, free = delta > 0, delta < 0
    np.testing.assert_allclose(lo[hit], float(PARAMS.l_max))  # 10 x l_occ (1.39) clamped at 3.5
    np.testing.assert_allclose(lo[free], float(PARAMS.l_min))
    assert np.all(lo[~touched] == 0) and np.array_equal(np.asarray(grid.observed), touched)
    assert hit.sum() == 1  # the +inf ray clears to range_max but marks no hit; NaN does nothing
    assert (free[:, 40]).sum() == 30  # the +inf ray: rows 30 up to 69, clipped at the top row 59
    assert touched.sum() == hit.sum() + free.sum()  # the two rays share only the sensor's cell (free)


def test_map_from_scans_vmaps_and_saves(tmp_path):
    # A square room of walls 2 m from the centre; robots at different poses map it.
    spec = grid_spec((-3.0, -3.0, 3.0, 3.0), 0.05, 4.0)
    bearings = jnp.linspace(-jnp.pi, jnp.pi, 360, endpoint=False)

    def room_ranges(pose):
        a = pose[2] + bearings
        c, s = jnp.cos(a), jnp.sin(a)
        tx = jnp.where(c > 0, (2.0 - pose[0]) / c, (-2.0 - pose[0]) / c)
        ty = jnp.where(s > 0, (2.0 - pose[1]) / s, (-2.0 - pose[1]) / s)
        return jnp.minimum(jnp.abs(tx), jnp.abs(ty)) - 1e-3

    poses = jnp.asarray([[[0.0, 0.0, 0.0], [0.5, 0.2, 1.0]], [[-0.7, 0.3, 2.0], [0.1, -0.4, -1.0]]])
    ranges = jax.vmap(jax.vmap(room_ranges))(poses)
    grids = fleet_maps(spec, OccupancyParams(), poses, ranges, bearings)
    for k in range(2):
        alone = jax.jit(map_from_scans)(spec, OccupancyParams(), poses[k], ranges[k], bearings)
        np.testing.assert_array_equal(grids.log_odds[k], alone.log_odds)
        occ = to_occupancy_map(spec, jax.tree.map(lambda x, k=k: x[k], grids))
        wall = (np.abs(np.abs(occ.cell_centers()) - 2.0) < 0.05).any(-1) & (np.abs(occ.cell_centers()) < 2.05).all(-1)
        hits = occ.grid > 65
        assert hits.sum() > 100 and np.all(wall[hits])  # every occupied cell lies on a wall
        saved = load_map(save_map(tmp_path / f"m{k}.yaml", occ))
        assert np.array_equal(saved.grid == 100, hits) and saved.origin == occ.origin


def test_bad_grid_bounds():
    with pytest.raises(ValueError, match="xmax > xmin"):
        grid_spec((1.0, 0.0, 0.0, 1.0), 0.05, 4.0)


def test_scan_mask_skips_scans():
    spec = grid_spec((-2.0, -2.0, 2.0, 2.0), 0.1, 3.0)
    rng = np.random.default_rng(3)
    poses = jnp.asarray(rng.uniform(-1, 1, (6, 3)), jnp.float32)
    ranges = jnp.asarray(rng.uniform(0.3, 3.5, (6, 90)), jnp.float32)
    bearings = jnp.linspace(-jnp.pi, jnp.pi, 90, endpoint=False)
    keep = np.array([True, False, True, True, False, True])
    build = jax.jit(map_from_scans)
    masked = build(spec, PARAMS, poses, ranges, bearings, jnp.asarray(keep))
    kept = build(spec, PARAMS, poses[keep], ranges[keep], bearings)
    np.testing.assert_array_equal(masked.log_odds, kept.log_odds)
    np.testing.assert_array_equal(masked.observed, kept.observed)
