"""Gait clock, swing trajectory and Raibert foothold against closed forms and NumPy loops."""

import jax
import jax.numpy as jnp
import numpy as np

from jaxquad.sim.gait import TROT_OFFSETS, leg_phases, raibert_foothold, swing_position


def test_leg_phases_match_numpy_loop():
    offsets = jnp.asarray(TROT_OFFSETS, jnp.float32)
    phases = np.linspace(-1.3, 2.7, 97, dtype=np.float32)
    stance, progress = jax.jit(jax.vmap(leg_phases, in_axes=(0, None, None)))(
        jnp.asarray(phases), offsets, jnp.float32(0.6)
    )
    for k, ph in enumerate(phases):
        for leg, off in enumerate(TROT_OFFSETS):
            c = (ph + off) % 1.0
            ref_stance = c < 0.6
            ref_progress = c / 0.6 if ref_stance else (c - 0.6) / 0.4
            assert bool(stance[k, leg]) == ref_stance
            np.testing.assert_allclose(float(progress[k, leg]), ref_progress, atol=1e-5)


def test_trot_pairs_diagonal_and_alternating():
    ph = jnp.linspace(0.0, 1.0, 50, endpoint=False)
    stance, _ = jax.vmap(leg_phases, in_axes=(0, None, None))(ph, jnp.asarray(TROT_OFFSETS), jnp.float32(0.5))
    stance = np.asarray(stance)
    np.testing.assert_array_equal(stance[:, 0], stance[:, 3])  # FL with RR
    np.testing.assert_array_equal(stance[:, 1], stance[:, 2])  # FR with RL
    np.testing.assert_array_equal(stance[:, 0], ~stance[:, 1])  # pairs alternate at duty 0.5


def test_swing_endpoints_peak_and_rest():
    p_lift = jnp.array([[0.1, 0.2, -0.3]] * 4)
    p_land = jnp.array([[0.3, 0.1, -0.28]] * 4)
    h = jnp.float32(0.08)
    f = lambda s: swing_position(p_lift, p_land, jnp.full(4, s), h)[0]
    np.testing.assert_allclose(f(0.0), p_lift[0], atol=1e-7)
    np.testing.assert_allclose(f(1.0), p_land[0], atol=1e-7)
    mid = 0.5 * (p_lift[0] + p_land[0])
    np.testing.assert_allclose(f(0.5), mid + jnp.array([0.0, 0.0, 0.08]), atol=1e-6)
    # Zero velocity at lift-off and touch-down (forward-mode derivative and finite differences).
    for s in (0.0, 1.0):
        np.testing.assert_allclose(jax.jacfwd(f)(jnp.float32(s)), 0.0, atol=1e-6)
    eps = 1e-3
    fd = (np.asarray(f(0.3 + eps)) - np.asarray(f(0.3 - eps))) / (2 * eps)
    np.testing.assert_allclose(jax.jacfwd(f)(jnp.float32(0.3)), fd, rtol=2e-2, atol=1e-3)


def test_raibert_rule_closed_form():
    p_hip = jnp.array([[0.2, 0.15], [0.2, -0.15], [-0.2, 0.15], [-0.2, -0.15]])
    v, v_cmd, w, t_st, k = jnp.array([0.3, 0.05]), jnp.array([0.5, 0.0]), 0.4, 0.2, 0.1
    got = np.asarray(raibert_foothold(p_hip, v, v_cmd, jnp.float32(w), jnp.float32(t_st), jnp.float32(k)))
    for i in range(4):
        x, y = np.asarray(p_hip[i])
        v_hip = np.array([0.5 - w * y, 0.0 + w * x])
        ref = np.array([x, y]) + 0.5 * t_st * v_hip + k * (np.array([0.3, 0.05]) - np.array([0.5, 0.0]))
        np.testing.assert_allclose(got[i], ref, atol=1e-6)
