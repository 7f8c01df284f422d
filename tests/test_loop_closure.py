"""Loop-closure candidates on scans cast by an independent NumPy caster: a loop around a block (found, with
the true relative pose), a corridor of identical pillars (rejected as ambiguous), too-short chains, chains
counted in path for sparse nodes, a match spread too wide (rejected as degenerate)."""

import functools

import jax
import jax.numpy as jnp
import numpy as np
from _laser2d import box, cast

from jaxquad.kernels.lie import SE2
from jaxquad.kernels.loop_closure import LoopParams, LoopSpec, _chains, find_loop_closure

BEARINGS = np.linspace(-np.pi, np.pi, 240, endpoint=False)
CAPACITY = 128
SPEC = LoopSpec()


@functools.partial(jax.jit, static_argnums=0)
def _find(spec, params, poses, ranges, valid, node_mask, j):
    return find_loop_closure(spec, params, poses, ranges, valid, jnp.asarray(BEARINGS, jnp.float32), node_mask, j)


def _path(corners, spacing):
    """Poses every `spacing` m along a polyline, heading along it."""
    out = []
    for a, b in zip(corners[:-1], corners[1:]):
        d = np.subtract(b, a)
        length = np.linalg.norm(d)
        for s in np.arange(0.0, length, spacing):
            out.append([*(a + d * s / length), np.arctan2(d[1], d[0])])
    return np.array(out)


def _nodes(segments, truth, drift):
    """Scans at the true poses; stored poses drift linearly with the node index up to `drift` (x, y, theta)."""
    ranges = np.stack([cast(segments, p, BEARINGS, 6.0) for p in truth])
    est = truth + np.linspace(0, 1, len(truth))[:, None] * np.asarray(drift)
    n = len(truth)
    pad = CAPACITY - n
    f = lambda x: jnp.asarray(np.concatenate([x, np.zeros((pad, *x.shape[1:]))]), jnp.float32)
    valid = np.isfinite(ranges)
    mask = np.arange(CAPACITY) < n
    return f(est), f(np.where(valid, ranges, 0)), jnp.asarray(np.pad(valid, ((0, pad), (0, 0)))), jnp.asarray(mask)


def _relative(a, b):
    T = SE2.from_xy_theta(*a).inverse() @ SE2.from_xy_theta(*b)
    return np.array([*np.asarray(T.translation()), float(T.rotation().as_radians())])


# A 2 m wide corridor around a block, with a few features on its walls so that places differ.
LOOP_WORLD = np.concatenate(
    [
        box(-5, -4, 5, 4),
        box(-3, -2, 3, 2),
        box(-1.0, -4.0, -0.6, -3.6),
        box(1.5, -2.3, 2.3, -2.0),
        box(4.6, 0.5, 5.0, 1.3),
        box(-5.0, -1.0, -4.7, -0.2),
        box(0.0, 3.7, 0.8, 4.0),
    ]
)


def test_loop_found_with_true_relative_pose():
    truth = _path([(0.0, -3.0), (4.0, -3.0), (4.0, 3.0), (-4.0, 3.0), (-4.0, -3.0), (1.5, -3.0)], 0.25)
    drift = (0.5, -0.35, 0.06)  # odometry error accumulated over the loop
    poses, ranges, valid, mask = _nodes(LOOP_WORLD, truth, drift)
    j = len(truth) - 1
    out = _find(SPEC, LoopParams(), poses, ranges, valid, mask, j)
    assert bool(out.accept), out
    i = int(out.i)
    assert int(out.chain_length) >= 7 and i < 20
    est_i = np.asarray(poses[i])
    err = _relative(est_i, np.asarray(out.pose_j)) - _relative(truth[i], truth[j])
    assert np.linalg.norm(err[:2]) < 0.03 and abs(err[2]) < np.deg2rad(1.0)
    np.testing.assert_allclose(np.asarray(out.T_i_j), _relative(est_i, np.asarray(out.pose_j)), atol=1e-4)
    assert float(out.second_response) < 0.9 * float(out.coarse_response)
    assert np.all(np.linalg.eigvalsh(np.asarray(out.covariance)) > 0)
    # Halfway round the loop there is no old place within 3 m: nothing to close.
    half = _find(SPEC, LoopParams(), poses, ranges, valid, mask, 60)
    assert not bool(half.accept) and int(half.chain_length) == 0
    assert float(half.coarse_response) == 0.0 and float(half.fine_response) == 0.0  # no match was run
    # A chain requirement longer than the run of nearby old nodes rejects the same candidate.
    strict = _find(SPEC, LoopParams(min_chain=jnp.asarray(40)), poses, ranges, valid, mask, j)
    assert not bool(strict.accept)


def test_repeated_corridor_rejected_as_ambiguous():
    # A straight corridor with identical pillars every 1.5 m on both walls, driven out and back.
    walls = [np.array([[-2.0, -1.0, 30.0, -1.0], [-2.0, 1.0, 30.0, 1.0], [-2.0, -1.0, -2.0, 1.0]])]
    pillars = [box(x, -1.0, x + 0.3, -0.7) for x in np.arange(-1.5, 30, 1.5)]
    pillars += [box(x, 0.7, x + 0.3, 1.0) for x in np.arange(-1.5, 30, 1.5)]
    world = np.concatenate(walls + pillars)
    out_and_back = np.concatenate([_path([(0.0, 0.0), (12.0, 0.0)], 0.25), _path([(12.0, 0.1), (1.0, 0.1)], 0.25)])
    # Drift along the corridor: the robot believes it is 1.2 m from where it is, near a period away.
    poses, ranges, valid, mask = _nodes(world, out_and_back, (1.2, 0.0, 0.0))
    j = len(out_and_back) - 1
    out = _find(SPEC, LoopParams(), poses, ranges, valid, mask, j)
    assert int(out.chain_length) >= 7
    assert float(out.coarse_response) >= 0.35 and float(out.fine_response) >= 0.45  # confident on its own ...
    assert float(out.second_response) >= 0.9 * float(out.coarse_response)  # ... but a period away looks the same
    assert not bool(out.accept)
    lenient = _find(SPEC, LoopParams(ambiguity_ratio=jnp.asarray(1.01)), poses, ranges, valid, mask, j)
    assert bool(lenient.accept)  # the ambiguity test is what rejects it


def test_vmapped_over_robots_equals_single():
    truth = _path([(0.0, -3.0), (4.0, -3.0), (4.0, 3.0), (-4.0, 3.0), (-4.0, -3.0), (1.5, -3.0)], 0.25)
    a = _nodes(LOOP_WORLD, truth, (0.5, -0.35, 0.06))
    b = _nodes(LOOP_WORLD, truth, (-0.3, 0.4, -0.05))
    # The third robot is halfway round, with no chain to match: its matches are skipped, the others' not.
    js = jnp.array([len(truth) - 1, len(truth) - 3, 60])
    stacked = [jnp.stack([x, y, y]) for x, y in zip(a, b)]
    bearings = jnp.asarray(BEARINGS, jnp.float32)

    def one(poses, ranges, valid, mask, j):
        return find_loop_closure(SPEC, LoopParams(), poses, ranges, valid, bearings, mask, j)

    fleet = jax.jit(jax.vmap(one))(*stacked, js)
    for k, args in enumerate((a, b)):
        single = _find(SPEC, LoopParams(), *args, js[k])
        assert bool(fleet.accept[k]) == bool(single.accept) and bool(single.accept)
        np.testing.assert_allclose(np.asarray(fleet.T_i_j[k]), np.asarray(single.T_i_j), atol=1e-5)
    assert int(fleet.chain_length[2]) == 0 and not bool(fleet.accept[2]) and float(fleet.coarse_response[2]) == 0.0


def test_degenerate_match_rejected_by_its_spread():
    """The position-spread test against NumPy's largest eigenvalue of the match covariance: a limit just
    below it rejects the loop found above, just above it keeps it."""
    truth = _path([(0.0, -3.0), (4.0, -3.0), (4.0, 3.0), (-4.0, 3.0), (-4.0, -3.0), (1.5, -3.0)], 0.25)
    poses, ranges, valid, mask = _nodes(LOOP_WORLD, truth, (0.5, -0.35, 0.06))
    j = len(truth) - 1
    out = _find(SPEC, LoopParams(), poses, ranges, valid, mask, j)
    assert bool(out.accept)
    largest = float(np.sqrt(np.linalg.eigvalsh(np.asarray(out.covariance, np.float64)[:2, :2]).max()))
    assert largest <= float(LoopParams().max_position_std)
    for scale, accept in ((0.99, False), (1.01, True)):
        p = LoopParams(max_position_std=jnp.asarray(scale * largest, jnp.float32))
        assert bool(_find(SPEC, p, poses, ranges, valid, mask, j).accept) == accept


def _numpy_chains(eligible: np.ndarray, travel: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per node, the length of its run of consecutive eligible nodes and the path the run spans (0 if not
    eligible), by a plain loop."""
    n = len(eligible)
    length, span = np.zeros(n, int), np.zeros(n)
    k = 0
    while k < n:
        if not eligible[k]:
            k += 1
            continue
        end = k
        while end + 1 < n and eligible[end + 1]:
            end += 1
        length[k : end + 1] = end - k + 1
        span[k : end + 1] = travel[end] - travel[k]
        k = end + 1
    return length, span


def test_chain_spans_against_numpy():
    """Each eligible node's run of consecutive eligible nodes: its length and the path it spans, against a
    plain loop over random masks."""
    rng = np.random.default_rng(3)
    for _ in range(20):
        eligible = rng.random(40) < 0.6
        travel = np.cumsum(rng.uniform(0.0, 1.5, 40))
        label, length, span = jax.jit(_chains)(jnp.asarray(eligible), jnp.asarray(travel, jnp.float32))
        want_len, want_span = _numpy_chains(eligible, travel)
        np.testing.assert_array_equal(np.asarray(length), want_len)
        np.testing.assert_allclose(np.asarray(span), want_span, atol=1e-5)
        assert np.all((np.asarray(label) > 0) == eligible)


def test_sparse_nodes_close_the_loop_by_chain_distance():
    """Nodes 1 m apart, as a log that keeps a scan per metre: no run of 7 old nodes fits within the 3 m search
    radius, so the count alone finds no chain; counted in path (3 m) the loop closes with the true relative pose."""
    truth = _path([(0.0, -3.0), (4.0, -3.0), (4.0, 3.0), (-4.0, 3.0), (-4.0, -3.0), (1.5, -3.0)], 1.0)
    poses, ranges, valid, mask = _nodes(LOOP_WORLD, truth, (0.5, -0.35, 0.06))
    j = len(truth) - 1
    est = np.asarray(poses)[: len(truth)]
    travel = np.concatenate([[0.0], np.cumsum(np.hypot(*np.diff(est[:, :2], axis=0).T))])
    near = (np.hypot(*(est[:j, :2] - est[j, :2]).T) < 3.0) & (travel[j] - travel[:j] >= 6.0)
    assert 0 < _numpy_chains(near, travel[:j])[0].max() < 7  # old nodes near node j, but too few in a row
    counted = _find(SPEC, LoopParams(), poses, ranges, valid, mask, j)
    assert int(counted.chain_length) == 0 and not bool(counted.accept)
    spanned = _find(SPEC, LoopParams(min_chain_distance=jnp.asarray(3.0)), poses, ranges, valid, mask, j)
    assert bool(spanned.accept)
    i = int(spanned.i)
    err = _relative(np.asarray(poses[i]), np.asarray(spanned.pose_j)) - _relative(truth[i], truth[j])
    assert np.linalg.norm(err[:2]) < 0.03 and abs(err[2]) < np.deg2rad(1.0)
    # A span longer than the run of nearby old nodes finds nothing either.
    far = _find(SPEC, LoopParams(min_chain_distance=jnp.asarray(8.0)), poses, ranges, valid, mask, j)
    assert not bool(far.accept)
