"""KITTI segment drift against a NumPy loop implementation of the KITTI devkit's definition, and
closed forms (perfect, stationary, scaled, turning estimates)."""

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from jaxquad.metrics import evaluate_batch, evaluate_drift


def _poses(p, q_xyzw):
    """4x4 homogeneous poses."""
    T = np.tile(np.eye(4), (len(p), 1, 1))
    T[:, :3, :3] = Rotation.from_quat(q_xyzw).as_matrix()
    T[:, :3, 3] = p
    return T


def kitti_drift(p_gt, q_gt, p_est, q_est, lengths, step):
    """The KITTI odometry devkit's t_rel / r_rel, written from its definition with plain loops:
    (overall t %, overall r deg/m, per-length t, per-length r, per-length counts)."""
    gt, est = _poses(p_gt, q_gt), _poses(p_est, q_est)
    dist = [0.0]
    for k in range(1, len(gt)):
        dist.append(dist[-1] + float(np.linalg.norm(gt[k, :3, 3] - gt[k - 1, :3, 3])))
    errors = {length: [] for length in lengths}
    for first in range(0, len(gt), step):
        for length in lengths:
            last = None
            for k in range(first, len(gt)):
                if dist[k] > dist[first] + length:
                    last = k
                    break
            if last is None:
                continue
            delta_gt = np.linalg.inv(gt[first]) @ gt[last]
            delta_est = np.linalg.inv(est[first]) @ est[last]
            E = np.linalg.inv(delta_gt) @ delta_est
            cos = 0.5 * (E[0, 0] + E[1, 1] + E[2, 2] - 1.0)
            r = np.arccos(max(min(cos, 1.0), -1.0))
            t = np.linalg.norm(E[:3, 3])
            errors[length].append((100.0 * t / length, np.degrees(r) / length))
    every = [e for length in lengths for e in errors[length]]
    mean = lambda rows, k: float(np.mean([e[k] for e in rows])) if rows else float("nan")
    return (
        mean(every, 0),
        mean(every, 1),
        [mean(errors[x], 0) for x in lengths],
        [mean(errors[x], 1) for x in lengths],
        [len(errors[x]) for x in lengths],
    )


def _loop(n, rng, noise, turns=1.0):
    """A 3-D loop of ~50 m with turning attitude, and an estimate that accumulates heading and
    position errors (a random walk), as odometry does."""
    s = np.linspace(0.0, 2 * np.pi * turns, n)
    p = np.stack([9 * np.cos(s), 7 * np.sin(s), 0.3 * np.sin(3 * s)], 1)
    rv = np.stack([0.05 * np.sin(2 * s), 0.04 * np.cos(3 * s), s + np.pi / 2], 1)
    q = Rotation.from_rotvec(rv).as_quat()
    yaw_err = np.cumsum(noise * rng.normal(size=n))
    rv_est = rv + np.stack([0 * s, 0 * s, yaw_err], 1)
    p_est = p + np.cumsum(noise * rng.normal(size=(n, 3)), axis=0)
    return p, q, p_est, Rotation.from_rotvec(rv_est).as_quat()


def _line(n, h, yaw=0.3):
    """Straight walk along a heading `yaw`, h metres a pose, constant attitude."""
    u = np.array([np.cos(yaw), np.sin(yaw), 0.0])
    p = np.outer(np.arange(n) * h, u)
    q = np.tile(Rotation.from_euler("z", yaw).as_quat(), (n, 1))
    return p, q


def _first_exceeding_steps(length, h):
    """Poses from a segment's start to its end on a uniform line: the first k with k h > L."""
    k = int(np.floor(length / h)) + 1
    assert abs(length / h - round(length / h)) > 1e-3  # away from ties, so rounding cannot flip k
    return k


@pytest.mark.parametrize(("lengths", "step", "seed"), [((2.0, 5.0, 10.0), 10, 0), ((1.5, 7.0, 60.0), 3, 1)])
def test_matches_kitti_definition(lengths, step, seed):
    p, q, p_est, q_est = _loop(400, np.random.default_rng(seed), 0.01)
    d = evaluate_drift(p, q, p_est, q_est, lengths, step)
    t, r, t_len, r_len, n_len = kitti_drift(p, q, p_est, q_est, lengths, step)
    np.testing.assert_array_equal(d.n_segments_per_length, n_len)
    assert d.n_segments == sum(n_len) and d.step == step
    np.testing.assert_allclose(d.trans_pct, t, rtol=1e-9)
    np.testing.assert_allclose(d.rot_deg_per_m, r, rtol=1e-6)  # acos in the oracle loses digits near 0
    np.testing.assert_allclose(d.trans_pct_per_length, t_len, rtol=1e-9)
    np.testing.assert_allclose(d.rot_deg_per_m_per_length, r_len, rtol=1e-6)
    assert d.trans_pct > 0.1 and d.rot_deg_per_m > 0.01  # a real error, not a trivially zero one


def test_alignment_free():
    p, q, p_est, q_est = _loop(300, np.random.default_rng(2), 0.01)
    R = Rotation.from_rotvec([0.3, -0.2, 1.1])
    moved = evaluate_drift(
        p,
        q,
        R.apply(p_est) + [4.0, -2.0, 1.0],
        (R * Rotation.from_quat(q_est)).as_quat(),
    )
    d = evaluate_drift(p, q, p_est, q_est)
    np.testing.assert_allclose(moved.trans_pct_per_length, d.trans_pct_per_length, rtol=1e-9)
    np.testing.assert_allclose(moved.rot_deg_per_m_per_length, d.rot_deg_per_m_per_length, rtol=1e-6)


def test_perfect_estimate_is_zero():
    p, q, _, _ = _loop(300, np.random.default_rng(3), 0.0)
    d = evaluate_drift(p, q, p, q)
    assert d.n_segments > 0
    np.testing.assert_allclose([d.trans_pct, d.rot_deg_per_m], 0.0, atol=1e-9)


@pytest.mark.parametrize("s", [0.0, 0.9, 1.25])
def test_scaled_and_stationary_on_a_line(s):
    """Estimate = s x truth along a straight walk (s = 0: it stands still): t_rel = |1 - s| k h / L
    with k h the true length of the segment (first pose past L), i.e. about |1 - s| x 100 %."""
    h, lengths = 0.03, (2.0, 5.0, 10.0)
    p, q = _line(600, h)
    p_est = s * p + [1.0, 2.0, 0.5]  # an offset changes nothing
    d = evaluate_drift(p, q, p_est, q, lengths)
    expected = [100 * abs(1 - s) * _first_exceeding_steps(length, h) * h / length for length in lengths]
    np.testing.assert_allclose(d.trans_pct_per_length, expected, rtol=1e-9)
    n_len = [len(range(0, 600 - _first_exceeding_steps(length, h), 10)) for length in lengths]
    np.testing.assert_array_equal(d.n_segments_per_length, n_len)
    np.testing.assert_allclose(d.trans_pct, np.dot(expected, n_len) / sum(n_len), rtol=1e-9)
    np.testing.assert_allclose(d.rot_deg_per_m, 0.0, atol=1e-9)
    if s == 0.0:
        assert 100.0 <= d.trans_pct < 101.6


def test_turning_in_place_closed_form():
    """Truth walks a line; the estimate has the right positions but turns w rad a pose: the error
    rotation of a k-pose segment is w k rad, so r_rel = deg(w k) / L."""
    h, w, length = 0.03, 0.002, 2.0
    p, q = _line(200, h, yaw=0.0)
    q_est = Rotation.from_euler("z", w * np.arange(200)[:, None]).as_quat()
    d = evaluate_drift(p, q, p, q_est, (length,), step=1)
    k = _first_exceeding_steps(length, h)
    np.testing.assert_allclose(d.rot_deg_per_m, np.degrees(w * k) / length, rtol=1e-9)
    # Translation error: the start heading w i rotates the true chord k h: 2 k h sin(w i / 2), averaged.
    i = np.arange(0, 200 - k)
    np.testing.assert_allclose(d.trans_pct, 100 * np.mean(2 * k * h * np.sin(w * i / 2)) / length, rtol=1e-9)


def test_too_short_is_nan_with_zero_segments():
    p, q = _line(50, 0.03)  # 1.47 m of path
    d = evaluate_drift(p, q, p, q, (1.0, 2.0))
    np.testing.assert_array_equal(d.n_segments_per_length, [len(range(0, 50 - 34, 10)), 0])
    assert np.isfinite(d.trans_pct_per_length[0]) and np.isnan(d.trans_pct_per_length[1])
    assert np.isfinite(d.trans_pct)  # the overall mean covers the segments there are
    none = evaluate_drift(p, q, p, q, (2.0, 5.0))
    assert none.n_segments == 0 and np.isnan(none.trans_pct) and np.isnan(none.rot_deg_per_m)
    assert np.all(np.isnan(none.rot_deg_per_m_per_length))
    empty = evaluate_drift(np.zeros((0, 3)), np.zeros((0, 4)), np.zeros((0, 3)), np.zeros((0, 4)))
    assert empty.n_segments == 0 and np.isnan(empty.trans_pct)


def test_bad_input_is_one_line():
    p, q = _line(50, 0.03)
    for args, message in [
        ((p, q, p, q, (0.0,)), "positive"),
        ((p, q, p, q, (2.0,), 0), "step"),
        ((p, q, p[:-1], q[:-1]), "arrays twice"),
        ((p * np.nan, q, p, q), "NaN"),
        ((p, q, p, 0 * q), "zero quaternion"),
    ]:
        with pytest.raises(ValueError, match=message):
            evaluate_drift(*args)


def test_batched_float32_matches_single_float64():
    rng = np.random.default_rng(4)
    trajs = [_loop(300, rng, 0.005 * (k + 1)) for k in range(3)]
    arrays = [np.stack([t[f] for t in trajs]).astype(np.float32) for f in range(4)]
    batch = evaluate_batch(*arrays, align="se3")
    assert batch.drift.trans_pct.dtype == np.float32 and batch.drift.trans_pct.shape == (3,)
    for k in range(len(trajs)):
        single = evaluate_drift(*(a[k].astype(np.float64) for a in arrays))
        np.testing.assert_array_equal(
            np.asarray(batch.drift.n_segments_per_length)[k],
            single.n_segments_per_length,
        )
        np.testing.assert_allclose(
            np.asarray(batch.drift.trans_pct_per_length)[k], single.trans_pct_per_length, rtol=2e-3
        )
        np.testing.assert_allclose(
            np.asarray(batch.drift.rot_deg_per_m_per_length)[k], single.rot_deg_per_m_per_length, rtol=2e-3
        )
