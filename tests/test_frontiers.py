"""Frontiers: mask by a per-cell loop, clusters against scipy.ndimage.label (8-connected), choice by a NumPy loop."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy import ndimage

from jaxquad.kernels.frontiers import (
    FrontierParams,
    choose_frontier,
    frontier_mask,
    label_clusters,
)
from jaxquad.kernels.planner import cost_to_go

FREE_THRESH = 19.6
_mask = jax.jit(frontier_mask)
_label = jax.jit(label_clusters)
_choose = jax.jit(choose_frontier)
_ctg = jax.jit(cost_to_go)


def _random_map(seed, shape=(60, 60)):
    """Free space with obstacles and smooth unknown blobs (so frontiers form long curves)."""
    rng = np.random.default_rng(seed)
    field = ndimage.gaussian_filter(rng.random(shape), 3.0)
    grid = np.where(field > np.quantile(field, 0.6), -1, 0).astype(np.int8)
    grid[rng.random(shape) < 0.05] = 100
    grid[rng.random(shape) < 0.05] = 10  # known, below the free threshold
    grid[rng.random(shape) < 0.02] = 40  # known, neither free nor occupied
    return grid


def _reference_mask(grid):
    h, w = grid.shape
    free = (grid >= 0) & (grid < FREE_THRESH)
    out = np.zeros_like(free)
    for r in range(h):
        for c in range(w):
            if grid[r, c] < 0:
                for dr, dc in ((-1, 0), (1, 0), (0, -1), (0, 1)):
                    if 0 <= r + dr < h and 0 <= c + dc < w and free[r + dr, c + dc]:
                        out[r, c] = True
    return out


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_mask_and_clusters_match_scipy(seed):
    grid = _random_map(seed)
    mask = np.asarray(_mask(jnp.asarray(grid), FREE_THRESH))
    np.testing.assert_array_equal(mask, _reference_mask(grid))
    labels = np.asarray(_label(jnp.asarray(mask)))
    ref, n_ref = ndimage.label(mask, structure=np.ones((3, 3)))
    assert n_ref > 3
    assert np.all(labels[~mask] == mask.size)
    for k in range(1, n_ref + 1):
        cells = np.flatnonzero(ref == k)
        assert np.all(labels.flat[cells] == cells.min())  # one label per component, its smallest index
    assert len(np.unique(labels[mask])) == n_ref


def _reference_choice(grid, value, blacklist, min_size, res, gain_scale, keep=None):
    """The loop's choice: (cost, (goal, centroid, size)); a cluster whose goal lies in `keep` (any size) first."""
    mask = _reference_mask(grid)
    ref, n_ref = ndimage.label(mask, structure=np.ones((3, 3)))
    reach = (grid >= 0) & (grid < FREE_THRESH) & np.isfinite(value)
    keep = np.zeros(grid.shape, bool) if keep is None else keep
    best = (np.inf, None)
    best_kept = (np.inf, None)
    for k in range(1, n_ref + 1):
        cells = np.argwhere(ref == k)
        centroid = cells.mean(axis=0)
        cand = {
            (r + dr, c + dc)
            for r, c in cells
            for dr, dc in ((-1, 0), (1, 0), (0, -1), (0, 1))
            if 0 <= r + dr < grid.shape[0] and 0 <= c + dc < grid.shape[1] and reach[r + dr, c + dc]
        }
        if not cand:
            continue
        cand = sorted(cand)
        d2 = [np.sum((np.array(p) - centroid) ** 2) for p in cand]
        goal = min((d, p[0] * grid.shape[1] + p[1]) for d, p in zip(d2, cand))[1]
        if blacklist.flat[goal] or (len(cells) * res < min_size and not keep.flat[goal]):
            continue
        cost = min(value[p] for p in cand) * res - gain_scale * len(cells) * res
        if cost < best[0]:
            best = (cost, (goal, centroid, len(cells)))
        if keep.flat[goal] and cost < best_kept[0]:
            best_kept = (cost, (goal, centroid, len(cells)))
    return best_kept if best_kept[1] is not None else best


@pytest.mark.parametrize("seed, gain_scale, keep", [(3, 0.0, False), (4, 0.0, False), (5, 2.0, False), (11, 0.0, True)])
def test_choice_matches_loop_reference(seed, gain_scale, keep):
    grid = _random_map(seed)
    res = 0.05
    weight = np.where((grid >= 0) & (grid < FREE_THRESH), 1.0, np.inf).astype(np.float32)
    start = np.argwhere(np.isfinite(weight))[len(np.argwhere(np.isfinite(weight))) // 2]
    source = np.zeros(grid.shape, bool)
    source[tuple(start)] = True
    value = np.asarray(_ctg(jnp.asarray(weight), jnp.asarray(source)))
    blacklist = np.zeros(grid.shape, bool)
    params = FrontierParams.default(gain_scale=gain_scale)
    first = _reference_choice(grid, value, blacklist, 0.75, res, gain_scale)
    assert first[1] is not None
    kept = np.zeros(grid.shape, bool)
    if keep:  # keep the goals of the farthest clusters, small ones included (they would not qualify otherwise)
        far = np.isfinite(value) & (value > np.quantile(value[np.isfinite(value)], 0.7))
        kept = far & (grid >= 0) & (grid < FREE_THRESH)
        assert _reference_choice(grid, value, blacklist, 0.75, res, gain_scale, kept)[1][0] != first[1][0]
    sizes = []
    for _ in range(3):  # choose, blacklist the goal, choose again
        want_cost, want = _reference_choice(grid, value, blacklist, 0.75, res, gain_scale, kept)
        got = _choose(jnp.asarray(grid), res, jnp.asarray(value), jnp.asarray(blacklist), params, jnp.asarray(kept))
        assert bool(got.found) == (want is not None)
        if want is None:
            break
        goal, centroid, size = want
        assert float(got.cost) == pytest.approx(want_cost, rel=1e-5)
        assert tuple(np.asarray(got.goal_rc)) == divmod(goal, grid.shape[1])
        np.testing.assert_allclose(np.asarray(got.centroid_rc), centroid, rtol=1e-5)
        assert int(got.size) == size
        sizes.append(size)
        blacklist.flat[goal] = True
    assert not keep or min(sizes) * res < 0.75  # a kept cluster below min_size was chosen


def test_fully_known_map_has_no_frontier():
    grid = np.zeros((40, 40), np.int8)
    grid[10, :] = 100
    got = _choose(
        jnp.asarray(grid),
        0.05,
        jnp.zeros((40, 40)),
        jnp.zeros((40, 40), bool),
        FrontierParams.default(),
    )
    assert not bool(got.found) and int(got.n_candidates) == 0


def test_unreachable_frontier_is_not_chosen():
    grid = np.full((40, 40), -1, np.int8)
    grid[5:15, 5:15] = 0
    value = np.full((40, 40), np.inf, np.float32)  # the robot reaches nothing
    got = _choose(
        jnp.asarray(grid),
        0.05,
        jnp.asarray(value),
        jnp.zeros((40, 40), bool),
        FrontierParams.default(),
    )
    assert not bool(got.found)


def test_choice_vmaps_over_robots():
    grids = np.stack([_random_map(s, (40, 40)) for s in (6, 7)])
    values = np.zeros((2, 40, 40), np.float32)
    batched = jax.jit(jax.vmap(choose_frontier, in_axes=(0, None, 0, 0, None)))(
        jnp.asarray(grids),
        0.05,
        jnp.asarray(values),
        jnp.zeros((2, 40, 40), bool),
        FrontierParams.default(),
    )
    for i in range(2):
        one = _choose(
            jnp.asarray(grids[i]),
            0.05,
            jnp.asarray(values[i]),
            jnp.zeros((40, 40), bool),
            FrontierParams.default(),
        )
        assert tuple(np.asarray(batched.goal_rc[i])) == tuple(np.asarray(one.goal_rc))
