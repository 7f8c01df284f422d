"""Mahony attitude filter against a closed-form rotation with its exact gyro and accelerometer."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from jaxquad.estimate import attitude
from jaxquad.kernels.lie import rotation_matrix as quat_to_matrix

G = attitude.GRAVITY
RATE_HZ = 200.0


def rx(a):
    c, s = np.cos(a), np.sin(a)
    return np.array([[1, 0, 0], [0, c, -s], [0, s, c]])


def rz(a):
    c, s = np.cos(a), np.sin(a)
    return np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])


def synthetic(duration_s, bias):
    """R_world_base = Rz(psi) Rx(phi); omega_base = Rx(phi)^T psi_dot e_z + phi_dot e_x (closed form)."""
    t = np.arange(0.0, duration_s, 1.0 / RATE_HZ)
    psi, psi_dot = 0.3 * t, 0.3 * np.ones_like(t)
    phi = 0.4 + 0.3 * np.sin(np.pi * t)
    phi_dot = 0.3 * np.pi * np.cos(np.pi * t)
    R = np.stack([rz(a) @ rx(b) for a, b in zip(psi, phi)])
    omega = np.stack([rx(b).T @ [0, 0, w] + [wd, 0, 0] for b, w, wd in zip(phi, psi_dot, phi_dot)])
    acc = np.einsum("tji,j->ti", R, [0.0, 0.0, G])  # R^T (0, 0, g): specific force at rest
    return t, R, omega + bias, acc


@pytest.fixture(scope="module")
def run():
    return jax.jit(attitude.estimate_attitude)


def tilt_error(q_est, R_true):
    up_est = np.asarray(jax.vmap(quat_to_matrix)(jnp.asarray(q_est)))[:, 2]
    up_true = R_true[:, 2, :]
    return np.arccos(np.clip((up_est * up_true).sum(1), -1, 1))


def test_converges_to_true_attitude_with_gyro_bias(run):
    bias = np.array([0.02, -0.03, 0.015])
    t, R, gyro, acc = synthetic(60.0, bias)
    q0 = jnp.array([1.0, 0.0, 0.0, 0.0])  # starts 0.4 rad off in roll
    q, flags = run(attitude.AttitudeParams.default(), jnp.asarray(t), jnp.asarray(gyro), jnp.asarray(acc), q0)
    err = tilt_error(np.asarray(q), R)
    assert err[0] > 0.35
    # Residual: the gyro of sample k-1 is held over the step, a lag of about
    # max|phi_ddot| dt / (2 kp) = 3 rad/s^2 * 5 ms / 2 = 7.4 mrad on this motion.
    assert err[-2000:].max() < 1e-2
    # Without the integral term the bias leaves a steady tilt error (the test can fail).
    no_ki = attitude.AttitudeParams(kp=jnp.asarray(1.0), ki=jnp.asarray(0.0), acc_gate=jnp.asarray(0.3))
    q_p, _ = run(no_ki, jnp.asarray(t), jnp.asarray(gyro), jnp.asarray(acc), q0)
    assert tilt_error(np.asarray(q_p), R)[-2000:].max() > 3 * err[-2000:].max()
    assert bool(flags[:-1].all())


def test_bias_estimate():
    bias = np.array([0.02, -0.03, 0.015])
    t, R, gyro, acc = synthetic(60.0, bias)
    state = attitude.init(jnp.asarray(attitude.attitude_from_acc(jnp.asarray(acc[0]))))
    params = attitude.AttitudeParams.default()

    def body(s, x):
        s, _ = attitude.step(params, s, *x, jnp.asarray(1.0 / RATE_HZ))
        return s, None

    state, _ = jax.lax.scan(body, state, (jnp.asarray(gyro), jnp.asarray(acc)))
    np.testing.assert_allclose(np.asarray(state.gyro_bias), bias, atol=3e-3)


@pytest.mark.parametrize("roll,pitch", [(0.0, 0.0), (0.3, -0.2), (-1.0, 0.7), (2.5, 0.1)])
def test_attitude_from_acc(roll, pitch):
    ry = lambda a: np.array([[np.cos(a), 0, np.sin(a)], [0, 1, 0], [-np.sin(a), 0, np.cos(a)]])
    R = ry(pitch) @ rx(roll)
    acc = R.T @ [0, 0, G]
    R_est = np.asarray(quat_to_matrix(attitude.attitude_from_acc(jnp.asarray(acc))))
    np.testing.assert_allclose(R_est, R, atol=1e-5)


def test_bad_readings_are_skipped_not_propagated(run):
    t, R, gyro, acc = synthetic(10.0, np.zeros(3))
    gyro[100:110] = np.nan
    acc[200:205] = np.inf
    acc[300:320] *= 3.0  # a kick: |acc| = 3 g is not gravity
    acc[0] = np.nan  # no initial tilt: identity start
    q, flags = run(attitude.AttitudeParams.default(), jnp.asarray(t), jnp.asarray(gyro), jnp.asarray(acc))
    assert np.isfinite(np.asarray(q)).all()
    f = np.asarray(flags)
    assert not f[100:110, 0].any() and f[111:199, 0].all()
    assert not f[200:205, 1].any() and not f[300:320, 1].any() and f[320:399, 1].all()
    assert tilt_error(np.asarray(q), R)[-200:].max() < 0.03  # from 0.4 rad at t = 0


def test_vmap_over_robots_and_params_and_grad(run):
    t, R, gyro, acc = synthetic(5.0, np.zeros(3))
    params = jax.vmap(attitude.AttitudeParams)(
        jnp.array([0.5, 1.0, 2.0]), jnp.array([0.0, 0.05, 0.1]), jnp.full(3, 0.3)
    )
    batch = jnp.broadcast_to(jnp.asarray(gyro), (3,) + gyro.shape), jnp.broadcast_to(jnp.asarray(acc), (3,) + acc.shape)
    q, _ = jax.vmap(run, in_axes=(0, None, 0, 0, None))(params, jnp.asarray(t), *batch, None)
    assert q.shape == (3, t.size, 4)
    q1, _ = run(jax.tree.map(lambda a: a[1], params), jnp.asarray(t), jnp.asarray(gyro), jnp.asarray(acc))
    np.testing.assert_allclose(np.asarray(q[1]), np.asarray(q1), atol=1e-5)

    def loss(kp):
        p = attitude.AttitudeParams(kp=kp, ki=jnp.asarray(0.05), acc_gate=jnp.asarray(0.3))
        qs, _ = attitude.estimate_attitude(
            p, jnp.asarray(t[:200]), jnp.asarray(gyro[:200]), jnp.asarray(acc[:200]), jnp.array([1.0, 0, 0, 0])
        )
        return jnp.sum(qs[-1, 1:] ** 2)

    g = jax.grad(loss)(jnp.asarray(1.0))
    eps = 1e-2
    fd = (loss(jnp.asarray(1.0 + eps)) - loss(jnp.asarray(1.0 - eps))) / (2 * eps)
    assert np.isfinite(float(g))
    np.testing.assert_allclose(float(g), float(fd), rtol=0.05)


def test_step_toward_a_noisy_reported_attitude():
    """Against a reported attitude with white noise (a tilt of 5 mrad per sample about random axes) the
    filter finds the gyro bias (x and y too: with a yaw reference every axis is observable) and
    smooths the report: its error is a fraction of the report's."""
    bias = np.array([0.02, -0.03, 0.015])
    t, R, _, _ = synthetic(60.0, bias)
    # The rate that carries R[k-1] exactly to R[k] over the step, plus the bias (gyro[k] for k >= 1).
    rel = Rotation.from_matrix(R[:-1]).inv() * Rotation.from_matrix(R[1:])
    gyro = np.concatenate([np.zeros((1, 3)), rel.as_rotvec() * RATE_HZ]) + bias
    rng = np.random.default_rng(0)
    noise = 5e-3 * rng.standard_normal((t.size, 3))
    R_meas = np.stack([r @ Rotation.from_rotvec(n).as_matrix() for r, n in zip(R, noise)])
    q_meas = Rotation.from_matrix(R_meas).as_quat()[:, [3, 0, 1, 2]]
    params = attitude.AttitudeParams.toward_report()
    dt = jnp.asarray(1.0 / RATE_HZ)

    def body(s, x):
        g, q = x
        s, used = attitude.step_toward(params, s, g, q, dt)
        return s, (s.q_world_base, used)

    state0 = attitude.init(jnp.asarray(q_meas[0]))
    # Sample k's gyro carries the attitude from k-1 to k, as `pipeline_step` feeds it.
    state, (q, used) = jax.lax.scan(body, state0, (jnp.asarray(gyro[1:]), jnp.asarray(q_meas[1:])))
    np.testing.assert_allclose(np.asarray(state.gyro_bias), bias, atol=2e-3)
    assert bool(np.asarray(used).all())
    R_est = Rotation.from_quat(np.asarray(q)[:, [1, 2, 3, 0]])
    err = (Rotation.from_matrix(R[1:]).inv() * R_est).magnitude()[-2000:]
    err_meas = np.linalg.norm(noise[1:], axis=1)[-2000:]
    assert np.sqrt(np.mean(err**2)) < 0.4 * np.sqrt(np.mean(err_meas**2))
    # A report that is not a unit quaternion does not correct: the gyro alone carries the attitude.
    s1, used = attitude.step_toward(params, state, jnp.asarray(gyro[-1]), jnp.full(4, jnp.nan), dt)
    assert not bool(used[1]) and np.isfinite(np.asarray(s1.q_world_base)).all()
    np.testing.assert_array_equal(np.asarray(s1.gyro_bias), np.asarray(state.gyro_bias))
