"""Obstacles under the scan plane, from every pixel of a depth image.

A 2D scan is the level plane through the camera (`kernels.scan`): a box lower than the camera (a pallet, a step)
is never in it, so no map built from scans holds it. ROS robots add such obstacles with pointcloud_to_laserscan's
height band or Nav2's voxel layer; this is that band as a scan. Every pixel is back-projected, levelled by the
IMU's roll and pitch, and kept when its height above the floor (the camera's height plus its levelled z) lies in
[z_min, z_max] and its horizontal range is at least range_min. The kept points are counted on a polar grid of
`n_bins` bearings by `n_ranges` cells of `range_step` m, and per bearing the range is the centre of the nearest
cell holding `min_points` points or more (inf: none), so that a lone noisy pixel marks nothing. The floor's own
points lie near height 0, under z_min.
"""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
from jaxtyping import Array, ArrayLike, Float

from jaxquad.kernels.scan import Intrinsics, Scan, _unpack, levelled_points


class LowObstacleParams(eqx.Module):
    """Traced numbers of the low-obstacle scan (m, but `min_points`)."""

    camera_height: Float[Array, ""]  # the camera's height above the floor
    z_min: Float[Array, ""]  # points lower than this above the floor are the floor's
    z_max: Float[Array, ""]  # and higher ones the scan plane's
    range_min: Float[Array, ""]
    range_step: Float[Array, ""]  # the polar grid's range cells
    min_points: Float[Array, ""]  # points a cell needs to hold an obstacle

    @classmethod
    def default(cls, camera_height: float, **overrides: float) -> LowObstacleParams:
        # 8 cm clears the floor's points (the levelled height errs by ~2 cm at 2.5 m under 0.3 deg of tilt error and
        # the trot's bobbing); 3 cm under the camera leaves the scan plane's own walls to the 2D scan.
        values = dict(z_min=0.08, z_max=camera_height - 0.03, range_min=0.3, range_step=0.05, min_points=3.0)
        values.update(overrides)
        return cls(
            camera_height=jnp.asarray(camera_height, jnp.float32),
            **{k: jnp.asarray(v, jnp.float32) for k, v in values.items()},
        )


def low_obstacle_scan(
    depth: Float[ArrayLike, "H W"],
    intrinsics: Intrinsics,
    roll: Float[ArrayLike, ""],
    pitch: Float[ArrayLike, ""],
    params: LowObstacleParams,
    n_bins: int = 80,
    n_ranges: int = 50,
) -> Scan:
    """The low-obstacle scan of one z-depth image (m; 0 or non-finite: invalid) from a camera `camera_height` m
    above the floor (see the module doc). Bins span the image's horizontal field of view, increasing; bearings are
    bin centres in the levelled frame (x forward, y left: the base's heading). `n_bins` and `n_ranges` are static;
    ranges reach `n_ranges * range_step` m."""
    depth = jnp.asarray(depth, jnp.float32)
    if depth.ndim != 2 or min(n_bins, n_ranges) < 1:
        raise ValueError(f"depth must be (H, W) and n_bins, n_ranges >= 1, got {depth.shape}, {n_bins}, {n_ranges}")
    fx, _, cx, _ = _unpack(intrinsics)
    height, width = depth.shape
    v, u = jnp.meshgrid(jnp.arange(height, dtype=jnp.float32), jnp.arange(width, dtype=jnp.float32), indexing="ij")
    good = jnp.isfinite(depth) & (depth > 0)
    p_level = levelled_points(jnp.where(good, depth, 0.0), u, v, intrinsics, roll, pitch)
    above_floor = params.camera_height + p_level[..., 2]
    r = jnp.hypot(p_level[..., 0], p_level[..., 1])
    lo, hi = jnp.arctan2(-(width - 1 - cx), fx), jnp.arctan2(cx, fx)
    step = (hi - lo) / n_bins
    index = jnp.floor((jnp.arctan2(p_level[..., 1], p_level[..., 0]) - lo) / step)
    cell = jnp.floor(r / params.range_step)
    valid = (
        good
        & (above_floor >= params.z_min)
        & (above_floor <= params.z_max)
        & (r >= params.range_min)
        & (cell < n_ranges)
        & (index >= 0)
        & (index < n_bins)
    )
    # Points left out go to one extra slot that is dropped.
    slot = jnp.where(valid, index * n_ranges + cell, n_bins * n_ranges).astype(jnp.int32).ravel()
    counts = jax.ops.segment_sum(valid.astype(jnp.int32).ravel(), slot, num_segments=n_bins * n_ranges + 1)
    enough = counts[:-1].reshape(n_bins, n_ranges).astype(jnp.float32) >= params.min_points
    nearest = jnp.argmax(enough, axis=1).astype(jnp.float32)
    return Scan(
        ranges=jnp.where(enough.any(axis=1), (nearest + 0.5) * params.range_step, jnp.inf),
        bearings=lo + (jnp.arange(n_bins, dtype=jnp.float32) + 0.5) * step,
        range_min=params.range_min,
        range_max=n_ranges * params.range_step,
    )
