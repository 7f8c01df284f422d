"""The Lie-group helpers against scipy's rotations and closed forms."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from jaxquad.kernels.lie import SO3, quat_from_rpy, roll_pitch, rotation_matrix, skew, wrap_angle, yaw_of

RNG = np.random.default_rng(0)
RPY = RNG.uniform([-3.1, -1.5, -3.1], [3.1, 1.5, 3.1], size=(20, 3))


@pytest.mark.parametrize("rpy", RPY)
def test_rpy_roundtrip_matches_scipy(rpy):
    q = np.asarray(quat_from_rpy(*rpy), np.float64)
    ref = Rotation.from_euler("ZYX", rpy[::-1]).as_quat(scalar_first=True)
    assert np.allclose(q * np.sign(q[0]), ref * np.sign(ref[0]), atol=1e-6)
    r, p = roll_pitch(q * 3.0)  # any scale
    assert np.allclose([r, p, yaw_of(q)], rpy, atol=1e-5)
    assert np.allclose(rotation_matrix(q * 0.5), Rotation.from_quat(ref, scalar_first=True).as_matrix(), atol=1e-6)


def test_skew_is_cross_product():
    w, x = RNG.normal(size=3).astype(np.float32), RNG.normal(size=3)
    assert np.allclose(skew(w) @ x, np.cross(w, x), atol=1e-6)


def test_wrap_angle():
    a = np.array([-7.0, -np.pi, 0.0, 3.0, 4.0, 10.0])
    w = np.asarray(wrap_angle(a))
    assert np.all((w >= -np.pi) & (w < np.pi))
    assert np.allclose(np.cos(w), np.cos(a), atol=1e-6) and np.allclose(np.sin(w), np.sin(a), atol=1e-6)


def test_so3_exp_gradient_finite_at_zero():
    g = jax.grad(lambda phi: SO3.exp(phi).as_matrix()[0, 1])(np.zeros(3, np.float32))
    assert np.all(np.isfinite(g)) and np.allclose(g, [0, 0, -1], atol=1e-6)


def test_se3_exp_matches_scipy_expm_and_has_exact_slope_at_zero():
    from scipy.linalg import expm

    from jaxquad.kernels.lie import se3_exp

    for v, phi in [(RNG.normal(size=3), RNG.normal(size=3)), (RNG.normal(size=3), 1e-4 * RNG.normal(size=3))]:
        xi = np.zeros((4, 4))
        xi[:3, :3] = [[0, -phi[2], phi[1]], [phi[2], 0, -phi[0]], [-phi[1], phi[0], 0]]
        xi[:3, 3] = v
        T = se3_exp(jnp.asarray(v, jnp.float32), jnp.asarray(phi, jnp.float32)).as_matrix()
        assert np.allclose(T, expm(xi), atol=2e-5)
    # y of exp((1, 0, 0), (0, 0, w)) = (1 - cos w) / w: slope 1/2 at w = 0 (jaxlie's SE3.exp gives 1).
    slope = jax.grad(lambda w: se3_exp(jnp.array([1.0, 0, 0]), jnp.stack([0.0, 0.0, w])).translation()[1])(0.0)
    assert np.isclose(slope, 0.5, atol=1e-6)
