"""Scan slicing against a NumPy loop of the slicing definition and against an analytically rendered
room whose level scan is known in closed form."""

import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxquad.kernels import CameraIntrinsics, Scan, baseline_scan, level_scan, stabilized_scan

_stabilized = jax.jit(stabilized_scan, static_argnums=4)
_baseline = jax.jit(baseline_scan, static_argnums=2)
_level = jax.jit(level_scan, static_argnums=4)

# D435i-like camera at 640 x 480, 0.35 m above the floor of a room (Go2/Silver Badger head height).
FX = FY = 348.0
CX, CY = 319.5, 239.5
WIDTH, HEIGHT = 640, 480
K = CameraIntrinsics(*(jnp.float32(c) for c in (FX, FY, CX, CY)))
P_WORLD_CAM = np.array([0.0, 0.0, 0.35])
YAW = 0.2
ROOM = (np.array([-3.0, -4.5, 0.0]), np.array([5.5, 5.0, 2.5]))  # walls, floor and ceiling (m)
BOXES = [
    (np.array([2.5, -0.5, 0.0]), np.array([3.2, 0.5, 0.15])),  # low box, well under the scan plane
    (np.array([3.0, 1.5, 0.0]), np.array([3.6, 2.2, 1.2])),  # boxes crossing the scan plane
    (np.array([1.2, -1.0, 0.0]), np.array([1.5, -0.7, 0.9])),
    (np.array([4.0, -3.0, 0.0]), np.array([4.6, -2.2, 1.0])),
    (np.array([1.8, -2.6, 0.52]), np.array([3.2, 1.2, 0.6])),  # table top above the scan plane
]


def _R_world_base(roll, pitch, yaw):
    cr, sr, cp, sp, cy, sy = (f(a) for a in (roll, pitch, yaw) for f in (np.cos, np.sin))
    R_x = np.array([[1, 0, 0], [0, cr, -sr], [0, sr, cr]])
    R_y = np.array([[cp, 0, sp], [0, 1, 0], [-sp, 0, cp]])
    R_z = np.array([[cy, -sy, 0], [sy, cy, 0], [0, 0, 1]])
    return R_z @ R_y @ R_x


def _ray_hit(o, d):
    """Ray parameter of the first hit with the room (from inside) or a box (slab method)."""
    with np.errstate(divide="ignore", invalid="ignore"):
        lo, hi = ROOM
        t = np.min(np.where(d > 0, (hi - o) / d, np.where(d < 0, (lo - o) / d, np.inf)), axis=-1)
        for b_lo, b_hi in BOXES:
            t1, t2 = (b_lo - o) / d, (b_hi - o) / d
            t_in, t_out = np.max(np.minimum(t1, t2), axis=-1), np.min(np.maximum(t1, t2), axis=-1)
            t = np.where((t_in > 0) & (t_in <= t_out), np.minimum(t, t_in), t)
    return t


def _render(roll, pitch):
    v, u = np.mgrid[0:HEIGHT, 0:WIDTH].astype(float)
    d_cam = np.stack([(u - CX) / FX, (v - CY) / FY, np.ones_like(u)], -1)
    d_base = np.stack([d_cam[..., 2], -d_cam[..., 0], -d_cam[..., 1]], -1)  # camera x right, y down, z fwd
    d_world = d_base @ _R_world_base(roll, pitch, YAW).T
    return _ray_hit(P_WORLD_CAM, d_world)  # d_cam has unit z, so the ray parameter is the depth


def _true_level_ranges(bearings):
    """Closed form: the horizontal plane through the camera cut with the scene, ccw from heading."""
    a = np.asarray(bearings, float) + YAW
    return _ray_hit(P_WORLD_CAM, np.stack([np.cos(a), np.sin(a), np.zeros_like(a)], -1))


def _errors(scan: Scan):
    truth = _true_level_ranges(scan.bearings)
    assert np.all(truth < 8.0)  # the scene is built so every true ray is in range
    r = np.asarray(scan.ranges)
    r = np.where(np.isfinite(r), r, float(scan.range_max))  # a missed ray reads as far as it can
    e = np.abs(r - truth)
    return e.mean(), np.median(e)


def test_untilted_baseline_and_stabilized_are_the_truth():
    depth = jnp.asarray(_render(0.0, 0.0), jnp.float32)
    base, stab = _baseline(depth, K, 30), _stabilized(depth, K, 0.0, 0.0, 30)
    np.testing.assert_array_equal(base.ranges, stab.ranges)
    np.testing.assert_allclose(stab.ranges, _true_level_ranges(stab.bearings), rtol=1e-5)


@pytest.mark.parametrize("roll_deg,pitch_deg", [(5, 0), (-5, 0), (0, 5), (0, -5), (-8, 6), (10, -10), (15, 3)])
def test_stabilized_beats_baseline_and_level_beats_stabilized(roll_deg, pitch_deg):
    roll, pitch = math.radians(roll_deg), math.radians(pitch_deg)
    depth = jnp.asarray(_render(roll, pitch), jnp.float32)
    base_mean, _ = _errors(_baseline(depth, K, 30))
    stab_mean, stab_median = _errors(_stabilized(depth, K, roll, pitch, 30))
    level = _level(depth, K, roll, pitch, 30)
    level_mean, level_median = _errors(level)
    assert stab_mean < 0.25 * base_mean
    assert level_mean < stab_mean and level_median < stab_median
    assert level_median < 0.01  # metres
    assert np.mean(np.isfinite(level.ranges)) > 0.97


def _reference_stabilized(depth, fx, fy, cx, cy, roll, pitch, h, range_min, range_max, reduce=min):
    """Loop over columns and band rows, word for word the slicing definition (float32 like the kernel);
    `reduce` combines a column's valid ranges (the definition's min, or np.median)."""
    height, width = depth.shape
    f32 = np.float32
    ranges = np.full(width, np.inf, f32)
    for u in range(width):
        column = []
        for k in range(h):
            o = math.floor(cy - h / 2) + k
            v = int(np.round(o + (u - cx) * math.tan(-roll) - fy * math.tan(pitch)))
            if not 0 <= v < height:
                continue
            z = f32(depth[v, u])
            if not np.isfinite(z) or z <= 0:
                continue
            x = f32(u - f32(cx)) * z / f32(fx)
            r = np.sqrt(x * x + z * z)
            if range_min <= r <= range_max:
                column.append(r)
        if column:
            ranges[u] = reduce(column)
    return ranges


def _angles_off_half_pixel(rng, width, cx, fy, scale):
    """Random roll/pitch whose unrounded rows all keep 1e-3 px from a rounding tie, so float32 and
    float64 round the same way."""
    while True:
        roll, pitch = rng.uniform(-scale, scale, 2)
        frac = np.mod((np.arange(width) - cx) * math.tan(-roll) - fy * math.tan(pitch), 1.0)
        if np.min(np.abs(frac - 0.5)) > 1e-3:
            return float(roll), float(pitch)


@pytest.mark.parametrize(
    "seed,height,width,band,scale", [(0, 48, 64, 5, 0.3), (1, 60, 80, 12, 0.6), (2, 480, 640, 30, 0.25)]
)
def test_stabilized_matches_reference_loop_pixel_for_pixel(seed, height, width, band, scale):
    rng = np.random.default_rng(seed)
    depth = rng.uniform(0.0, 10.0, (height, width)).astype(np.float32)
    holes = rng.uniform(size=depth.shape)
    depth[holes < 0.1] = 0.0
    depth[(holes > 0.1) & (holes < 0.15)] = np.nan
    depth[(holes > 0.15) & (holes < 0.2)] = np.inf
    depth[:, 3] = 0.0  # a column with no reading at all
    fx, fy = rng.uniform(0.5, 0.7, 2) * width
    cx, cy = width / 2 + rng.uniform(-3, 3), height / 2 + rng.uniform(-3, 3)
    fx, fy, cx, cy = (float(np.float32(c)) for c in (fx, fy, cx, cy))
    for _ in range(3):
        roll, pitch = _angles_off_half_pixel(rng, width, cx, fy, scale)
        scan = _stabilized(jnp.asarray(depth), (fx, fy, cx, cy), jnp.float32(roll), jnp.float32(pitch), band)
        ref = _reference_stabilized(depth, fx, fy, cx, cy, roll, pitch, band, 0.2, 8.0)
        np.testing.assert_allclose(scan.ranges, ref, rtol=1e-6)  # same pixel in every column
        assert np.isinf(scan.ranges[3])
        assert not np.any(np.isnan(scan.ranges))
        np.testing.assert_allclose(scan.bearings, np.arctan2(-(np.arange(width) - cx), fx), rtol=1e-6, atol=1e-7)


@pytest.mark.parametrize("cy", [2.0, 23.5, 44.0, -20.0, 70.0])
def test_baseline_matches_reference_loop_when_the_band_overhangs_the_image(cy):
    # The baseline reads its band as one slice moved onto the image: only band rows on the image count.
    rng = np.random.default_rng(5)
    depth = rng.uniform(0.0, 10.0, (48, 64)).astype(np.float32)
    depth[rng.uniform(size=depth.shape) < 0.1] = np.nan
    intrinsics = (40.0, 40.0, 31.5, cy)
    scan = _baseline(jnp.asarray(depth), intrinsics, 12)
    ref = _reference_stabilized(depth, *intrinsics, 0.0, 0.0, 12, 0.2, 8.0)
    np.testing.assert_allclose(scan.ranges, ref, rtol=1e-6)
    if cy in (-20.0, 70.0):
        assert np.all(np.isinf(scan.ranges))


@pytest.mark.parametrize("band", [1, 4, 5])
def test_median_band_matches_reference_loop(band):
    # Holes make columns with every count of valid rows from 0 to the band height, odd and even.
    rng = np.random.default_rng(10 + band)
    depth = rng.uniform(0.0, 10.0, (48, 64)).astype(np.float32)
    depth[rng.uniform(size=depth.shape) < 0.3] = 0.0
    intrinsics = (40.0, 40.0, 31.5, 23.5)
    roll, pitch = _angles_off_half_pixel(rng, 64, 31.5, 40.0, 0.3)
    stab = jax.jit(stabilized_scan, static_argnums=(4, 7))
    got = stab(jnp.asarray(depth), intrinsics, jnp.float32(roll), jnp.float32(pitch), band, 0.2, 8.0, "median")
    ref = _reference_stabilized(depth, *intrinsics, roll, pitch, band, 0.2, 8.0, reduce=np.median)
    np.testing.assert_allclose(got.ranges, ref, rtol=1e-6)
    base = jax.jit(baseline_scan, static_argnums=(2, 5))(jnp.asarray(depth), intrinsics, band, 0.2, 8.0, "median")
    ref0 = _reference_stabilized(depth, *intrinsics, 0.0, 0.0, band, 0.2, 8.0, reduce=np.median)
    np.testing.assert_allclose(base.ranges, ref0, rtol=1e-6)
    with pytest.raises(ValueError, match="band_reduce"):
        stabilized_scan(jnp.asarray(depth), intrinsics, 0.0, 0.0, band, 0.2, 8.0, "mean")


def test_band_minimum_reads_noisy_walls_short_and_the_median_does_not():
    # A wall 4 m ahead with independent noise of std 0.16 m per pixel (1 % of z^2): the minimum of 5
    # readings has mean -1.163 sigma (expected minimum of 5 standard normals), the median mean 0.
    sigma, band = 0.16, 5
    images = jnp.asarray(4.0 + sigma * np.random.default_rng(3).standard_normal((4000, band, 1)), jnp.float32)
    fn = jax.jit(jax.vmap(baseline_scan, in_axes=(0, None, None, None, None, None)), static_argnums=(2, 5))
    intrinsics = (10.0, 10.0, 0.0, band / 2)  # one column on the optical axis: range = depth
    low, mid = fn(images, intrinsics, band, 0.2, 8.0, "min"), fn(images, intrinsics, band, 0.2, 8.0, "median")
    n = images.shape[0]
    assert abs(float(jnp.mean(low.ranges)) - 4.0 + 1.163 * sigma) < 4 * 0.67 * sigma / np.sqrt(n)
    assert abs(float(jnp.mean(mid.ranges)) - 4.0) < 4 * 0.54 * sigma / np.sqrt(n)


def test_numpy_depth_images_are_accepted():
    depth = np.random.default_rng(6).uniform(0.1, 9.0, (60, 80)).astype(np.float32)
    small_K = (70.0, 70.0, 39.5, 29.5)
    for scan in (
        lambda d: stabilized_scan(d, small_K, 0.05, -0.02, 6),
        lambda d: baseline_scan(d, small_K, 6),
        lambda d: level_scan(d, small_K, 0.05, -0.02, 6),
    ):
        np.testing.assert_array_equal(scan(depth).ranges, scan(jnp.asarray(depth)).ranges)


def test_bearing_sign_left_is_positive():
    # A wall patch only in the left half of the image must appear at positive bearings.
    depth = np.zeros((HEIGHT, WIDTH), np.float32)
    depth[:, :100] = 2.0
    for scan in (_stabilized(jnp.asarray(depth), K, 0.0, 0.0, 30), _level(jnp.asarray(depth), K, 0.0, 0.0, 30)):
        seen = np.isfinite(scan.ranges)
        assert seen.any() and np.all(scan.bearings[seen] > 0)


@pytest.mark.parametrize("roll,pitch", [(0.0, 1.5), (0.0, -1.5), (float("nan"), 0.0), (0.3, float("inf"))])
def test_no_nan_for_extreme_or_invalid_angles(roll, pitch):
    depth = jnp.asarray(_render(0.0, 0.0), jnp.float32)
    for scan in (_stabilized(depth, K, roll, pitch, 30), _level(depth, K, roll, pitch, 30)):
        assert not np.any(np.isnan(scan.ranges)) and not np.any(np.isnan(scan.bearings))
    # Looking straight down or up at +-86 deg leaves the band off the image: every ray reads +inf.
    if math.isfinite(roll) and abs(pitch) > 1.4:
        assert np.all(np.isinf(_stabilized(depth, K, roll, pitch, 30).ranges))


def test_all_invalid_image_gives_inf_everywhere():
    depth = jnp.full((HEIGHT, WIDTH), jnp.nan).at[::2].set(0.0)
    for scan in (_baseline(depth, K, 30), _stabilized(depth, K, 0.1, -0.1, 30), _level(depth, K, 0.1, -0.1, 30)):
        assert np.all(np.isinf(scan.ranges)) and np.all(scan.ranges > 0)


def test_range_limits_are_applied():
    depth = jnp.asarray(_render(0.0, 0.0), jnp.float32)
    for scan in (_stabilized(depth, K, 0.0, 0.0, 30, 1.0, 4.0), _level(depth, K, 0.0, 0.0, 30, 1.0, 4.0)):
        r = np.asarray(scan.ranges)
        assert np.all((np.isinf(r)) | ((r >= 1.0) & (r <= 4.0)))
        assert np.isinf(r).any() and np.isfinite(r).any()


def test_vmap_over_images_matches_single_calls_and_grad_is_finite():
    rng = np.random.default_rng(4)
    small_K = (70.0, 70.0, 39.5, 29.5)  # an 80 x 60 camera keeps the compiles short
    depth = jnp.asarray(rng.uniform(0.1, 9.0, (3, 60, 80)), jnp.float32).at[:, 20:40, 10:20].set(jnp.nan)
    roll, pitch = jnp.array([0.05, -0.1, 0.0]), jnp.array([-0.08, 0.04, 0.12])
    for kernel in (stabilized_scan, level_scan):
        batch = jax.jit(jax.vmap(kernel, in_axes=(0, None, 0, 0, None)), static_argnums=4)(
            depth, small_K, roll, pitch, 6
        )
        single = jax.jit(kernel, static_argnums=4)
        for i in range(3):
            one = single(depth[i], small_K, roll[i], pitch[i], 6)
            np.testing.assert_allclose(batch.ranges[i], one.ranges, rtol=1e-6)

        def loss(d, r, p, kernel=kernel):
            ranges = kernel(d, small_K, r, p, 6).ranges
            return jnp.sum(jnp.where(jnp.isfinite(ranges), ranges, 0.0))

        grads = jax.jit(jax.grad(loss, argnums=(0, 1, 2)))(depth[0], roll[0], pitch[0])
        assert all(np.all(np.isfinite(g)) for g in grads)
        assert float(jnp.abs(grads[0]).sum()) > 0


def test_level_scan_bins_and_checks():
    scan = _level(jnp.ones((HEIGHT, WIDTH)), K, 0.0, 0.0, 30)
    assert scan.ranges.shape == scan.bearings.shape == (320,)
    assert np.all(np.diff(scan.bearings) > 0)
    np.testing.assert_allclose(np.asarray(scan.bearings)[[0, -1]], [-math.atan2(CX, FX), math.atan2(CX, FX)], atol=3e-3)
    with pytest.raises(ValueError, match="band_height"):
        stabilized_scan(jnp.ones((HEIGHT, WIDTH)), K, 0.0, 0.0, 0)
    # Rejected by the explicit check, or first by the runtime shape check of the tests' type checker.
    with pytest.raises((ValueError, TypeError), match="depth"):
        baseline_scan(jnp.ones(WIDTH), K, 5)
