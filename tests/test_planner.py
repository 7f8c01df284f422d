"""Grid planner: cost-to-go against scipy's Dijkstra on the same 8-connected graph; path descent optimality."""

import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy import sparse
from scipy.sparse import csgraph

from jaxquad.kernels.costmap import INSCRIBED, LETHAL, UNKNOWN
from jaxquad.kernels.planner import cost_to_go, descend, nearest_open_cell, step_weights

_ctg = jax.jit(cost_to_go)
_descend = jax.jit(descend, static_argnames=("n_points", "stride"))


def _reference_graph(weight):
    """8-connected graph, edge |step| * (w_a + w_b) / 2, built cell by cell."""
    h, w = weight.shape
    src, dst, cost = [], [], []
    for r in range(h):
        for c in range(w):
            for dr in (-1, 0, 1):
                for dc in (-1, 0, 1):
                    rr, cc = r + dr, c + dc
                    inside = (dr or dc) and 0 <= rr < h and 0 <= cc < w
                    if inside and np.isfinite(weight[r, c]) and np.isfinite(weight[rr, cc]):
                        src.append(r * w + c), dst.append(rr * w + cc)
                        cost.append(math.hypot(dr, dc) * 0.5 * (weight[r, c] + weight[rr, cc]))
    return sparse.csr_matrix((cost, (src, dst)), shape=(h * w, h * w))


def _random_weights(seed, shape):
    rng = np.random.default_rng(seed)
    weight = 1.0 + 3.0 * rng.random(shape)
    weight[rng.random(shape) < 0.25] = np.inf
    weight[5:7, : shape[1] - 4] = np.inf  # a wall with a gap: long detours
    return weight.astype(np.float32)


@pytest.mark.parametrize("seed, shape", [(0, (40, 40)), (1, (48, 70))])
def test_cost_to_go_matches_scipy_dijkstra(seed, shape):
    weight = _random_weights(seed, shape)
    open_idx = np.flatnonzero(np.isfinite(weight))
    goal = int(open_idx[len(open_idx) // 2])
    source = np.zeros(shape, bool)
    source.flat[goal] = True
    expected = csgraph.dijkstra(_reference_graph(weight), indices=goal).reshape(shape)
    expected[~np.isfinite(weight)] = np.inf
    got = np.asarray(_ctg(jnp.asarray(weight), jnp.asarray(source)))
    np.testing.assert_array_equal(np.isfinite(got), np.isfinite(expected))
    finite = np.isfinite(expected)
    np.testing.assert_allclose(got[finite], expected[finite], rtol=1e-5)


def test_descent_path_is_a_shortest_path():
    weight = _random_weights(2, (40, 40))
    weight[0, 0] = 1.0
    source = np.zeros((40, 40), bool)
    source[0, 0] = True
    value = np.asarray(_ctg(jnp.asarray(weight), jnp.asarray(source)))
    reach = np.argwhere(np.isfinite(value))
    start = reach[np.argmax(value[np.isfinite(value)])]
    cells, valid, complete = _descend(jnp.asarray(value), jnp.asarray(weight), jnp.asarray(start), n_points=400)
    cells, valid = np.asarray(cells), np.asarray(valid)
    assert bool(complete)
    path = cells[valid]
    assert tuple(path[0]) == tuple(start) and tuple(path[-1]) == (0, 0)
    steps = np.diff(path, axis=0)
    assert np.all(np.abs(steps).max(axis=1) == 1)
    length = sum(math.hypot(*d) * 0.5 * (weight[tuple(a)] + weight[tuple(b)]) for d, a, b in zip(steps, path, path[1:]))
    assert length == pytest.approx(value[tuple(start)], rel=1e-5)
    assert np.all(np.isfinite(weight[path[:, 0], path[:, 1]]))


def test_descent_stride_mask_and_unreachable():
    weight = np.ones((20, 30), np.float32)
    source = np.zeros((20, 30), bool)
    source[10, 25] = True
    value = _ctg(jnp.asarray(weight), jnp.asarray(source))
    cells, valid, complete = _descend(value, jnp.asarray(weight), jnp.array([10, 2]), n_points=10, stride=4)
    # 23 straight steps: points at steps 0, 4, ..., 20 and then the goal; the rest invalid.
    assert bool(complete) and int(np.sum(valid)) == 7
    assert tuple(np.asarray(cells)[6]) == (10, 25) and tuple(np.asarray(cells)[2]) == (
        10,
        10,
    )
    weight[:, 15] = np.inf
    value = _ctg(jnp.asarray(weight), jnp.asarray(source))
    assert np.isinf(float(value[10, 2]))
    _, valid, complete = _descend(value, jnp.asarray(weight), jnp.array([10, 2]), n_points=10, stride=4)
    assert not bool(complete) and not np.any(np.asarray(valid))


def test_step_weights_and_nearest_open_cell():
    cost = jnp.array([[0.0, 126.0, INSCRIBED, LETHAL, UNKNOWN]])
    w = np.asarray(step_weights(cost, 3.0))[0]
    np.testing.assert_allclose(w[:2], [1.0, 1.0 + 3.0 * 126 / 252])
    assert np.all(np.isinf(w[2:]))
    assert float(step_weights(cost, 3.0, allow_unknown=True)[0, 4]) == 1.0
    rc, ok = nearest_open_cell(step_weights(cost, 3.0), jnp.array([0, 4]), 3.0)
    assert tuple(np.asarray(rc)) == (0, 1) and bool(ok)
    _, ok = nearest_open_cell(step_weights(cost, 3.0), jnp.array([0, 4]), 2.0)
    assert not bool(ok)


def test_cost_to_go_vmaps_over_robots():
    weight = jnp.asarray(_random_weights(3, (40, 40)))
    sources = np.zeros((3, 40, 40), bool)
    open_idx = np.flatnonzero(np.isfinite(np.asarray(weight)))
    for i, k in enumerate(open_idx[[0, 100, 500]]):
        sources[i].flat[k] = True
    batched = jax.jit(jax.vmap(cost_to_go, in_axes=(None, 0)))(weight, jnp.asarray(sources))
    for i in range(3):
        np.testing.assert_allclose(np.asarray(batched[i]), np.asarray(_ctg(weight, jnp.asarray(sources[i]))))
