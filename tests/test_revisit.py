"""Active loop closing (`jaxquad.nav.revisit`): the node chosen against a NumPy search over random node sets, and
when a revisit starts and ends, on hand-built cases."""

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxquad.kernels.costmap import CostGrid
from jaxquad.nav import revisit

RES = 0.05
SHAPE = (80, 100)  # rows (y), columns (x): 4 m x 5 m from the origin
PARAMS = revisit.RevisitParams.default(after=30.0, min_age=60.0, max_path=3.0, spacing=0.5, dwell=2.0, timeout=20.0)
_update = jax.jit(revisit.update)


def _grid() -> CostGrid:
    return CostGrid(jnp.zeros(SHAPE), jnp.zeros(2), jnp.asarray(RES, jnp.float32))


def _value(rng, pose) -> np.ndarray:
    """A cost-to-go: straight-line cells from the robot times a step weight of 1-2, inf on a random block."""
    rows, cols = np.indices(SHAPE)
    d = np.hypot(cols + 0.5 - pose[0] / RES, rows + 0.5 - pose[1] / RES) * rng.uniform(1.0, 2.0, SHAPE)
    r0, c0 = rng.integers(0, 60), rng.integers(0, 80)
    d[r0 : r0 + 20, c0 : c0 + 20] = np.inf
    return d.astype(np.float32)


def _reference(node_pose, node_t, node_mask, tried, t, pose, value):
    """Index of the node a revisit should go to (module doc), or None: a plain loop over the nodes."""
    best, best_path = None, np.inf
    for k in range(len(node_t)):
        col, row = int(np.floor(node_pose[k, 0] / RES)), int(np.floor(node_pose[k, 1] / RES))
        inside = 0 <= row < SHAPE[0] and 0 <= col < SHAPE[1]
        path = value[row, col] * RES if inside else np.inf
        ok = node_mask[k] and t - node_t[k] >= 60.0 and not tried[k] and path <= 3.0
        ok = ok and np.hypot(*(node_pose[k, :2] - pose[:2])) >= 0.5
        if ok and path < best_path:
            best, best_path = k, path
    return best


@pytest.mark.parametrize("seed", range(6))
def test_the_nearest_old_untried_node_is_chosen_as_a_numpy_search_chooses_it(seed):
    rng = np.random.default_rng(seed)
    n = 40
    node_pose = np.column_stack([rng.uniform(-0.3, 5.2, n), rng.uniform(-0.3, 4.2, n), rng.uniform(-3, 3, n)])
    node_pose = node_pose.astype(np.float32)
    node_t = rng.uniform(0, 120, n).astype(np.float32)
    node_mask = rng.random(n) < 0.9
    tried = rng.random(n) < 0.2
    pose = np.array([2.5, 2.0, 0.0], np.float32)
    value = _value(rng, pose)
    state = eqx.tree_at(lambda s: (s.tried, s.since), revisit.init(n), (jnp.asarray(tried), jnp.float32(40.0)))
    nodes = revisit.Nodes(jnp.asarray(node_pose), jnp.asarray(node_t), jnp.asarray(node_mask))
    out = _update(PARAMS, state, nodes, jnp.int32(0), jnp.float32(130.0), pose, _grid(), value, 1.0)
    k = _reference(node_pose, node_t, node_mask, tried, 130.0, pose, value)
    assert bool(out.active) == (k is not None)
    if k is not None:
        np.testing.assert_array_equal(np.asarray(out.goal), node_pose[k])
        near = node_mask & (np.hypot(*(node_pose[:, :2] - node_pose[k, :2]).T) <= 0.5)
        np.testing.assert_array_equal(np.asarray(out.tried), tried | near)
        assert int(out.started) == 1


def _one_node_case():
    """A robot at (1, 1) and one node 1.5 m away, 100 s old, on an open grid."""
    node_pose = jnp.array([[2.5, 1.0, 0.7]], jnp.float32)
    pose = jnp.array([1.0, 1.0, 0.0], jnp.float32)
    rows, cols = np.indices(SHAPE)
    value = jnp.asarray(np.hypot(cols + 0.5 - 20, rows + 0.5 - 20), jnp.float32)
    return node_pose, jnp.array([0.0], jnp.float32), jnp.array([True]), pose, value


def _step(state, pose, loops=0, t=100.0, elapsed=1.0, params=PARAMS, running=True, nodes=None):
    node_pose, node_t, mask, _, value = _one_node_case()
    nodes = revisit.Nodes(node_pose, node_t, mask) if nodes is None else nodes
    return _update(params, state, nodes, jnp.int32(loops), jnp.float32(t), pose, _grid(), value, elapsed, running)


def test_a_revisit_starts_only_after_the_time_without_a_closure_and_never_with_after_inf():
    node_pose, _, _, pose, _ = _one_node_case()
    s = revisit.init(1)
    for _ in range(29):
        s = _step(s, pose)
        assert not bool(s.active)
    s = _step(s, pose)  # 30 s without a closure
    assert bool(s.active)
    np.testing.assert_array_equal(np.asarray(s.goal), np.asarray(node_pose[0]))
    s = revisit.init(1)
    never = revisit.RevisitParams.default(after=np.inf)
    for _ in range(5):
        s = _step(s, pose, elapsed=100.0, params=never)
    assert not bool(s.active) and int(s.started) == 0


def test_a_closure_resets_the_clock_and_ends_a_revisit():
    _, _, _, pose, _ = _one_node_case()
    s = _step(revisit.init(1), pose, elapsed=20.0)
    s = _step(s, pose, loops=1, elapsed=20.0)  # a closure at 40 s: the clock starts again
    assert not bool(s.active) and float(s.since) == 0.0
    s = _step(s, pose, loops=1, elapsed=30.0)
    assert bool(s.active)
    s = _step(s, pose, loops=2)
    assert not bool(s.active) and int(s.closed) == 1 and int(s.started) == 1


def test_a_revisit_ends_after_dwelling_at_the_node_or_at_its_timeout_and_is_not_repeated():
    node_pose, _, _, pose, _ = _one_node_case()
    s = _step(revisit.init(1), pose, elapsed=30.0)
    assert bool(s.active)
    at_node = node_pose[0] + jnp.array([0.3, 0.0, 0.0])
    s = _step(s, at_node)  # 1 s there
    assert bool(s.active)
    s = _step(s, at_node)  # 2 s: dwell done
    assert not bool(s.active) and float(s.since) == 0.0 and int(s.closed) == 0
    s = _step(s, pose, elapsed=30.0)  # the only node was tried: nothing to revisit
    assert not bool(s.active) and int(s.started) == 1

    s = _step(revisit.init(1), pose, elapsed=30.0)
    for _ in range(19):
        s = _step(s, pose)
        assert bool(s.active)
    s = _step(s, pose)  # 20 s away without getting there
    assert not bool(s.active)


def test_nodes_added_where_a_revisit_ended_are_tried_and_an_ended_run_starts_none():
    node_pose, node_t, mask, pose, _ = _one_node_case()
    s = _step(
        revisit.init(2), pose, elapsed=30.0, nodes=revisit.Nodes(*(jnp.r_[a, a] for a in (node_pose, node_t, mask)))
    )
    assert bool(s.active) and np.asarray(s.tried).all()  # both slots hold the node: both tried at the start
    # Two slots: the revisited node, and one the SLAM adds 0.3 m from it while the robot waits there.
    two = jnp.r_[node_pose, node_pose + jnp.array([[0.3, 0.0, 0.0]])]
    s = _step(revisit.init(2), pose, elapsed=30.0, nodes=revisit.Nodes(two, jnp.zeros(2), jnp.array([True, False])))
    assert bool(s.active) and np.asarray(s.tried).tolist() == [True, False]
    at_node = node_pose[0] + jnp.array([0.2, 0.0, 0.0])
    for _ in range(2):
        s = _step(s, at_node, nodes=revisit.Nodes(two, jnp.zeros(2), jnp.array([True, True])))
    assert not bool(s.active) and np.asarray(s.tried).tolist() == [True, True]

    s = _step(revisit.init(1), pose, elapsed=30.0)
    assert bool(s.active)
    s = _step(s, pose, running=False)  # the run ended: the revisit with it, and no other begins
    assert not bool(s.active)
    s = _step(revisit.init(1), pose, elapsed=100.0, running=False)  # an untried node, the clock long past
    assert not bool(s.active) and int(s.started) == 0
