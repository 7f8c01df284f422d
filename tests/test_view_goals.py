"""View goals: rays' free lengths against exact ray-square intersections, the goal against a brute-force search over
every cell with a clear straight line to the frontier (NumPy), and the cases with nothing to look at."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from _slot_maps import room_with_slots
from scipy import ndimage

from jaxquad.kernels.planner import cost_to_go
from jaxquad.kernels.view_goals import ViewParams, choose_view, free_lengths, in_view

RES = 0.05
FREE_THRESH = 50.0
PARAMS = ViewParams.default()
_choose = jax.jit(choose_view)
_lengths = jax.jit(free_lengths, static_argnums=(2, 3))
_in_view = jax.jit(in_view, static_argnums=(2, 3))


def _chords(shape, start, direction, t_max):
    """Per cell: (t_enter, t_exit) of the ray start + t * direction (cells; unit direction) through its square,
    t_enter = inf where the ray misses it (slab method, every cell at once)."""
    r, c = np.meshgrid(np.arange(shape[0], dtype=float), np.arange(shape[1], dtype=float), indexing="ij")
    t0, t1 = np.full(shape, 0.0), np.full(shape, t_max)
    for lo, o, d in ((r, start[0], direction[0]), (c, start[1], direction[1])):
        if abs(d) < 1e-12:
            inside = (o >= lo) & (o <= lo + 1)
            t0, t1 = np.where(inside, t0, np.inf), np.where(inside, t1, -np.inf)
        else:
            a, b = (lo - o) / d, (lo + 1 - o) / d
            t0, t1 = np.maximum(t0, np.minimum(a, b)), np.minimum(t1, np.maximum(a, b))
    return np.where(t1 > t0, t0, np.inf), t1


def _blocked_from(free, target, start, direction, t_max, min_chord):
    """Distance at which the ray first enters a cell that is not free (the target's own excepted) through a chord of
    at least `min_chord` cells, or leaves the grid; t_max if neither. With min_chord 0 the first entry of any kind."""
    t_in, t_out = _chords(free.shape, start, direction, t_max)
    block = ~free & (t_out - t_in >= max(min_chord, 1e-9))
    block[tuple(target)] = False
    first = np.min(np.where(block, t_in, np.inf))
    h, w = free.shape
    ts = [
        (b - o) / d for o, d, lim in ((start[0], direction[0], h), (start[1], direction[1], w)) for b in (0, lim) if d
    ]
    leave = min(t for t in ts if t > 0)
    return min(first, leave, t_max)


def _room_with_slot():
    """4 x 3 m room; in its top wall a slot 0.4 m wide and 0.9 m deep whose inner 0.6 m are unknown."""
    return room_with_slots(100, (40,))


def _value(grid, start_rc, blocked_rows_from=None):
    """Cost-to-go over free cells; rows from `blocked_rows_from` up are out of the robot's reach (a slot too narrow)."""
    weight = np.where((grid >= 0) & (grid < FREE_THRESH), 1.0, np.inf)
    if blocked_rows_from is not None:
        weight[blocked_rows_from:] = np.inf
    source = np.zeros(grid.shape, bool)
    source[start_rc] = True
    return np.asarray(cost_to_go(jnp.asarray(weight), jnp.asarray(source)))


def _view(grid, value, robot_rc, excluded=None, params=PARAMS):
    """`choose_view` on NumPy inputs."""
    excluded = np.zeros(grid.shape, bool) if excluded is None else excluded
    args = (jnp.asarray(robot_rc), jnp.asarray(excluded), FREE_THRESH, params)
    return _choose(jnp.asarray(grid), RES, jnp.asarray(value), *args)


def _clear(free, target, cell, min_chord=0.25):
    """The straight line from the target's centre to the cell's centre crosses no cell that is not free (the target's
    own excepted) through a chord of `min_chord` cells or more."""
    a, b = np.asarray(target, float) + 0.5, np.asarray(cell, float) + 0.5
    length = np.linalg.norm(b - a)
    return _blocked_from(free, target, a, (b - a) / length, length, min_chord) >= length - 1e-6


def _brute_force(grid, value, target, params=PARAMS):
    """(cost, cell) of the cheapest reachable cell with a clear line to `target` within the ranges, every cell tried
    (cheapest first)."""
    free = (grid >= 0) & (grid < FREE_THRESH)
    cells = np.argwhere(np.isfinite(value))
    d = np.linalg.norm(cells - np.asarray(target), axis=1)
    near = (d * RES >= float(params.min_range)) & (d * RES <= float(params.max_range))
    cells, d = cells[near], d[near]
    cost = value[cells[:, 0], cells[:, 1]] + float(params.range_weight) * d
    for k in np.argsort(cost, kind="stable"):
        if _clear(free, target, cells[k]):
            return cost[k], tuple(cells[k])
    return np.inf, None


def _eligible(grid, excluded=None, min_size=float(PARAMS.min_size)):
    """Frontier cells (unknown, a free 4-neighbour) of 8-connected clusters at least min_size long, not excluded."""
    free = (grid >= 0) & (grid < FREE_THRESH)
    padded = np.pad(free, 1)
    touches = padded[:-2, 1:-1] | padded[2:, 1:-1] | padded[1:-1, :-2] | padded[1:-1, 2:]
    mask = (grid < 0) & touches
    labels, _ = ndimage.label(mask, structure=np.ones((3, 3)))
    sizes = np.bincount(labels.ravel())
    out = mask & (sizes[labels] * RES >= min_size - 1e-6)
    return out if excluded is None else out & ~excluded


def _check_cost(out, value):
    """The reported cost is the goal's cost-to-go plus range_weight times its distance to the target."""
    goal, target = np.asarray(out.goal_rc), np.asarray(out.target_rc)
    expected = value[tuple(goal)] + float(PARAMS.range_weight) * np.linalg.norm(goal - target)
    np.testing.assert_allclose(float(out.cost), expected, rtol=1e-5)


@pytest.mark.parametrize("seed", [0, 1])
def test_free_lengths_bracket_the_exact_first_blocked_cell(seed):
    """Each ray's free length lies between the first entry into a blocked cell (less one sample step) and the exit
    from the first blocked cell that the ray crosses through a quarter of a cell or more (no sample can skip it)."""
    rng = np.random.default_rng(seed)
    free = ndimage.gaussian_filter(rng.random((70, 70)), 2.0) < 0.52
    target = tuple(rng.integers(25, 45, 2))
    n_rays, reach = 90, 30
    lengths = np.asarray(_lengths(jnp.asarray(free), jnp.asarray(target, jnp.int32), n_rays, reach))
    start = np.asarray(target, float) + 0.5
    for k, a in enumerate(2 * np.pi * np.arange(n_rays) / n_rays):
        d = np.array([np.sin(a), np.cos(a)])
        lo = _blocked_from(free, target, start, d, reach, 0.0)
        t_in, t_out = _chords(free.shape, start, d, reach)
        solid = ~free & (t_out - t_in >= 0.3)
        solid[target] = False
        hi = min(np.min(np.where(solid, t_out, np.inf)), _blocked_from(free, target, start, d, reach, 0.3) + 0.25)
        assert lo - 0.25 - 1e-4 <= lengths[k] <= min(hi, reach) + 1e-4, (k, lo, hi, lengths[k])


@pytest.mark.parametrize("seed", [0, 1])
def test_cells_in_view_have_a_clear_line_and_nearly_every_clear_cell_is_in_view(seed):
    """Against the exact line from the target's centre to each cell's centre: no cell in view has one that passes
    through a blocked cell by more than the rays' spacing at that distance (under 0.9 of a cell within 50 cells at 360
    rays), and at least 95 % of the cells whose line touches no blocked cell at all are in view."""
    rng = np.random.default_rng(seed)
    free = ndimage.gaussian_filter(rng.random((90, 90)), 2.0) < 0.53
    target = (45, 45)
    free[44:47, 44:47] = True
    m = 30
    seen, _ = _in_view(jnp.asarray(free), jnp.asarray(target, jnp.int32), 360, m)
    seen = np.asarray(seen)
    clear_any = []
    for dr, dc in np.argwhere(np.ones_like(seen)) - m:
        cell = (target[0] + dr, target[1] + dc)
        if (dr, dc) == (0, 0) or np.hypot(dr, dc) > m:
            continue
        ok_seen = seen[dr + m, dc + m]
        if ok_seen:
            assert _clear(free, target, cell, min_chord=0.9), cell
        if _clear(free, target, cell, min_chord=0.0):
            clear_any.append(ok_seen)
    assert len(clear_any) > 100 and np.mean(clear_any) >= 0.95, (len(clear_any), np.mean(clear_any))


def test_slot_is_looked_into_from_its_mouth_as_the_brute_force_search_finds():
    grid = _room_with_slot()
    value = _value(grid, (20, 20), blocked_rows_from=60)
    out = _view(grid, value, (20, 20))
    assert bool(out.found) and int(out.n_targets) == int(_eligible(grid).sum()) == 8
    target = tuple(np.asarray(out.target_rc))
    assert grid[target] == -1 and 40 <= target[1] < 48  # a frontier cell inside the slot
    _check_cost(out, value)
    # Every target scored (all 8 here) searched over every cell: the cheapest of them.
    best = min((_brute_force(grid, value, tuple(t)) for t in np.argwhere(_eligible(grid))), key=lambda b: b[0])
    goal = tuple(np.asarray(out.goal_rc))
    free = (grid >= 0) & (grid < FREE_THRESH)
    assert np.isfinite(value[goal]) and _clear(free, target, goal)
    d = np.linalg.norm(np.subtract(goal, target)) * RES
    assert float(PARAMS.min_range) <= d <= float(PARAMS.max_range)
    # The rays' wedges may refuse a cell whose line grazes a corner: within a cell's worth of the best cost.
    assert best[0] - 1e-3 <= float(out.cost) <= best[0] + 2.0, (float(out.cost), best, goal)
    assert 38 <= goal[1] <= 49  # before the mouth, looking along the slot


def test_a_walled_off_frontier_is_hopeless_and_an_excluded_one_not_looked_at():
    grid = _room_with_slot()
    grid[60:66, 40:48] = 100  # the slot's mouth walled: its unknown cells touch no free cell the robot can see
    grid[66, 41:47] = 0  # ... but free cells inside keep a frontier there: 6 cells above them, 2 at their ends
    value = _value(grid, (20, 20), blocked_rows_from=60)
    out = _view(grid, value, (20, 20))
    assert not bool(out.found) and int(out.n_targets) == 8 and int(out.n_left) == 0
    np.testing.assert_array_equal(np.asarray(out.hopeless), _eligible(grid))

    open_ = _room_with_slot()
    first = _view(open_, value, (20, 20))
    assert bool(first.found) and int(first.n_left) == 8 and not np.asarray(first.hopeless).any()
    excluded = np.zeros(grid.shape, bool)
    excluded[tuple(np.asarray(first.target_rc))] = True
    second = _view(open_, value, (20, 20), excluded)  # another cell of the slot's frontier
    assert bool(second.found) and int(second.n_targets) == 7
    assert tuple(np.asarray(second.target_rc)) != tuple(np.asarray(first.target_rc))
    excluded[66, 40:48] = True
    again = _view(open_, value, (20, 20), excluded)
    assert not bool(again.found) and int(again.n_targets) == 0 and not np.asarray(again.hopeless).any()


def _two_slots():
    return room_with_slots(100, (40, 70))


def test_the_nearest_frontier_cells_are_scored_a_kept_one_first_and_short_clusters_skipped():
    """Two slots, the robot nearer the right one; 4 targets scored: the 4 eligible cells nearest the robot (NumPy),
    the view of the cheapest; a target kept in the left slot is chosen over them; a cluster under min_size is none."""
    grid = _two_slots()
    robot = (20, 90)
    value = _value(grid, robot, blocked_rows_from=60)
    four = ViewParams.default(n_scored=4)
    out = _view(grid, value, robot, params=four)
    cells = np.argwhere(_eligible(grid))
    d2 = np.sort(((cells - robot) ** 2).sum(1))
    scored = np.asarray(out.scored_rc)
    np.testing.assert_array_equal(np.sort(((scored - robot) ** 2).sum(1)), d2[:4])
    assert bool(out.found) and 70 <= int(out.target_rc[1]) < 78 and int(out.n_targets) == 16
    _check_cost(out, value)
    best = min((_brute_force(grid, value, tuple(t)) for t in scored), key=lambda b: b[0])
    assert best[0] - 1e-3 <= float(out.cost) <= best[0] + 2.0

    args = (jnp.asarray(robot), jnp.zeros(grid.shape, bool), FREE_THRESH, four, None)
    keep = _choose(jnp.asarray(grid), RES, jnp.asarray(value), *args, jnp.array([66, 43]))
    assert tuple(np.asarray(keep.target_rc)) == (66, 43) and float(keep.cost) > float(out.cost)
    _check_cost(keep, value)
    nothing = _choose(jnp.asarray(grid), RES, jnp.asarray(value), *args, jnp.array([-1, -1]))
    assert tuple(np.asarray(nothing.target_rc)) == tuple(np.asarray(out.target_rc))

    short = ViewParams.default(min_size=0.45)  # each slot's frontier is 8 cells = 0.4 m
    none = _view(grid, value, robot, params=short)
    assert int(none.n_targets) == 0 and not bool(none.found)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_random_maps_goal_is_in_view_and_as_cheap_as_the_brute_force_search_for_the_targets(seed):
    """Rooms of free cells with scattered walls and unknown blobs, the robot somewhere free: the goal sees its target
    along a clear line, within the ranges, and costs what the search over every cell finds for the targets scored,
    which are the eligible cells nearest the robot (NumPy)."""
    rng = np.random.default_rng(seed)
    field = ndimage.gaussian_filter(rng.random((60, 60)), 3.0)
    grid = np.where(field > np.quantile(field, 0.7), -1, 0).astype(np.int8)
    grid[ndimage.binary_dilation(rng.random((60, 60)) < 0.01, iterations=2)] = 100
    robot = tuple(rng.choice(np.argwhere(grid == 0)))
    value = _value(grid, robot)
    out = _view(grid, value, robot)
    assert bool(out.found)
    cells = np.argwhere(_eligible(grid))
    scored = np.asarray(out.scored_rc)
    k = int(PARAMS.n_scored)
    np.testing.assert_array_equal(np.sort(((scored - robot) ** 2).sum(1)), np.sort(((cells - robot) ** 2).sum(1))[:k])
    target, goal = tuple(np.asarray(out.target_rc)), tuple(np.asarray(out.goal_rc))
    free = (grid >= 0) & (grid < FREE_THRESH)
    assert grid[target] == -1 and np.isfinite(value[goal]) and _clear(free, target, goal)
    _check_cost(out, value)
    best = min((_brute_force(grid, value, tuple(t)) for t in scored), key=lambda b: b[0])
    assert best[0] - 1e-3 <= float(out.cost) <= best[0] + 2.0
