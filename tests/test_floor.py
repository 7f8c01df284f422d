"""Floor height filter against a NumPy Kalman filter, its closed-form steady state, and geometry."""

import jax
import jax.numpy as jnp
import numpy as np
from scipy.spatial.transform import Rotation

from jaxquad.kernels import FloorParams, floor_init, floor_step, stance_height


def _run(params, z0, dz, dt, h, n):
    def body(s, x):
        s = floor_step(params, s, *x)
        return s, s.z

    return jax.lax.scan(body, floor_init(z0), (dz, dt, h, n))[1]


_run_jit = jax.jit(_run)


def _numpy_kf(q, s, z0, dz, dt, h, n):
    z, var, floor, has, out = z0, 0.0, 0.0, False, []
    for k in range(len(dz)):
        z, var = z + dz[k], var + q * q * dt[k]
        if n[k] > 0:
            if not has:
                floor, has = z - h[k], True
            g = var / (var + s * s / n[k])
            z, var = z + g * (floor + h[k] - z), (1 - g) * var
        out.append(z)
    return np.array(out)


def test_matches_numpy_kalman_filter():
    rng = np.random.default_rng(0)
    T, dt = 600, 0.004
    n = rng.choice([0.0, 2.0, 3.0, 4.0], T)
    h = 0.3 + 0.01 * rng.standard_normal(T)
    dz = 0.001 * rng.standard_normal(T)
    params = FloorParams(process_std=jnp.asarray(0.05), meas_std=jnp.asarray(0.02))
    z = _run_jit(
        params,
        jnp.float32(0.31),
        jnp.asarray(dz, jnp.float32),
        jnp.full(T, dt, jnp.float32),
        jnp.asarray(h, jnp.float32),
        jnp.asarray(n, jnp.float32),
    )
    ref = _numpy_kf(0.05, 0.02, 0.31, dz, np.full(T, dt), h, n)
    np.testing.assert_allclose(z, ref, atol=2e-5)


def test_velocity_bias_gives_the_closed_form_bounded_error():
    """A constant vertical-velocity bias b with exact height measurements every step: the error
    settles at b dt / K with K the steady gain of the Riccati equation (b dt (1 - K) / K after the
    updates, plus the first step's b dt, taken into the floor height), instead of growing."""
    q, s, b, dt, T = 0.05, 0.02, -0.05, 0.004, 5000
    params = FloorParams(process_std=jnp.asarray(q), meas_std=jnp.asarray(s))
    z = _run_jit(
        params,
        jnp.float32(0.3),
        jnp.full(T, b * dt, jnp.float32),
        jnp.full(T, dt, jnp.float32),
        jnp.full(T, 0.3, jnp.float32),
        jnp.full(T, 2.0, jnp.float32),
    )
    Qd, R = q * q * dt, s * s / 2
    P = (Qd + np.sqrt(Qd * Qd + 4 * Qd * R)) / 2  # predicted variance at steady state
    K = P / (P + R)
    np.testing.assert_allclose(float(z[-1]) - 0.3, b * dt / K, rtol=2e-2)
    assert abs(float(z[-1]) - 0.3) < 0.05  # vs |b| T dt = 1 m integrated


def test_no_stance_integrates_and_nan_is_skipped():
    params = FloorParams.default()
    z = _run_jit(
        params,
        jnp.float32(0.3),
        jnp.array([0.01, jnp.nan, 0.01]),
        jnp.full(3, 0.004),
        jnp.array([0.0, jnp.nan, 0.0]),
        jnp.zeros(3),
    )
    np.testing.assert_allclose(z, [0.31, 0.31, 0.32], atol=1e-6)


def test_stance_height_is_minus_mean_world_z_of_contact_points():
    rng = np.random.default_rng(1)
    R = Rotation.from_euler("xyz", [0.1, -0.2, 1.0]).as_matrix()
    p = rng.standard_normal((4, 3))
    w = np.array([1.0, 0.0, 0.5, 1.0])
    p_nan = p.copy()
    p_nan[1] = np.nan
    h, n = jax.jit(stance_height)(
        jnp.asarray(p_nan, jnp.float32),
        jnp.asarray(R, jnp.float32),
        jnp.asarray(w, jnp.float32),
    )
    ref = -np.sum(w * (p @ R.T)[:, 2]) / w.sum()
    np.testing.assert_allclose(h, ref, rtol=1e-5)
    assert float(n) == 2.5
    h0, n0 = stance_height(jnp.asarray(p, jnp.float32), jnp.asarray(R, jnp.float32), jnp.zeros(4))
    assert float(h0) == 0.0 and float(n0) == 0.0
