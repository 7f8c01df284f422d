"""`kernels.chain_filter`: the tree-reduced filter covariance against a sequential NumPy Kalman filter, and against
the plain compounding of the steps when nothing is measured."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxquad.kernels.chain_filter import filtered_covariance


def _kalman(F, Q, h, info, P0):
    """Sequential covariance form of the Kalman filter (float64)."""
    P = P0.copy()
    for k in range(len(F)):
        P = F[k] @ P @ F[k].T + Q[k]
        if info[k] > 0:
            S = h[k] @ P @ h[k] + 1.0 / info[k]
            K = P @ h[k] / S
            P = P - np.outer(K, h[k] @ P)
    return P


def _chain(rng, n, d=4):
    """Random steps shaped like the SLAM's: a heading offset carried unchanged, an SE(2)-like block."""
    F = np.tile(np.eye(d), (n, 1, 1))
    F[:, 1:, 1:] += rng.normal(size=(n, d - 1, d - 1)) * 0.3
    Q = np.zeros((n, d, d))
    L = rng.normal(size=(n, d - 1, d - 1)) * np.array([0.01, 0.01, 0.004])
    Q[:, 1:, 1:] = L @ np.swapaxes(L, 1, 2) + np.diag([1e-5, 1e-5, 1e-6])
    h = np.tile(np.r_[1.0, np.zeros(d - 2), 1.0], (n, 1))
    info = np.where(rng.uniform(size=n) < 0.6, 1.0 / np.deg2rad(rng.uniform(0.5, 3.0, n)) ** 2, 0.0)
    P0 = np.diag(np.r_[np.deg2rad(1.0) ** 2, np.zeros(d - 1)])
    return F, Q, h, info, P0


@pytest.mark.parametrize("n", [1, 2, 5, 37, 300])
def test_matches_sequential_kalman_filter(n):
    rng = np.random.default_rng(n)
    args = _chain(rng, n)
    want = _kalman(*args)
    got = np.asarray(jax.jit(filtered_covariance)(*(jnp.asarray(a, jnp.float32) for a in args)), np.float64)
    scale = np.sqrt(np.outer(np.diag(want), np.diag(want)))
    np.testing.assert_allclose(got, want, atol=1e-5 * scale.max(), rtol=0)
    assert np.all(np.abs(got - want) <= 1e-4 * scale + 1e-12)
    if n >= 37:  # over a long chain the measurements count: the unfiltered covariance is wider
        unfiltered = _kalman(args[0], args[1], args[2], np.zeros(n), args[4])
        assert unfiltered[3, 3] > 1.5 * want[3, 3]


def test_without_measurements_is_the_compounded_sum():
    rng = np.random.default_rng(7)
    F, Q, h, _, P0 = _chain(rng, 20)
    want, Phi = np.zeros((4, 4)), np.eye(4)
    for k in reversed(range(20)):  # sum_k (F_n ... F_k+1) Q_k (...)^T + (F_n ... F_1) P0 (...)^T
        want += Phi @ Q[k] @ Phi.T
        Phi = Phi @ F[k]
    want += Phi @ P0 @ Phi.T
    got = np.asarray(filtered_covariance(*(jnp.asarray(a, jnp.float32) for a in (F, Q, h, np.zeros(20), P0))))
    np.testing.assert_allclose(got, want, rtol=1e-4, atol=1e-6 * np.abs(want).max())
