"""spd_solve and spd_inverse against numpy.linalg in float64: well-conditioned and near-singular SPD
matrices, several right-hand sides, under jit and vmap, gradients against the closed form d(A^-1 b),
and a non-SPD matrix flagged by non-finite output."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxquad.kernels._small_linalg import spd_inverse, spd_solve

_solve = jax.jit(spd_solve)
_solve_batch = jax.jit(jax.vmap(spd_solve))


def _spd(rng, n, cond):
    """Random SPD matrix with eigenvalues log-spaced from 1 down to 1/cond, in a random basis."""
    Q, _ = np.linalg.qr(rng.standard_normal((n, n)))
    return (Q * np.logspace(0, -np.log10(cond), n)) @ Q.T


@pytest.mark.parametrize("n", [1, 2, 3, 4, 6])
@pytest.mark.parametrize("cond", [10.0, 1e4])
def test_matches_numpy_solve(n, cond):
    rng = np.random.default_rng(n)
    for _ in range(20):
        A = np.asarray(_spd(rng, n, cond) * rng.uniform(0.1, 100.0), np.float32).astype(np.float64)
        A = 0.5 * (A + A.T)
        b = rng.standard_normal(n).astype(np.float32).astype(np.float64)
        x = np.asarray(_solve(jnp.asarray(A, jnp.float32), jnp.asarray(b, jnp.float32)), np.float64)
        ref = np.linalg.solve(A, b)
        # Backward-stable solve: forward error within a small multiple of cond * eps.
        assert np.linalg.norm(x - ref) <= 2 * n * cond * 2.0**-23 * np.linalg.norm(ref)


def test_near_singular_gram_matrix_like_the_observer():
    # J J^T + lambda I with two nearly parallel rows: cond ~ 1e5, as a foot over another foot.
    rng = np.random.default_rng(1)
    for _ in range(20):
        J = rng.standard_normal((4, 18)) * 0.3
        J[1] = J[0] + 1e-3 * rng.standard_normal(18)
        A = (J @ J.T + 1e-4 * np.eye(4)).astype(np.float32).astype(np.float64)
        b = rng.standard_normal(4).astype(np.float32).astype(np.float64)
        x = np.asarray(_solve(jnp.asarray(A, jnp.float32), jnp.asarray(b, jnp.float32)), np.float64)
        ref = np.linalg.solve(A, b)
        assert np.all(np.isfinite(x))
        assert np.linalg.norm(x - ref) <= 4 * np.linalg.cond(A) * 2.0**-23 * np.linalg.norm(ref)
        # The residual stays small whatever the conditioning.
        assert np.linalg.norm(A @ x - b) <= 1e-6 * (np.linalg.norm(A, 2) * np.linalg.norm(x) + np.linalg.norm(b))


def test_vmap_matches_numpy_per_matrix():
    rng = np.random.default_rng(2)
    A = np.stack([_spd(rng, 4, 100.0) for _ in range(16)])
    b = rng.standard_normal((16, 4))
    x = _solve_batch(jnp.asarray(A, jnp.float32), jnp.asarray(b, jnp.float32))
    assert x.shape == (16, 4)
    np.testing.assert_allclose(x, np.linalg.solve(A, b[..., None])[..., 0], rtol=1e-4, atol=1e-4)


def test_gradient_matches_closed_form():
    # A = M M^T + I keeps A symmetric, so the gradient in M goes through both triangles of A.
    # For x = A^-1 b and loss c . x: d/db = A^-T c = y, d/dA = -y x^T, d/dM = d/dA (M) + (d/dA)^T M.
    rng = np.random.default_rng(3)
    M, b, c = rng.standard_normal((4, 4)), rng.standard_normal(4), rng.standard_normal(4)

    def loss(M, b):
        return jnp.asarray(c, jnp.float32) @ spd_solve(M @ M.T + jnp.eye(4), b)

    gM, gb = jax.jit(jax.grad(loss, argnums=(0, 1)))(jnp.asarray(M, jnp.float32), jnp.asarray(b, jnp.float32))
    A = M @ M.T + np.eye(4)
    x = np.linalg.solve(A, b)
    y = np.linalg.solve(A.T, c)
    gA = -np.outer(y, x)
    np.testing.assert_allclose(gb, y, rtol=1e-4, atol=1e-5)
    np.testing.assert_allclose(gM, gA @ M + gA.T @ M, rtol=1e-4, atol=1e-5)


def test_not_positive_definite_is_not_a_finite_answer():
    # A zero pivot (singular) or a negative one (indefinite) must not pass as a solution.
    singular = jnp.array([[1.0, 1.0], [1.0, 1.0]])
    assert not np.all(np.isfinite(_solve(singular, jnp.array([1.0, 0.0]))))
    indefinite = jnp.array([[1.0, 2.0], [2.0, 1.0]])
    x = np.asarray(_solve(indefinite, jnp.array([1.0, 0.0])))
    # LDL^T of an indefinite matrix still solves it exactly when no pivot is zero: x = A^-1 b.
    np.testing.assert_allclose(x, np.linalg.solve(np.array([[1.0, 2.0], [2.0, 1.0]]), [1.0, 0.0]), rtol=1e-6)


@pytest.mark.parametrize("n", [2, 3, 4])
@pytest.mark.parametrize("cond", [10.0, 1e4])
def test_inverse_and_several_right_hand_sides_match_numpy(n, cond):
    rng = np.random.default_rng(10 + n)
    inverse, solve = jax.jit(spd_inverse), jax.jit(spd_solve)
    for _ in range(20):
        A = np.asarray(_spd(rng, n, cond) * rng.uniform(0.1, 1e4), np.float32).astype(np.float64)
        A = 0.5 * (A + A.T)
        B = rng.standard_normal((n, 5)).astype(np.float32).astype(np.float64)
        X = np.asarray(inverse(jnp.asarray(A, jnp.float32)), np.float64)
        ref = np.linalg.inv(A)
        assert np.array_equal(X, X.T)  # exactly symmetric, as an information or covariance must be
        assert np.linalg.norm(X - ref) <= 4 * n * cond * 2.0**-23 * np.linalg.norm(ref)
        Y = np.asarray(solve(jnp.asarray(A, jnp.float32), jnp.asarray(B, jnp.float32)), np.float64)
        assert Y.shape == (n, 5)
        ref_Y = np.linalg.solve(A, B)
        assert np.linalg.norm(Y - ref_Y) <= 4 * n * cond * 2.0**-23 * np.linalg.norm(ref_Y)


def test_inverse_reads_the_lower_triangle_and_maps_over_a_batch():
    rng = np.random.default_rng(4)
    A = np.stack([_spd(rng, 3, 100.0) for _ in range(16)])
    garbage = A + np.triu(rng.standard_normal((16, 3, 3)), 1)  # only the strict upper triangle changed
    X = jax.jit(jax.vmap(spd_inverse))(jnp.asarray(garbage, jnp.float32))
    np.testing.assert_allclose(X, np.linalg.inv(A), rtol=1e-4, atol=1e-4)
    B = rng.standard_normal((16, 3, 2))
    Y = jax.jit(jax.vmap(spd_solve))(jnp.asarray(A, jnp.float32), jnp.asarray(B, jnp.float32))
    np.testing.assert_allclose(Y, np.linalg.solve(A, B), rtol=1e-4, atol=1e-4)


def test_bad_shapes_raise():
    # Rejected by the explicit check, or first by the tests' runtime shape check (a TypeError).
    with pytest.raises((ValueError, TypeError), match="spd_solve"):
        spd_solve(jnp.eye(3), jnp.ones(4))
    with pytest.raises((ValueError, TypeError), match="spd_solve"):
        spd_solve(jnp.ones((3, 4)), jnp.ones(4))
    with pytest.raises((ValueError, TypeError), match="spd_solve"):
        spd_solve(jnp.eye(3), jnp.ones((3, 2, 2)))
