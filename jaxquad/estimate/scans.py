"""Laser scans from a log's depth images with the estimated attitude (one robot).

Each depth frame takes the roll and pitch (ZYX Euler angles of R_world_base) of the latest pipeline
sample at or before its stamp, and is sliced twice: the IMU-stabilized band and the fixed-row
baseline (kernels.stabilized_scan / baseline_scan, vmapped over frames); on request a third time,
the gravity-levelled scan (kernels.level_scan, one bin per image column). The kernels assume the
camera looks along the base x axis; a mount tilt in T_base_camera is not compensated.
"""

from __future__ import annotations

import functools

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from jaxquad.kernels import CameraIntrinsics, baseline_scan, level_scan, stabilized_scan
from jaxquad.kernels.lie import roll_pitch


class LogScans(eqx.Module):
    """Scans of F frames over W image columns."""

    ranges_stabilized: Float[Array, "F W"]  # m, +inf where no valid pixel
    ranges_baseline: Float[Array, "F W"]
    bearings: Float[Array, "W"]  # rad, counter-clockwise from forward
    roll: Float[Array, "F"]  # rad, attitude used per frame
    pitch: Float[Array, "F"]
    ranges_level: Float[Array, "F W"] | None = None  # m, gravity-levelled scan (when asked for)
    bearings_level: Float[Array, "W"] | None = None  # rad, its bin centres


@functools.partial(jax.jit, static_argnames=("band_height", "band_reduce"))
def _slice(depth, intrinsics, roll, pitch, band_height, range_min, range_max, band_reduce):
    stab = jax.vmap(
        lambda d, r, p: stabilized_scan(d, intrinsics, r, p, band_height, range_min, range_max, band_reduce)
    )
    base = jax.vmap(lambda d: baseline_scan(d, intrinsics, band_height, range_min, range_max, band_reduce))
    s, b = stab(depth, roll, pitch), base(depth)
    return s.ranges, b.ranges, s.bearings[0]


@functools.partial(jax.jit, static_argnames=("band_height",))
def _slice_level(depth, intrinsics, roll, pitch, band_height, range_min, range_max):
    n_bins = depth.shape[-1]
    lev = jax.vmap(lambda d, r, p: level_scan(d, intrinsics, r, p, band_height, range_min, range_max, n_bins))
    s = lev(depth, roll, pitch)
    return s.ranges, s.bearings[0]


def frame_samples(t: np.ndarray, depth_t: np.ndarray) -> np.ndarray:
    """Index of the latest log sample at or before each depth frame (the first sample for earlier
    frames): the sample whose attitude and pose belong to that frame."""
    return np.clip(np.searchsorted(t, depth_t, side="right") - 1, 0, t.size - 1)


def log_scans(
    depth: np.ndarray,
    depth_t: np.ndarray,
    K: np.ndarray,
    t: np.ndarray,
    q_world_base: np.ndarray,
    band_height: int = 5,
    range_min: float = 0.2,
    range_max: float = 8.0,
    level: bool = False,
    band_reduce: str = "median",
) -> LogScans:
    """Scans of depth (F, H, W) at depth_t (F,) s, attitude q_world_base (T, 4) at t (T,) s; `level`
    adds the gravity-levelled scan (always the minimum per bin); `band_reduce` ("median" or the paper's
    "min", see `jaxquad.kernels.scan`) reduces the stabilized and baseline bands."""
    k = frame_samples(t, depth_t)
    roll, pitch = roll_pitch(jnp.asarray(q_world_base[k], jnp.float32))
    intr = CameraIntrinsics(*(jnp.asarray(K[i, j], jnp.float32) for i, j in ((0, 0), (1, 1), (0, 2), (1, 2))))
    stab, base, bearings = _slice(
        jnp.asarray(depth, jnp.float32),
        intr,
        roll,
        pitch,
        band_height,
        jnp.asarray(range_min, jnp.float32),
        jnp.asarray(range_max, jnp.float32),
        band_reduce,
    )
    extra = {}
    if level:
        lev, bearings_level = _slice_level(
            jnp.asarray(depth, jnp.float32),
            intr,
            roll,
            pitch,
            band_height,
            jnp.asarray(range_min, jnp.float32),
            jnp.asarray(range_max, jnp.float32),
        )
        extra = {"ranges_level": lev, "bearings_level": bearings_level}
    return LogScans(ranges_stabilized=stab, ranges_baseline=base, bearings=bearings, roll=roll, pitch=pitch, **extra)
