"""Scans of a log's depth frames with the estimated attitude."""

import jax.numpy as jnp
import numpy as np
from scipy.spatial.transform import Rotation

from jaxquad.estimate import scans
from jaxquad.kernels import stabilized_scan
from jaxquad.kernels.lie import roll_pitch

K = np.array([[80.0, 0, 39.5], [0, 80.0, 29.5], [0, 0, 1]])


def test_roll_pitch_matches_scipy():
    rpy = np.array([[0.1, -0.2, 0.5], [-0.4, 0.3, -2.0], [0.0, 1.2, 3.0]])
    q_xyzw = Rotation.from_euler("ZYX", rpy[:, ::-1]).as_quat()
    roll, pitch = roll_pitch(jnp.asarray(q_xyzw[:, [3, 0, 1, 2]]))
    np.testing.assert_allclose(np.asarray(roll), rpy[:, 0], atol=1e-6)
    np.testing.assert_allclose(np.asarray(pitch), rpy[:, 1], atol=1e-6)


def test_frames_use_latest_attitude_and_a_wall_reads_its_distance():
    # A wall 3 m ahead (z-depth 3 everywhere) read from 60x80 frames.
    depth = np.full((3, 60, 80), 3.0)
    depth[1, :, :10] = 0.0  # invalid pixels: those rays read +inf
    t = np.arange(10) * 0.1
    pitch_true = 0.02 * np.arange(10)
    q = Rotation.from_euler("ZYX", np.stack([0 * t, pitch_true, 0 * t], 1)).as_quat()[:, [3, 0, 1, 2]]
    depth_t = np.array([0.05, 0.31, 0.99])  # latest samples at or before: 0, 3, 9
    sc = scans.log_scans(depth, depth_t, K, t, q, band_height=5, range_min=0.2, range_max=8.0)
    np.testing.assert_allclose(np.asarray(sc.pitch), pitch_true[[0, 3, 9]], atol=1e-6)
    u = np.arange(80)
    wall = 3.0 * np.sqrt(1 + ((u - K[0, 2]) / K[0, 0]) ** 2)  # range to a fronto-parallel plane
    np.testing.assert_allclose(np.asarray(sc.ranges_stabilized[0]), wall, rtol=1e-5)
    np.testing.assert_allclose(np.asarray(sc.ranges_baseline[2]), wall, rtol=1e-5)
    assert np.isinf(np.asarray(sc.ranges_stabilized[1, :10])).all()
    direct = stabilized_scan(jnp.asarray(depth[2], jnp.float32), (80.0, 80.0, 39.5, 29.5), 0.0, pitch_true[9], 5)
    np.testing.assert_allclose(np.asarray(sc.ranges_stabilized[2]), np.asarray(direct.ranges), rtol=1e-6)
