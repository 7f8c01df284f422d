"""Depth images by ray casting against a floor plane and yaw-rotated boxes (slab method).

One camera, all pixels and all boxes at once by broadcasting: the per-box hit distances of a
pixel are reduced with a `min` over the box axis, which XLA fuses with the slab arithmetic, so
the (H, W, B) intermediate is never stored. `vmap` over robots at the call site.

Camera convention: the optical frame (x right, y down, z forward, as OpenCV and RealSense use);
`pinhole_rays` gives per-pixel rays with z = 1, so the distance along such a ray is the z-depth
that depth cameras report.
"""

from __future__ import annotations

import equinox as eqx
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

# A ray component this small is treated as parallel to the slab (finite, so 0 * big stays 0).
_PARALLEL_EPS = 1e-12


class Boxes(eqx.Module):
    """Static boxes of one world, each rotated about the world z axis only."""

    center: Float[Array, "B 3"]  # world frame, m
    half: Float[Array, "B 3"]  # half extents along the box axes, m
    yaw: Float[Array, " B"]  # rotation about world z, rad


def pinhole_rays(K: np.ndarray, height: int, width: int) -> Float[np.ndarray, "H W 3"]:
    """Per-pixel ray directions in the optical frame, z component 1 (pixel centres at integers)."""
    u, v = np.meshgrid(np.arange(width, dtype=np.float64), np.arange(height, dtype=np.float64))
    x = (u - K[0, 2]) / K[0, 0]
    y = (v - K[1, 2]) / K[1, 1]
    return np.stack([x, y, np.ones_like(x)], axis=-1).astype(np.float32)


def _safe_inv(d: Array) -> Array:
    return 1.0 / jnp.where(jnp.abs(d) < _PARALLEL_EPS, _PARALLEL_EPS, d)


def ray_distance(
    p_world_origin: Float[Array, "3"],
    d_world: Float[Array, "*R 3"],
    boxes: Boxes,
    floor_z: float | Float[Array, ""] = 0.0,
) -> Float[Array, "*R"]:
    """Distance along each ray (in units of its direction vector) to the nearest surface; inf if none.

    Surfaces: the floor plane z = floor_z seen from above and the outside of every box. A box
    that contains the origin is ignored (the camera is never inside an obstacle).
    """
    c, s = jnp.cos(boxes.yaw), jnp.sin(boxes.yaw)  # (B,)
    delta = p_world_origin - boxes.center  # (B, 3)
    # Origin and directions in each box's frame: R_world_box^T = Rz(-yaw).
    o = jnp.stack([c * delta[:, 0] + s * delta[:, 1], -s * delta[:, 0] + c * delta[:, 1], delta[:, 2]], -1)
    dx, dy, dz = d_world[..., 0:1], d_world[..., 1:2], d_world[..., 2:3]  # (*R, 1) against (B,)
    d_box = (c * dx + s * dy, -s * dx + c * dy, jnp.broadcast_to(dz, jnp.broadcast_shapes(dz.shape, c.shape)))
    t_enter, t_exit = None, None
    for axis in range(3):
        inv = _safe_inv(d_box[axis])
        t1 = (-boxes.half[:, axis] - o[:, axis]) * inv
        t2 = (boxes.half[:, axis] - o[:, axis]) * inv
        lo, hi = jnp.minimum(t1, t2), jnp.maximum(t1, t2)
        t_enter = lo if t_enter is None else jnp.maximum(t_enter, lo)
        t_exit = hi if t_exit is None else jnp.minimum(t_exit, hi)
    hit = (t_exit >= t_enter) & (t_enter >= 0.0)
    t_box = jnp.min(jnp.where(hit, t_enter, jnp.inf), axis=-1)
    dz0 = d_world[..., 2]
    height = p_world_origin[2] - floor_z
    t_floor = jnp.where((dz0 < 0.0) & (height > 0.0), height / jnp.where(dz0 < 0.0, -dz0, 1.0), jnp.inf)
    return jnp.minimum(t_box, t_floor)


def cast_depth(
    p_world_cam: Float[Array, "3"],
    R_world_cam: Float[Array, "3 3"],
    rays_cam: Float[Array, "H W 3"],
    boxes: Boxes,
    floor_z: float | Float[Array, ""] = 0.0,
) -> Float[Array, "H W"]:
    """Noise-free z-depth image (m) of the optical frame `cam`; inf where a ray hits nothing.

    `rays_cam` are `pinhole_rays` (z = 1), so the distance along a ray equals its z-depth.
    """
    d_world = rays_cam @ R_world_cam.T
    return ray_distance(p_world_cam, d_world, boxes, floor_z)
