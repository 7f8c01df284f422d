"""A robot's rectangular planform: its overlap with the yaw-rotated boxes of a world (the collision judge),
the disks that cover it (what a costmap-based controller checks), and points of its outline.

Two rectangles in the plane are disjoint exactly when their projections onto one of the four edge
normals (two per rectangle) are disjoint (the separating axis theorem); otherwise they overlap
(touching counts as overlap). The boxes' heights are ignored: every box stands on the floor and
rises above the robot's base.

Covering disks: `n` equal disks centred on the rectangle's long axis, one per 1/n of its length, each reaching
its slice's corners (radius sqrt(half_width^2 + (half_length / n)^2)). A disk is clear of obstacles when its
centre is farther than the radius from them, so a costmap whose inscribed radius is that radius tests the
whole footprint with `n` look-ups (to within the grid's resolution) (the circle decomposition of car
planners).
"""

from __future__ import annotations

import jax.numpy as jnp
from jaxtyping import Array, Bool, Float

from jaxquad.kernels.lie import R2
from jaxquad.kernels.raycast import Boxes


def _axes(yaw: Float[Array, "*B"]) -> Float[Array, "*B 2 2"]:
    return jnp.swapaxes(R2(yaw), -1, -2)  # rows: the rectangle's unit axes in the world


def footprint_disks(
    center: Float[Array, " 2"], half_extents: Float[Array, " 2"], n: int = 3
) -> tuple[Float[Array, "K 2"], Float[Array, ""]]:
    """Centres (base frame, m) and common radius (m) of `n` disks covering the rectangle of `half_extents`
    (along the base's x and y) centred at `center`; the long axis is the longer of the two."""
    center, half = jnp.asarray(center, jnp.float32), jnp.asarray(half_extents, jnp.float32)
    along_x = half[0] >= half[1]
    long, short = jnp.maximum(half[0], half[1]), jnp.minimum(half[0], half[1])
    offsets = long * (2.0 * jnp.arange(n, dtype=jnp.float32) + 1.0 - n) / n  # slice centres
    axis = jnp.where(along_x, jnp.array([1.0, 0.0]), jnp.array([0.0, 1.0]))
    return center + offsets[:, None] * axis, jnp.sqrt(short**2 + (long / n) ** 2)


def footprint_outline(center: Float[Array, " 2"], half_extents: Float[Array, " 2"]) -> Float[Array, "6 2"]:
    """Points of the rectangle's outline (base frame, m): its 4 corners and the middles of its 2 long sides, the
    points a turn swings farthest."""
    center, half = jnp.asarray(center, jnp.float32), jnp.asarray(half_extents, jnp.float32)
    signs = jnp.array([[1.0, 1.0], [1.0, -1.0], [-1.0, 1.0], [-1.0, -1.0]])
    long_x = half[0] >= half[1]
    sides = jnp.where(long_x, jnp.array([[0.0, 1.0], [0.0, -1.0]]), jnp.array([[1.0, 0.0], [-1.0, 0.0]]))
    return center + jnp.concatenate([signs, sides]) * half


def footprint_overlaps(boxes: Boxes, pose: Float[Array, " 3"], half_extents: Float[Array, " 2"]) -> Bool[Array, " B"]:
    """Which boxes the rectangle of `half_extents` (m, along the base's x and y) centred at the planar
    pose (x, y (m), yaw (rad)) overlaps."""
    a = _axes(pose[2])  # (2, 2): rows are the footprint's unit axes
    b = _axes(boxes.yaw)  # (B, 2, 2)
    d = boxes.center[:, :2] - pose[:2]  # (B, 2)
    normals = jnp.concatenate([jnp.broadcast_to(a, b.shape), b], axis=1)  # (B, 4, 2)
    r_a = jnp.sum(half_extents * jnp.abs(jnp.einsum("bkj,ij->bki", normals, a)), -1)
    r_b = jnp.sum(boxes.half[:, None, :2] * jnp.abs(jnp.einsum("bkj,bij->bki", normals, b)), -1)
    gap = jnp.abs(jnp.einsum("bkj,bj->bk", normals, d))
    return jnp.all(gap <= r_a + r_b, axis=-1)
