"""SE(3) integration against the closed-form screw motion of a constant twist."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxquad.estimate import odometry
from jaxquad.kernels.lie import rotation_matrix as quat_to_matrix

IDENTITY = odometry.Pose(p_world_base=jnp.zeros(3), q_world_base=jnp.array([1.0, 0, 0, 0]))


@pytest.fixture(scope="module")
def run():
    return jax.jit(odometry.integrate_twist)


def helix(t, vx, vz, w):
    """Base moving forward at vx, up at vz, yawing at w: a helix of radius vx / w (closed form)."""
    p = np.stack([vx * np.sin(w * t) / w, vx * (1 - np.cos(w * t)) / w, vz * t], 1)
    q = np.stack([np.cos(w * t / 2), 0 * t, 0 * t, np.sin(w * t / 2)], 1)
    return p, q


def test_constant_twist_is_a_helix(run):
    t = np.linspace(0.0, 5.0, 251)
    vx, vz, w = 0.8, 0.1, 0.9
    n = t.size
    pose = run(
        IDENTITY, jnp.asarray(t), jnp.tile(jnp.array([vx, 0, vz]), (n, 1)), jnp.tile(jnp.array([0, 0, w]), (n, 1))
    )
    p, q = helix(t, vx, vz, w)
    # The exponential map is exact for a constant twist, whatever the step.
    np.testing.assert_allclose(np.asarray(pose.p_world_base), p, atol=2e-5)
    np.testing.assert_allclose(np.asarray(pose.q_world_base), q, atol=2e-6)


def test_general_screw_matches_matrix_exponential():
    """Twist with all six components from a tilted start, vs scipy's expm of the 4x4 twist matrix."""
    from scipy.linalg import expm

    v, w = np.array([0.3, -0.2, 0.5]), np.array([0.4, -0.7, 1.1])
    xi = np.zeros((4, 4))
    xi[:3, :3] = [[0, -w[2], w[1]], [w[2], 0, -w[0]], [-w[1], w[0], 0]]
    xi[:3, 3] = v
    q0 = jnp.array([0.9, 0.1, -0.3, 0.2]) / np.linalg.norm([0.9, 0.1, -0.3, 0.2])
    T0 = np.eye(4)
    T0[:3, :3] = np.asarray(quat_to_matrix(q0))
    T0[:3, 3] = [1.0, 2.0, -0.5]
    t = np.linspace(0.0, 3.0, 7)  # coarse steps: exactness does not depend on dt
    pose0 = odometry.Pose(p_world_base=jnp.asarray(T0[:3, 3]), q_world_base=q0)
    pose = odometry.integrate_twist(
        pose0, jnp.asarray(t), jnp.tile(jnp.asarray(v), (7, 1)), jnp.tile(jnp.asarray(w), (7, 1))
    )
    for k, tk in enumerate(t):
        T = T0 @ expm(xi * tk)
        np.testing.assert_allclose(np.asarray(pose.p_world_base[k]), T[:3, 3], atol=1e-5)
        np.testing.assert_allclose(np.asarray(quat_to_matrix(pose.q_world_base[k])), T[:3, :3], atol=1e-5)


def test_attitude_from_outside_and_hold(run):
    """With a given attitude, translation uses R_k V(omega dt) v dt; invalid samples hold."""
    t = np.linspace(0.0, 2.0, 101)
    vx, w = 0.5, 0.6
    p, q = helix(t, vx, 0.0, w)
    n = t.size
    v = np.tile([vx, 0, 0], (n, 1))
    om = np.tile([0, 0, w], (n, 1))
    pose = run(IDENTITY, jnp.asarray(t), jnp.asarray(v), jnp.asarray(om), jnp.asarray(q))
    np.testing.assert_allclose(np.asarray(pose.p_world_base), p, atol=2e-5)

    valid = np.ones(n, bool)
    valid[50:] = False
    v[60] = np.nan  # inside the held part: never read
    pose = run(IDENTITY, jnp.asarray(t), jnp.asarray(v), jnp.asarray(om), None, jnp.asarray(valid))
    got = np.asarray(pose.p_world_base)
    np.testing.assert_allclose(got[:51], p[:51], atol=2e-5)
    np.testing.assert_allclose(got[51:], np.broadcast_to(p[50], got[51:].shape), atol=2e-5)


def test_zero_twist_gradient_is_finite():
    """The Taylor branch keeps gradients finite at omega = 0 and matches finite differences."""

    def end_x(wz):
        t = jnp.linspace(0.0, 1.0, 11)
        v = jnp.tile(jnp.array([1.0, 0, 0]), (11, 1))
        om = jnp.tile(jnp.stack([0.0, 0.0, wz]), (11, 1))
        return odometry.integrate_twist(IDENTITY, t, v, om).p_world_base[-1, 1]

    g = jax.grad(end_x)(jnp.asarray(0.0))
    assert np.isfinite(float(g))
    # y(1) = vx (1 - cos w) / w -> dy/dw at 0 = vx / 2
    np.testing.assert_allclose(float(g), 0.5, atol=1e-4)


def test_vmap_over_robots(run):
    t = jnp.linspace(0.0, 1.0, 21)
    v = jnp.stack([jnp.tile(jnp.array([s, 0, 0]), (21, 1)) for s in (0.1, 0.2, 0.3)])
    om = jnp.zeros((3, 21, 3))
    poses = jax.vmap(run, in_axes=(None, None, 0, 0))(IDENTITY, t, v, om)
    np.testing.assert_allclose(np.asarray(poses.p_world_base[:, -1, 0]), [0.1, 0.2, 0.3], atol=1e-6)
