"""`kernels.bias_filter` against the batch least-squares posterior of the same linear-Gaussian model (NumPy), and its
chi-square gate."""

from __future__ import annotations

import jax.numpy as jnp
import numpy as np

from jaxquad.kernels.bias_filter import BiasFilter, bias_filter_init, bias_predict, bias_update


def _spd(rng, n, scale):
    A = rng.normal(size=(n, n))
    return scale * (A @ A.T / n + 0.5 * np.eye(n))


def _batch_posterior(x0, P0, steps):
    """Mean and covariance of the last state given every prior, step and measurement, by one weighted least-squares
    solve over all states [p_0, b_0, ..., p_N, b_N] (the smoother's joint posterior, marginalized)."""
    N = len(steps)
    n = 4 * (N + 1)
    rows, rhs, weights = [], [], []

    def add(A, r, W):
        rows.append(A)
        rhs.append(r)
        weights.append(np.linalg.inv(W))

    A = np.zeros((4, n))
    A[:, :4] = np.eye(4)
    add(A, x0, P0)
    for k, (d, G, Q, walk, m, R) in enumerate(steps, start=1):
        A = np.zeros((2, n))  # p_k - p_(k-1) + G b_(k-1) = d + w
        A[:, 4 * k : 4 * k + 2] = np.eye(2)
        A[:, 4 * (k - 1) : 4 * (k - 1) + 2] = -np.eye(2)
        A[:, 4 * (k - 1) + 2 : 4 * k] = G
        add(A, d, Q)
        A = np.zeros((2, n))  # b_k - b_(k-1) = u
        A[:, 4 * k + 2 : 4 * k + 4] = np.eye(2)
        A[:, 4 * (k - 1) + 2 : 4 * k] = -np.eye(2)
        add(A, np.zeros(2), walk)
        if m is not None:
            A = np.zeros((2, n))
            A[:, 4 * k : 4 * k + 2] = np.eye(2)
            add(A, m, R)
    import scipy.linalg

    A = np.vstack(rows)
    W = scipy.linalg.block_diag(*weights)
    r = np.concatenate(rhs)
    info = A.T @ W @ A
    cov = np.linalg.inv(info)
    mean = cov @ (A.T @ W @ r)
    return mean[-4:], cov[-4:, -4:]


def test_filter_equals_the_batch_posterior():
    rng = np.random.default_rng(3)
    x0 = rng.normal(size=4) * [1.0, 1.0, 0.01, 0.01]
    P0 = _spd(rng, 4, 0.01)
    steps = []
    for k in range(25):
        theta = rng.uniform(-np.pi, np.pi)
        c, s = np.cos(theta), np.sin(theta)
        G = np.array([[c, -s], [s, c]]) * rng.uniform(0.3, 0.7)
        m = rng.normal(size=2) if k % 3 != 1 else None  # every third step without a match
        steps.append((rng.normal(size=2) * 0.1, G, _spd(rng, 2, 1e-4), np.diag([1e-6, 3e-6]), m, _spd(rng, 2, 4e-4)))
    f = BiasFilter(x=jnp.asarray(x0, jnp.float32), P=jnp.asarray(P0, jnp.float32))
    for d, G, Q, walk, m, R in steps:
        f = bias_predict(f, *(jnp.asarray(a, jnp.float32) for a in (d, G, Q, np.diag(walk))))
        use = m is not None
        meas = jnp.asarray(m if use else np.zeros(2), jnp.float32)
        f, _, used = bias_update(f, meas, jnp.asarray(R, jnp.float32), jnp.asarray(1e9), jnp.asarray(use))
        assert bool(used) == use
    mean, cov = _batch_posterior(x0, P0, steps)
    np.testing.assert_allclose(f.x, mean, rtol=1e-3, atol=1e-5)
    np.testing.assert_allclose(f.P, cov, rtol=2e-3, atol=1e-8)


def test_bias_is_learned_from_matches_and_the_gate_drops_outliers():
    """Displacements read 5 mm/s too far sideways (base frame, heading 30 deg); exact matches of the true position
    every half second teach the filter that bias, and a match 1 m off is refused with the chi-square it reports."""
    b_true = np.array([0.0, 0.005])
    theta = np.radians(30.0)
    R = np.array([[np.cos(theta), -np.sin(theta)], [np.sin(theta), np.cos(theta)]])
    f = bias_filter_init(jnp.zeros(2, jnp.float32), jnp.zeros(2, jnp.float32), jnp.full(2, 0.01, jnp.float32))
    f32 = lambda a: jnp.asarray(a, jnp.float32)  # noqa: E731
    R_match, gate, yes = 1e-4 * jnp.eye(2), jnp.asarray(9.21), jnp.asarray(True)
    p_true = np.zeros(2)
    dt, v = 0.5, np.array([0.1, 0.0])
    for _ in range(400):
        p_true = p_true + R @ v * dt
        d = R @ (v + b_true) * dt
        f = bias_predict(f, f32(d), f32(R * dt), 1e-6 * jnp.eye(2), jnp.full(2, 1e-10))
        f, _, used = bias_update(f, f32(p_true), R_match, gate, yes)
        assert bool(used)
    np.testing.assert_allclose(f.bias, b_true, atol=5e-4)
    y = np.array([1.0, 0.0])
    S = np.asarray(f.P[:2, :2]) + 1e-4 * np.eye(2)
    bad, chi2, used = bias_update(f, f.x[:2] + f32(y), R_match, gate, yes)
    assert not bool(used) and float(chi2) > 9.21
    np.testing.assert_allclose(float(chi2), y @ np.linalg.solve(S, y), rtol=1e-3)
    np.testing.assert_array_equal(bad.x, f.x)


def test_a_known_bias_stays_and_a_prior_mean_is_where_learning_starts():
    """A prior mean with std 0 is a known bias: predictions take it out and matches leave it as it is; with a std the
    filter starts from the mean (the batch posterior's prior) and moves away from it as matches disagree."""
    f32 = lambda a: jnp.asarray(a, jnp.float32)  # noqa: E731
    p0, mean = f32([1.0, 2.0]), f32([0.0, -0.004])
    known = bias_filter_init(p0, mean, f32([0.0, 0.0]))
    np.testing.assert_array_equal(known.x, np.float32([1.0, 2.0, 0.0, -0.004]))
    np.testing.assert_array_equal(known.P, np.zeros((4, 4)))
    G, d = f32(0.5 * np.eye(2)), f32([0.05, 0.0])
    moved = bias_predict(known, d, G, f32(1e-6 * np.eye(2)), f32([0.0, 0.0]))
    np.testing.assert_allclose(moved.x, [1.05, 2.002, 0.0, -0.004], atol=1e-7)  # p + d - G b
    after, _, used = bias_update(moved, f32([1.05, 2.0]), f32(1e-4 * np.eye(2)), jnp.asarray(9.21), jnp.asarray(True))
    assert bool(used) and float(after.x[3]) == float(mean[1]) and float(after.x[2]) == 0.0  # no variance: no gain on b
    learning = bias_filter_init(p0, mean, f32([0.01, 0.01]))
    x0, P0 = np.concatenate([p0, mean]), np.diag([0.0, 0.0, 1e-4, 1e-4]) + 1e-12 * np.eye(4)
    steps = [(np.asarray(d), np.asarray(G), 1e-6 * np.eye(2), np.zeros((2, 2)) + 1e-12 * np.eye(2), m, 1e-4 * np.eye(2))
             for m in (np.array([1.05, 2.0]), np.array([1.10, 2.0]))]  # fmt: skip
    f = learning
    for d_, G_, Q, walk, m, R in steps:
        f = bias_predict(f, f32(d_), f32(G_), f32(Q), f32(np.diag(walk)))
        f, _, _ = bias_update(f, f32(m), f32(R), jnp.asarray(1e9), jnp.asarray(True))
    mean_ref, _ = _batch_posterior(x0, P0, steps)
    np.testing.assert_allclose(f.x, mean_ref, rtol=1e-3, atol=2e-5)
    assert float(f.x[3]) > -0.004  # the matches, which see no sideways drift, pull the bias towards 0
