"""body_twist against rigid-body kinematics and numpy.linalg.lstsq on the stacked weighted rows."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxquad.kernels import Twist, body_twist, rolling_contact

_twist = jax.jit(body_twist)
_twist_batch = jax.jit(jax.vmap(body_twist))


def _skew(a):
    return np.array([[0, -a[2], a[1]], [a[2], 0, -a[0]], [-a[1], a[0], 0]])


def _lstsq_twist(p, v, omega_imu, w, w_imu):
    """Independent reference: the paper's stacked system, rows scaled by sqrt(weight), float64."""
    rows = [np.sqrt(wi) * np.hstack([np.eye(3), -_skew(pi)]) for pi, wi in zip(p, w)]
    rhs = [np.sqrt(wi) * -vi for vi, wi in zip(v, w)]
    rows.append(np.sqrt(w_imu) * np.hstack([np.zeros((3, 3)), np.eye(3)]))
    rhs.append(np.sqrt(w_imu) * omega_imu)
    sol = np.linalg.lstsq(np.vstack(rows), np.concatenate(rhs), rcond=None)[0]
    return sol[:3], sol[3:]


def _random_legs(rng, n_feet=4):
    # Foot positions of a Go2-sized robot standing (base frame, m) plus noise; velocities m/s.
    nominal = np.array([[0.19, 0.14, -0.27], [0.19, -0.14, -0.27], [-0.19, 0.14, -0.27], [-0.19, -0.14, -0.27]])
    p = np.resize(nominal, (n_feet, 3)) + 0.05 * rng.standard_normal((n_feet, 3))
    v = 0.5 * rng.standard_normal((n_feet, 3))
    return p, v, rng.standard_normal(3)


def test_recovers_rigid_twist_with_feet_fixed_in_world():
    rng = np.random.default_rng(0)
    for _ in range(5):
        p, _, omega = _random_legs(rng)
        v_base = rng.standard_normal(3)
        # A foot fixed in the world moves in the base frame at -v_base - omega x p.
        v_foot = -v_base - np.cross(omega, p)
        t = _twist(
            jnp.asarray(p, jnp.float32), jnp.asarray(v_foot, jnp.float32), jnp.asarray(omega, jnp.float32), jnp.ones(4)
        )
        np.testing.assert_allclose(t.v_base, v_base, atol=1e-5)
        np.testing.assert_allclose(t.omega_base, omega, atol=1e-5)
        assert bool(t.linear_observed) and bool(t.valid)
        assert float(t.n_stance) == 4.0


@pytest.mark.parametrize("n_feet", [2, 3, 4, 6])
def test_matches_weighted_lstsq(n_feet):
    rng = np.random.default_rng(n_feet)
    for trial in range(10):
        p, v, omega_imu = _random_legs(rng, n_feet)
        w = rng.uniform(0.0, 1.0, n_feet)
        w[trial % n_feet] = 0.0 if trial % 3 == 0 else w[trial % n_feet]
        w_imu = rng.uniform(0.05, 3.0)
        v_ref, omega_ref = _lstsq_twist(p, v, omega_imu, w, w_imu)
        f32 = lambda a: jnp.asarray(a, jnp.float32)
        t = _twist(f32(p), f32(v), f32(omega_imu), f32(w), f32(w_imu))
        np.testing.assert_allclose(t.omega_base, omega_ref, rtol=1e-4, atol=2e-4)
        np.testing.assert_allclose(t.v_base, v_ref, rtol=1e-4, atol=2e-4)
        np.testing.assert_allclose(t.n_stance, w.sum(), rtol=1e-6)
        assert bool(t.linear_observed) == (w.sum() >= 1.5)


def test_vmap_over_robots_matches_single_calls():
    rng = np.random.default_rng(7)
    legs = [_random_legs(rng) for _ in range(8)]
    p, v, omega = (jnp.asarray(np.stack(x), jnp.float32) for x in zip(*legs))
    w = jnp.asarray(rng.uniform(0, 1, (8, 4)), jnp.float32).at[0].set(0.0)
    w_imu = jnp.full(8, 0.5)
    batch = _twist_batch(p, v, omega, w, w_imu)
    assert batch.v_base.shape == (8, 3) and batch.linear_observed.shape == (8,)
    for i in range(8):
        one = _twist(p[i], v[i], omega[i], w[i], w_imu[i])
        np.testing.assert_allclose(batch.v_base[i], one.v_base, rtol=1e-5, atol=1e-6)
        np.testing.assert_allclose(batch.omega_base[i], one.omega_base, rtol=1e-5, atol=1e-6)
    assert not bool(batch.linear_observed[0])


def test_gradient_matches_finite_differences_of_lstsq():
    rng = np.random.default_rng(3)
    p, v, omega_imu = _random_legs(rng)
    w = np.array([1.0, 0.8, 0.6, 0.3])
    probe = rng.standard_normal(6)

    def ref(x):  # scalar of the float64 reference as a function of the stacked foot data
        v_ref, omega_ref = _lstsq_twist(x[:12].reshape(4, 3), x[12:].reshape(4, 3), omega_imu, w, 1.0)
        return probe @ np.concatenate([v_ref, omega_ref])

    x0 = np.concatenate([p.ravel(), v.ravel()])
    eps = 1e-6
    fd = np.array([(ref(x0 + eps * e) - ref(x0 - eps * e)) / (2 * eps) for e in np.eye(24)])

    def f(x):
        t = body_twist(
            x[:12].reshape(4, 3), x[12:].reshape(4, 3), jnp.asarray(omega_imu, jnp.float32), jnp.asarray(w, jnp.float32)
        )
        return jnp.asarray(probe, jnp.float32) @ jnp.concatenate([t.v_base, t.omega_base])

    g = jax.jit(jax.grad(f))(jnp.asarray(x0, jnp.float32))
    np.testing.assert_allclose(g, fd, rtol=2e-3, atol=2e-3)


def _grads(p, v, omega, w):
    def loss(p, v, omega, w):
        t = body_twist(p, v, omega, w)
        return jnp.sum(t.v_base**2) + jnp.sum(t.omega_base**2) + t.n_stance

    return jax.jit(jax.grad(loss, argnums=(0, 1, 2, 3)))(p, v, omega, w)


@pytest.mark.parametrize("weights", [[0.0, 0.0, 0.0, 0.0], [1.0, 0.0, 0.0, 0.0], [0.7, 0.0, 0.0, 0.2], [1e-9, 0, 0, 0]])
def test_fewer_than_two_feet_is_flagged_without_nan(weights):
    rng = np.random.default_rng(1)
    p, v, omega = (jnp.asarray(a, jnp.float32) for a in _random_legs(rng))
    # Swing feet may carry garbage (e.g. kinematics of a leg not yet read): it must not leak.
    p = p.at[3].set(jnp.nan)
    w = jnp.asarray(weights, jnp.float32)
    if weights[3] > 0:
        p = p.at[3].set(0.1)
    t = _twist(p, v, omega, w)
    assert not bool(t.linear_observed) and bool(t.valid)
    assert np.all(np.isfinite(t.v_base)) and np.all(np.isfinite(t.omega_base))
    for g in _grads(p, v, omega, w):
        assert np.all(np.isfinite(g))
    if sum(weights) <= 1e-6:
        np.testing.assert_allclose(t.omega_base, omega, atol=1e-6)
        np.testing.assert_array_equal(t.v_base, np.zeros(3))
    elif weights.count(0.0) == 3:
        # One foot: omega comes from the gyro alone and v_base is that foot's rigid-body solution.
        np.testing.assert_allclose(t.omega_base, omega, atol=1e-6)
        np.testing.assert_allclose(t.v_base, -np.cross(omega, p[0]) - v[0], atol=1e-6)


def test_non_finite_stance_input_gives_invalid_zero_twist():
    rng = np.random.default_rng(2)
    p, v, omega = (jnp.asarray(a, jnp.float32) for a in _random_legs(rng))
    for bad in (dict(p=p.at[1, 2].set(jnp.inf)), dict(v=v.at[0, 0].set(jnp.nan)), dict(omega=omega.at[2].set(jnp.nan))):
        args = dict(p=p, v=v, omega=omega, w=jnp.ones(4)) | bad
        t = _twist(args["p"], args["v"], args["omega"], args["w"])
        assert not bool(t.valid) and not bool(t.linear_observed)
        np.testing.assert_array_equal(np.concatenate([t.v_base, t.omega_base]), np.zeros(6))
        for g in _grads(args["p"], args["v"], args["omega"], args["w"]):
            assert np.all(np.isfinite(g))


def test_twist_is_a_pytree_with_typed_leaves():
    t = _twist(jnp.zeros((4, 3)), jnp.zeros((4, 3)), jnp.zeros(3), jnp.ones(4))
    assert isinstance(t, Twist)
    assert t.linear_observed.dtype == jnp.bool_ and t.n_stance.shape == ()


# --- rolling contact and covariance ---

_rolling = jax.jit(rolling_contact)


def test_rolling_contact_recovers_base_velocity_of_a_rolling_sphere():
    """A sphere rolling without slipping: its centre moves at omega_foot x (r n) in the world. The
    centre-fixed model misses that; the contact-point model recovers the rigid base twist."""
    rng = np.random.default_rng(11)
    for _ in range(5):
        p, _, omega = _random_legs(rng)
        v_base = rng.standard_normal(3)
        n = rng.standard_normal(3)
        n /= np.linalg.norm(n)
        r = np.array([0.022, 0.02, 0.0, 0.03])
        omega_rel = rng.standard_normal((4, 3))  # foot body rate relative to the base
        # World velocity of the centre (base axes) for rolling: (omega + omega_rel) x (r n).
        v_centre_world = np.cross(omega + omega_rel, r[:, None] * n)
        v_foot = v_centre_world - v_base - np.cross(omega, p)
        f32 = lambda a: jnp.asarray(a, jnp.float32)  # noqa: E731
        pc, vc = _rolling(f32(p), f32(v_foot), f32(omega_rel), f32(r), f32(n))
        np.testing.assert_allclose(pc, p - r[:, None] * n, atol=1e-6)
        t = _twist(pc, vc, f32(omega), jnp.ones(4))
        np.testing.assert_allclose(t.v_base, v_base, atol=1e-5)
        t_point = _twist(f32(p), f32(v_foot), f32(omega), jnp.ones(4))
        assert np.linalg.norm(t_point.v_base - v_base) > 1e-3


@pytest.mark.parametrize("n_feet", [2, 3, 4])
def test_covariance_is_sigma2_times_inverse_normal_matrix(n_feet):
    rng = np.random.default_rng(20 + n_feet)
    for _ in range(5):
        p, v, omega_imu = _random_legs(rng, n_feet)
        w = rng.uniform(0.3, 1.0, n_feet)
        w_imu, s0, nu0 = rng.uniform(0.1, 2.0), rng.uniform(0.02, 0.2), rng.uniform(0.5, 5.0)
        A = np.vstack([np.hstack([np.eye(3), -_skew(pi)]) for pi in p] + [np.hstack([np.zeros((3, 3)), np.eye(3)])])
        W = np.diag(np.concatenate([np.repeat(w, 3), np.full(3, w_imu)]))
        v_ref, omega_ref = _lstsq_twist(p, v, omega_imu, w, w_imu)
        res = np.array([v_ref + np.cross(omega_ref, pi) + vi for pi, vi in zip(p, v)])
        sigma2 = (nu0 * s0**2 + np.sum(w * (res**2).sum(1))) / (nu0 + 3 * w.sum() - 3)
        cov_ref = sigma2 * np.linalg.inv(A.T @ W @ A)[:3, :3]
        f32 = lambda a: jnp.asarray(a, jnp.float32)  # noqa: E731
        t = _twist(f32(p), f32(v), f32(omega_imu), f32(w), f32(w_imu), 1.5, f32(s0), f32(nu0))
        np.testing.assert_allclose(t.residual, res, atol=2e-4)
        np.testing.assert_allclose(t.cov_v_base, cov_ref, rtol=2e-3, atol=1e-7)


@pytest.mark.parametrize("prior_dof, expected", [(1e7, 3.0), (0.0, 3.0 * 9 / 7)])
def test_covariance_is_calibrated_on_gaussian_foot_noise(prior_dof, expected):
    """Monte Carlo with white foot-velocity noise of known sigma: NEES of v_base averages 3 when sigma
    is the prior's, and 3 nu / (nu - 2) (Student t, nu = 9 residual dof of 4 feet) from residuals alone."""
    rng = np.random.default_rng(5)
    sigma, n = 0.05, 3000
    p = np.stack([_random_legs(rng)[0] for _ in range(n)])
    v_base, omega = rng.standard_normal((n, 3)), rng.standard_normal((n, 3))
    v_foot = -v_base[:, None] - np.cross(omega[:, None], p) + sigma * rng.standard_normal((n, 4, 3))
    f32 = lambda a: jnp.asarray(a, jnp.float32)  # noqa: E731
    t = _twist_batch(
        f32(p),
        f32(v_foot),
        f32(omega),
        jnp.ones((n, 4)),
        jnp.full(n, 1e3),
        jnp.full(n, 1.5),
        jnp.full(n, sigma),
        jnp.full(n, prior_dof),
    )
    e = np.asarray(t.v_base) - v_base
    nees = np.einsum("ti,tij,tj->t", e, np.linalg.inv(np.asarray(t.cov_v_base, np.float64)), e)
    assert abs(nees.mean() - expected) < 0.12 * expected
