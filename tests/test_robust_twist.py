"""robust_body_twist against a NumPy IRLS on the stacked weighted rows, with an injected slipping foot."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxquad.kernels import robust_body_twist, robust_weight

_NOMINAL = np.array(
    [
        [0.19, 0.14, -0.27],
        [0.19, -0.14, -0.27],
        [-0.19, 0.14, -0.27],
        [-0.19, -0.14, -0.27],
    ]
)


def _skew(a):
    return np.array([[0, -a[2], a[1]], [a[2], 0, -a[0]], [-a[1], a[0], 0]])


def _irls_reference(p, v, omega_imu, w, w_imu, scale, n_iter, loss, v_prior=None):
    """Float64 IRLS: lstsq on rows scaled by sqrt(weight); per-foot weights from the residual norm,
    times those of the residuals against v_prior (with the first solve's omega) when given."""
    u, u_prior = np.ones(len(p)), np.ones(len(p))
    for it in range(n_iter + 1):
        wf = w * u
        rows = [np.sqrt(wi) * np.hstack([np.eye(3), -_skew(pi)]) for pi, wi in zip(p, wf)]
        rhs = [np.sqrt(wi) * -vi for vi, wi in zip(v, wf)]
        rows.append(np.sqrt(w_imu) * np.hstack([np.zeros((3, 3)), np.eye(3)]))
        rhs.append(np.sqrt(w_imu) * omega_imu)
        x = np.linalg.lstsq(np.vstack(rows), np.concatenate(rhs), rcond=None)[0]
        if it == n_iter:
            return x[:3], x[3:], u
        weight = lambda r: np.where(w > 0, 1.0 / np.maximum(r, 1.0) if loss == "huber" else 1.0 / (1.0 + r * r), 1.0)
        if it == 0 and v_prior is not None:
            u_prior = weight(np.linalg.norm(v_prior + np.cross(x[3:], p) + v, axis=1) / scale)
        u = weight(np.linalg.norm(x[:3] + np.cross(x[3:], p) + v, axis=1) / scale) * u_prior


def _scene(rng, slip_foot, slip_speed=0.6, noise=0.02):
    p = _NOMINAL + 0.03 * rng.standard_normal((4, 3))
    v_base, omega = rng.standard_normal(3), 0.5 * rng.standard_normal(3)
    v = -v_base - np.cross(omega, p) + noise * rng.standard_normal((4, 3))
    if slip_foot is not None:
        d = rng.standard_normal(3)
        v[slip_foot] += slip_speed * d / np.linalg.norm(d)  # the foot slides in the world
    return p, v, omega, v_base


_F = {
    loss: jax.jit(
        jax.vmap(lambda p, v, o, w, s, loss=loss: robust_body_twist(p, v, o, w, 1.0, 1.5, s, n_iter=4, loss=loss))
    )
    for loss in ("huber", "cauchy")
}


@pytest.mark.parametrize("loss", ["huber", "cauchy"])
def test_matches_numpy_irls_and_flags_the_slipping_foot(loss):
    rng = np.random.default_rng(0 if loss == "huber" else 1)
    scenes = [_scene(rng, k % 4) for k in range(16)]
    p, v, omega, v_true = (np.stack(x) for x in zip(*scenes))
    w = np.ones((16, 4))
    w[12:, 3 - np.arange(4)[:, None].T[0]] = 1.0
    scale = np.full(16, 0.1)
    f32 = lambda a: jnp.asarray(a, jnp.float32)  # noqa: E731
    out = _F[loss](f32(p), f32(v), f32(omega), f32(w), f32(scale))
    for i in range(16):
        v_ref, omega_ref, u_ref = _irls_reference(p[i], v[i], omega[i], w[i], 1.0, 0.1, 4, loss)
        np.testing.assert_allclose(out.twist.v_base[i], v_ref, atol=2e-4)
        np.testing.assert_allclose(out.twist.omega_base[i], omega_ref, atol=2e-4)
        np.testing.assert_allclose(out.robust_weight[i], u_ref, rtol=2e-3, atol=1e-5)
        assert list(np.asarray(out.slip[i])) == [f == i % 4 for f in range(4)]
    # The reweighted solve is closer to the true velocity than plain least squares.
    plain = _F[loss](f32(p), f32(v), f32(omega), f32(w), f32(np.full(16, 1e6)))
    err_robust = np.linalg.norm(np.asarray(out.twist.v_base) - v_true, axis=1).mean()
    err_plain = np.linalg.norm(np.asarray(plain.twist.v_base) - v_true, axis=1).mean()
    assert err_robust < 0.5 * err_plain
    assert not np.any(np.asarray(plain.slip))


def test_swing_feet_and_nan_are_ignored_and_stance_count_kept():
    rng = np.random.default_rng(3)
    p, v, omega, v_true = _scene(rng, 1)
    p[3] = np.nan  # a swing foot's garbage
    w = np.array([1.0, 1.0, 1.0, 0.0])
    f32 = lambda a: jnp.asarray(a, jnp.float32)  # noqa: E731
    out = jax.jit(robust_body_twist)(f32(p), f32(v), f32(omega), f32(w))
    assert np.all(np.isfinite(out.twist.v_base)) and bool(out.twist.linear_observed)
    assert float(out.twist.n_stance) == 3.0 and not bool(out.slip[3])
    assert float(out.robust_weight[3]) == 1.0


def test_robust_weight_closed_forms():
    r = jnp.array([0.0, 0.05, 0.1, 0.2, 1.0])
    np.testing.assert_allclose(robust_weight(r, 0.1, "huber"), [1, 1, 1, 0.5, 0.1], rtol=1e-6)
    np.testing.assert_allclose(robust_weight(r, 0.1, "cauchy"), 1 / (1 + (np.asarray(r) / 0.1) ** 2), rtol=1e-6)
    with pytest.raises(ValueError, match="loss"):
        robust_weight(r, 0.1, "tukey")


_F_PRIOR = jax.jit(jax.vmap(lambda p, v, o, w, vp: robust_body_twist(p, v, o, w, 1.0, 1.5, 0.1, n_iter=3, v_prior=vp)))


def test_prior_velocity_picks_the_sliding_foot_of_a_diagonal_pair():
    # A trot's diagonal pair (feet 0 and 3; 1 and 2 swing, with NaN data) where foot 3 slides at
    # 0.3 m/s, as a foot still does at touchdown. Without a prior the two residuals are equal and
    # opposite: the solve stays halfway. A prior 0.02 m/s off the true velocity keeps foot 0.
    rng = np.random.default_rng(7)
    scenes = [_scene(rng, 3, slip_speed=0.3, noise=0.005) for _ in range(8)]
    p, v, omega, v_true = (np.stack(x) for x in zip(*scenes))
    p[:, 1:3] = np.nan
    w = np.tile([1.0, 0.0, 0.0, 1.0], (8, 1))
    v_prior = v_true + 0.02 * rng.standard_normal((8, 3))
    f32 = lambda a: jnp.asarray(a, jnp.float32)  # noqa: E731
    out = _F_PRIOR(f32(p), f32(v), f32(omega), f32(w), f32(v_prior))
    no_prior = _F_PRIOR(f32(p), f32(v), f32(omega), f32(w), f32(np.full((8, 3), np.nan)))  # NaN prior: ignored
    for i in range(8):
        pi, vi = np.where(w[i, :, None] > 0, p[i], 0.0), np.where(w[i, :, None] > 0, v[i], 0.0)
        v_ref, omega_ref, u_ref = _irls_reference(pi, vi, omega[i], w[i], 1.0, 0.1, 3, "huber", v_prior[i])
        np.testing.assert_allclose(out.twist.v_base[i], v_ref, atol=2e-4)
        np.testing.assert_allclose(out.robust_weight[i], u_ref, rtol=2e-3, atol=1e-5)
        assert list(np.asarray(out.slip[i])) == [False, False, False, True]
        v_plain = _irls_reference(pi, vi, omega[i], w[i], 1.0, 0.1, 3, "huber")[0]
        np.testing.assert_allclose(no_prior.twist.v_base[i], v_plain, atol=2e-4)
    err = lambda o: np.linalg.norm(np.asarray(o.twist.v_base) - v_true, axis=1)  # noqa: E731
    assert err(out).max() < 0.05 and err(no_prior).min() > 0.1
