"""Sensor noise models against closed forms and sample statistics."""

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxquad.kernels import Boxes, cast_depth, pinhole_rays
from jaxquad.sim import sensors as S

_K = S.intrinsics(160, 120)
_RAYS = jnp.asarray(pinhole_rays(_K, 120, 160))
# Optical frame of a level camera looking along world +x.
_R_LEVEL = jnp.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]])
_cast = jax.jit(cast_depth)
_depth_camera = jax.jit(S.depth_camera)
_imu_step = jax.jit(S.imu_step)


def _wall(distance: float, yaw: float = 0.0) -> jax.Array:
    """True depth of an infinite wall whose face passes through (distance, 0) with normal along yaw."""
    box = Boxes(
        jnp.array([[distance + 0.5 * np.cos(yaw), 0.5 * np.sin(yaw), 0.0]]),
        jnp.array([[0.5, 80.0, 80.0]]),
        jnp.array([yaw]),
    )
    return _cast(jnp.zeros(3), _R_LEVEL, _RAYS, box, -100.0)


def test_intrinsics_d435():
    np.testing.assert_allclose(S.intrinsics(640, 480)[0, 0], 348.0, atol=1.0)  # facts: ~348 px for 85.2 deg
    K = S.intrinsics(160, 120)
    assert K[0, 0] == K[1, 1] and K[0, 2] == 79.5 and K[1, 2] == 59.5


def test_wall_depth_noise_grows_with_square():
    noise = S.SensorNoise.default()
    for z in (1.0, 2.0, 4.0):
        depth = _depth_camera(noise, jax.random.key(1), _wall(z), _RAYS)
        d = np.asarray(depth)
        assert np.all(d > 0)
        np.testing.assert_allclose(d.mean(), z, atol=4 * 0.01 * z**2 / np.sqrt(d.size))
        np.testing.assert_allclose(d.std(), 0.01 * z**2, rtol=0.05)  # 2% at 2 m
    clean = _depth_camera(S.SensorNoise.noiseless(), jax.random.key(1), _wall(2.0), _RAYS)
    np.testing.assert_allclose(np.asarray(clean), 2.0, rtol=1e-6)


def test_range_limits_and_no_hit_read_zero():
    noise = S.SensorNoise.noiseless()
    assert np.all(np.asarray(_depth_camera(noise, jax.random.key(0), _wall(9.0), _RAYS)) == 0.0)
    assert np.all(np.asarray(_depth_camera(noise, jax.random.key(0), _wall(0.1), _RAYS)) == 0.0)
    empty = jnp.full((120, 160), jnp.inf)
    assert np.all(np.asarray(_depth_camera(noise, jax.random.key(0), empty, _RAYS)) == 0.0)


@pytest.mark.parametrize("yaw_deg", [0.0, 40.0, 75.0, 84.0])
def test_incidence_matches_plane_geometry(yaw_deg):
    yaw = np.deg2rad(yaw_deg)
    depth = _wall(3.0, yaw)
    cos = np.asarray(S.incidence_cos(depth, _RAYS))
    # Closed form: the wall normal in the optical frame is R_level^T (cos yaw, sin yaw, 0).
    n = np.asarray(_R_LEVEL).T @ np.array([np.cos(yaw), np.sin(yaw), 0.0])
    r = np.asarray(_RAYS)
    ref = np.abs(r @ n) / np.linalg.norm(r, axis=-1)
    hit = np.asarray(depth) < 20.0  # far hits may land on the box end caps
    np.testing.assert_allclose(cos[1:-1, 1:-1][hit[1:-1, 1:-1]], ref[1:-1, 1:-1][hit[1:-1, 1:-1]], atol=2e-3)
    measured = np.asarray(_depth_camera(S.SensorNoise.noiseless(), jax.random.key(0), depth, _RAYS))
    grazing = ref < np.cos(np.deg2rad(80.0))
    inner = np.s_[1:-1, 1:-1]
    clear_margin = np.abs(ref - np.cos(np.deg2rad(80.0))) > 5e-3
    in_range = hit & (np.asarray(depth) <= 8.0)
    sel = clear_margin[inner] & in_range[inner]
    np.testing.assert_array_equal((measured[inner] == 0)[sel], grazing[inner][sel])


def test_bias_random_walk_variance_under_vmap_and_scan():
    noise = S.SensorNoise.default(gyro_bias_init=0.0, gyro_bias_walk=0.01)
    dt, steps, n = 0.004, 250, 2000

    def run(key):
        state = S.imu_init(noise, key)

        def body(state, k):
            state, _ = S.imu_step(
                noise, state, k, jnp.zeros(3), jnp.array([0.0, 0.0, 9.81]), jnp.array([1.0, 0, 0, 0]), dt
            )
            return state, None

        state, _ = jax.lax.scan(body, state, jax.random.split(key, steps))
        return state.gyro_bias

    bias = np.asarray(jax.jit(jax.vmap(run))(jax.random.split(jax.random.key(3), n)))
    # Random walk: var = walk^2 * t, here 1e-4 * 1 s; sample variance of 6000 draws within ~4%.
    np.testing.assert_allclose(bias.var(), 0.01**2 * steps * dt, rtol=0.1)


def test_orientation_noise_levels_and_yaw_drift():
    quat_true = jnp.array([np.cos(0.2), np.sin(0.2) * 0.6, np.sin(0.2) * 0.8, 0.0])
    clean = S.SensorNoise.noiseless()
    state = S.imu_init(clean, jax.random.key(0))
    _, (gyro, acc, quat) = _imu_step(
        clean, state, jax.random.key(1), jnp.ones(3), jnp.array([0.0, 0.0, 9.81]), quat_true, 0.004
    )
    np.testing.assert_allclose(np.asarray(quat), np.asarray(quat_true), atol=1e-6)
    np.testing.assert_allclose(np.asarray(gyro), 1.0)
    # Pure yaw drift leaves the gravity direction seen in the base frame unchanged.
    drift = eqx.tree_at(lambda n: n.yaw_walk, clean, jnp.array(0.5, jnp.float32))
    st, (_, _, quat_d) = _imu_step(drift, state, jax.random.key(2), jnp.zeros(3), jnp.zeros(3), quat_true, 1.0)

    def up_in_base(q):
        w, x, y, z = np.asarray(q)
        return np.array([2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)])

    assert abs(float(st.yaw_drift)) > 1e-3
    np.testing.assert_allclose(up_in_base(quat_d), up_in_base(quat_true), atol=1e-6)
    np.testing.assert_allclose(np.linalg.norm(np.asarray(quat_d)), 1.0, atol=1e-6)


def test_encoder_quantization_and_torque_noise():
    noise = S.SensorNoise.default()
    q = jnp.linspace(-2.0, 2.0, 12)
    q_meas, qd_meas = S.encoders(noise, jax.random.key(0), q, jnp.zeros(12))
    steps = np.asarray(q_meas) / float(noise.q_step)
    np.testing.assert_allclose(steps, np.round(steps), atol=1e-3)
    assert np.max(np.abs(np.asarray(q_meas - q))) < 5 * float(noise.q_white) + float(noise.q_step)
    tau = jnp.full((20000,), 10.0)
    meas = np.asarray(S.joint_torque(noise, jax.random.key(1), tau))
    np.testing.assert_allclose(meas.std(), np.hypot(0.05 * 10.0, 0.1), rtol=0.05)
