"""The low-obstacle scan (`kernels.low_obstacles`): against a per-pixel NumPy loop on noisy images of a tilted
camera, and on a rendered floor with a low box, whose face it finds and whose floor it leaves out."""

import jax
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from jaxquad.kernels.low_obstacles import LowObstacleParams, low_obstacle_scan

K = (84.0, 108.0, 79.5, 59.5)  # fx, fy, cx, cy (px) of a 160 x 120 image, about 87 x 58 deg
H, W, CAM_H = 120, 160, 0.32
ARGS = dict(z_min=0.08, z_max=0.29, range_min=0.3, range_step=0.05, min_points=3)
PARAMS = LowObstacleParams.default(CAM_H)
_jit_scan = jax.jit(low_obstacle_scan, static_argnames=("n_bins", "n_ranges"))


def _scan(depth, intrinsics, roll, pitch):
    return _jit_scan(depth, intrinsics, roll, pitch, PARAMS)


def _level_from_camera(roll, pitch):
    """Rotation taking camera optical axes (x right, y down, z forward) to the levelled frame (x forward, y left, z
    up): the base's roll and pitch undone, as scipy composes them (extrinsic x then y)."""
    cam_to_base = np.array([[0, 0, 1], [-1, 0, 0], [0, -1, 0]], float)
    return Rotation.from_euler("xy", [roll, pitch]).as_matrix() @ cam_to_base


def _reference(depth, roll, pitch, n_bins=80, n_ranges=50):
    fx, fy, cx, cy = K
    R = _level_from_camera(roll, pitch)
    lo, hi = np.arctan2(-(W - 1 - cx), fx), np.arctan2(cx, fx)
    counts = np.zeros((n_bins, n_ranges), int)
    for v in range(H):
        for u in range(W):
            z = depth[v, u]
            if not (np.isfinite(z) and z > 0):
                continue
            p = R @ np.array([(u - cx) * z / fx, (v - cy) * z / fy, z])
            r, b = np.hypot(p[0], p[1]), np.arctan2(p[1], p[0])
            k, c = int(np.floor((b - lo) / ((hi - lo) / n_bins))), int(np.floor(r / ARGS["range_step"]))
            band = ARGS["z_min"] <= CAM_H + p[2] <= ARGS["z_max"] and r >= ARGS["range_min"]
            if band and c < n_ranges and 0 <= k < n_bins:
                counts[k, c] += 1
    enough = counts >= ARGS["min_points"]
    return np.where(enough.any(1), (np.argmax(enough, 1) + 0.5) * ARGS["range_step"], np.inf)


def _render(roll, pitch, box_x=1.5, box_half_y=0.3, box_h=0.24):
    """z-depth of a floor CAM_H below the camera and a box face at x = box_x (levelled frame), |y| <= box_half_y,
    up to box_h above the floor; rays that hit neither read 0."""
    fx, fy, cx, cy = K
    R = _level_from_camera(roll, pitch)
    v, u = np.mgrid[0:H, 0:W].astype(float)
    d_cam = np.stack([(u - cx) / fx, (v - cy) / fy, np.ones_like(u)], -1)  # z-depth 1 along each ray
    d = d_cam @ R.T
    t_floor = np.where(d[..., 2] < 0, -CAM_H / np.where(d[..., 2] < 0, d[..., 2], -1), np.inf)
    t_box = np.where(d[..., 0] > 0, box_x / np.where(d[..., 0] > 0, d[..., 0], 1), np.inf)
    hit_box = (np.abs(t_box * d[..., 1]) <= box_half_y) & (CAM_H + t_box * d[..., 2] <= box_h)
    t = np.minimum(t_floor, np.where(hit_box, t_box, np.inf))
    return np.where(np.isfinite(t), t, 0.0).astype(np.float32)  # t is the z-depth: d_cam's z is 1


@pytest.mark.parametrize("seed", range(3))
def test_low_scan_counts_as_a_per_pixel_loop_does(seed):
    assert {k: float(getattr(PARAMS, k)) for k in ARGS} == pytest.approx(ARGS)  # the reference's numbers
    rng = np.random.default_rng(seed)
    roll, pitch = rng.uniform(-0.1, 0.1, 2)
    depth = _render(roll, pitch, box_x=rng.uniform(0.8, 2.0), box_h=rng.uniform(0.15, 0.28))
    depth = depth * (1 + 0.01 * depth * rng.standard_normal(depth.shape))  # 1 % of z^2
    depth[rng.random(depth.shape) < 0.05] = 0.0
    got = np.asarray(_scan(depth, K, roll, pitch).ranges)
    want = _reference(depth.astype(np.float64), roll, pitch)
    both = np.isfinite(got) & np.isfinite(want)
    near = np.abs(np.where(both, got, 0) - np.where(both, want, 0)) <= ARGS["range_step"] + 1e-6
    equal = (got == want) | (both & np.isclose(np.where(both, got, 0), np.where(both, want, 0), atol=1e-5))
    assert np.all(equal | (both & near))  # a point on a cell's edge may flip
    assert np.mean(equal) > 0.95 and np.isfinite(want).sum() > 10


def test_a_box_lower_than_the_camera_is_found_and_the_floor_is_not():
    roll, pitch = 0.05, -0.08
    scan = _scan(_render(roll, pitch), K, roll, pitch)
    ranges, bearings = np.asarray(scan.ranges), np.asarray(scan.bearings)
    inside = np.abs(1.5 * np.tan(bearings)) < 0.25  # bearings well within the face (|y| < 0.3 m at x = 1.5 m)
    outside = np.abs(1.5 * np.tan(bearings)) > 0.4
    horizontal = 1.5 / np.cos(bearings)  # the face's horizontal range along each bearing
    assert np.all(np.abs(ranges[inside] - horizontal[inside]) <= ARGS["range_step"])
    assert np.all(np.isinf(ranges[outside]))  # floor only
    assert np.all(np.isinf(np.asarray(_scan(_render(roll, pitch, box_h=0.0), K, roll, pitch).ranges)))
