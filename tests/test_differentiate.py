"""Causal differentiating filter against the analytic derivative of a sinusoid."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxquad.estimate import differentiate as dif

RATE_HZ = 500.0
DT = 1.0 / RATE_HZ


@pytest.fixture(scope="module")
def run():
    return jax.jit(dif.joint_velocities)


def fit_gain_phase(y, t, w):
    """Least-squares y ~ g * A w cos(w t - lag): returns (g, lag) relative to d/dt sin(w t)."""
    basis = np.stack([np.cos(w * t), np.sin(w * t)], 1)
    (c, s), *_ = np.linalg.lstsq(basis, y, rcond=None)
    return np.hypot(c, s) / w, np.arctan2(s, c)


@pytest.mark.parametrize("freq_hz,cutoff_hz", [(2.0, 20.0), (5.0, 20.0), (1.0, 5.0)])
def test_sinusoid_gain_and_lag(run, freq_hz, cutoff_hz):
    t = np.arange(0.0, 4.0, DT)
    w, wc = 2 * np.pi * freq_hz, 2 * np.pi * cutoff_hz
    q = np.stack([np.sin(w * t), 2.0 * np.sin(w * t)], 1)
    qd = np.asarray(run(dif.DifferentiatorParams(jnp.asarray(cutoff_hz)), jnp.asarray(t), jnp.asarray(q)))
    steady = t > 1.0  # transient decays as exp(-wc t)
    gain, lag = fit_gain_phase(qd[steady, 0], t[steady], w)

    # Exact: the frequency response of the discrete filter, D(z) L(z) at z = exp(j w dt).
    z = np.exp(1j * w * DT)
    a = 1 - np.exp(-wc * DT)
    h = (1 - 1 / z) / DT * a / (1 - (1 - a) / z) / (1j * w)
    np.testing.assert_allclose(gain, abs(h), rtol=1e-3)
    np.testing.assert_allclose(lag, -np.angle(h), atol=2e-3)

    # The documented continuous bound: gain 1/sqrt(1 + (w/wc)^2), lag atan(w/wc) +- w dt / 2.
    np.testing.assert_allclose(gain, 1 / np.sqrt(1 + (w / wc) ** 2), rtol=0.01)
    np.testing.assert_allclose(lag, np.arctan(w / wc), atol=w * DT / 2)

    # Pointwise against the analytic derivative: error within what that gain and lag explain.
    bound = w * (abs(1 - gain) + abs(lag)) * 1.05
    assert np.abs(qd[steady, 0] - w * np.cos(w * t[steady])).max() < bound
    np.testing.assert_allclose(qd[:, 1], 2 * qd[:, 0], rtol=1e-4, atol=1e-4)


def test_nan_readings_and_gaps_hold(run):
    t = np.arange(0.0, 2.0, DT)
    t[600:] += 0.05  # a 50 ms gap
    q = np.sin(3.0 * t)[:, None].repeat(2, 1)
    q[300:310, 1] = np.nan
    qd = np.asarray(run(dif.DifferentiatorParams.default(), jnp.asarray(t), jnp.asarray(q)))
    assert np.isfinite(qd).all()
    np.testing.assert_allclose(qd[300:310, 1], qd[299, 1])  # held while missing
    assert np.abs(qd[-1, 1] - 3 * np.cos(3 * t[-1])).max() < 0.1  # recovered afterwards
    # Across the gap the difference is the mean velocity over it, not a spike.
    assert np.abs(qd[595:700, 0]).max() < 3.1


def test_step_flags_and_nonpositive_dt():
    params = dif.DifferentiatorParams.default()
    s = dif.init(jnp.array([0.0, jnp.nan]))
    s, used = dif.step(params, s, jnp.array([0.1, 0.2]), jnp.asarray(0.0))
    assert not bool(used.any()) and np.asarray(s.qd).tolist() == [0.0, 0.0]
    s, used = dif.step(params, s, jnp.array([0.1, jnp.inf]), jnp.asarray(DT))
    assert np.asarray(used).tolist() == [True, False]
    assert np.isfinite(np.asarray(s.qd)).all()


def test_vmap_and_grad_cutoff(run):
    t = jnp.arange(0.0, 0.5, DT)
    q = jnp.sin(5.0 * t)[:, None]
    params = jax.vmap(dif.DifferentiatorParams)(jnp.array([5.0, 20.0]))
    qd = jax.vmap(run, in_axes=(0, None, None))(params, t, q)
    assert qd.shape == (2, t.size, 1)
    loss = lambda fc: jnp.sum(run(dif.DifferentiatorParams(fc), t, q) ** 2)
    g = jax.grad(loss)(jnp.asarray(10.0))
    fd = (loss(jnp.asarray(10.05)) - loss(jnp.asarray(9.95))) / 0.1
    np.testing.assert_allclose(float(g), float(fd), rtol=0.02)
