"""Footprint-box overlap (separating axes) against an independent polygon test: two convex polygons
intersect iff an edge of one crosses an edge of the other or one holds a vertex of the other."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxquad.kernels.footprint import footprint_disks, footprint_outline, footprint_overlaps
from jaxquad.kernels.raycast import Boxes

_overlaps = jax.jit(footprint_overlaps)


def _corners(cx, cy, hx, hy, yaw):
    c, s = np.cos(yaw), np.sin(yaw)
    local = np.array([[hx, hy], [-hx, hy], [-hx, -hy], [hx, -hy]])
    return np.array([cx, cy]) + local @ np.array([[c, s], [-s, c]])


def _cross(o, a, b):
    return (a[0] - o[0]) * (b[1] - o[1]) - (a[1] - o[1]) * (b[0] - o[0])


def _segments_cross(p1, p2, q1, q2):
    d1, d2 = _cross(q1, q2, p1), _cross(q1, q2, p2)
    d3, d4 = _cross(p1, p2, q1), _cross(p1, p2, q2)
    return (d1 * d2 < 0) and (d3 * d4 < 0)


def _inside(poly, p):
    signs = [_cross(poly[i], poly[(i + 1) % 4], p) for i in range(4)]
    return all(s > 0 for s in signs) or all(s < 0 for s in signs)


def _reference(a, b) -> bool:
    edges = lambda P: [(P[i], P[(i + 1) % 4]) for i in range(4)]  # noqa: E731
    if any(_segments_cross(*e, *f) for e in edges(a) for f in edges(b)):
        return True
    return any(_inside(a, v) for v in b) or any(_inside(b, v) for v in a)


@pytest.mark.parametrize("seed", [0, 1])
def test_overlap_matches_polygon_reference(seed):
    rng = np.random.default_rng(seed)
    n = 64
    boxes = Boxes(
        center=jnp.asarray(np.c_[rng.uniform(-3, 3, (n, 2)), np.ones(n)], jnp.float32),
        half=jnp.asarray(np.c_[rng.uniform(0.05, 1.0, (n, 2)), np.ones(n)], jnp.float32),
        yaw=jnp.asarray(rng.uniform(-np.pi, np.pi, n), jnp.float32),
    )
    hits, checked = 0, 0
    for _ in range(12):
        pose = np.r_[rng.uniform(-2, 2, 2), rng.uniform(-np.pi, np.pi)]
        half = rng.uniform(0.1, 0.4, 2)
        got = np.asarray(_overlaps(boxes, jnp.asarray(pose, jnp.float32), jnp.asarray(half, jnp.float32)))
        a = _corners(*pose[:2], *half, pose[2])
        for k in range(n):
            b = _corners(*np.asarray(boxes.center[k, :2]), *np.asarray(boxes.half[k, :2]), float(boxes.yaw[k]))
            ref = _reference(a, b)
            # Skip near-touching pairs, where float32 and float64 may disagree.
            shrunk = _reference(_corners(*pose[:2], *(half - 1e-3), pose[2]), b)
            grown = _reference(_corners(*pose[:2], *(half + 1e-3), pose[2]), b)
            if shrunk == grown:
                assert got[k] == ref, (pose, half, k)
                checked += 1
                hits += ref
    assert checked > 600 and 20 < hits < checked - 20  # both answers exercised


def test_overlap_under_vmap_and_touching_counts():
    boxes = Boxes(center=jnp.array([[1.0, 0.0, 0.5]]), half=jnp.array([[0.5, 0.5, 0.5]]), yaw=jnp.zeros(1))
    poses = jnp.array([[0.2, 0.0, 0.0], [0.29, 0.0, 0.0], [-0.5, 0.0, 0.0], [0.0, 0.0, np.pi / 2]])
    got = jax.vmap(footprint_overlaps, in_axes=(None, 0, None))(boxes, poses, jnp.array([0.3, 0.1]))
    # x-extent reaches 0.5 at pose 0.2 (touching), 0.59 at 0.29, -0.2 at -0.5; turned 90 deg it reaches 0.1.
    np.testing.assert_array_equal(np.asarray(got)[:, 0], [True, True, False, False])


@pytest.mark.parametrize("half", [(0.315, 0.17), (0.1, 0.4), (0.2, 0.2)])
def test_disks_cover_the_rectangle_tightly(half):
    """Every point of the rectangle lies in a disk, and the farthest one (a corner) exactly at the radius:
    brute force over a dense grid of the rectangle."""
    center = np.array([-0.07, 0.03])
    disks, radius = footprint_disks(jnp.asarray(center), jnp.asarray(half), n=3)
    disks, radius = np.asarray(disks, float), float(radius)
    gx, gy = np.meshgrid(np.linspace(-half[0], half[0], 121), np.linspace(-half[1], half[1], 121))
    pts = center + np.c_[gx.ravel(), gy.ravel()]
    nearest = np.min(np.linalg.norm(pts[:, None] - disks[None], axis=-1), axis=1)
    assert nearest.max() <= radius + 1e-6
    np.testing.assert_allclose(nearest.max(), radius, rtol=1e-5)
    long = int(np.argmax(half))
    np.testing.assert_allclose(disks[:, 1 - long], center[1 - long], atol=1e-7)  # on the long axis
    np.testing.assert_allclose(np.diff(disks[:, long]), 2 * max(half) / 3, rtol=1e-5)


@pytest.mark.parametrize("half", [(0.315, 0.17), (0.1, 0.4)])
def test_outline_is_the_corners_and_the_long_sides_middles(half):
    center = np.array([-0.07, 0.03])
    got = np.asarray(footprint_outline(jnp.asarray(center), jnp.asarray(half)), float)
    corners = _corners(*center, *half, 0.0)
    long = int(np.argmax(half))
    middles = [center + s * half[1 - long] * np.eye(2)[1 - long] for s in (1, -1)]
    want = np.concatenate([corners, middles])
    assert got.shape == (6, 2)
    # The same points in any order: each wanted point matched by exactly one point given.
    d = np.linalg.norm(got[:, None] - want[None], axis=-1)
    np.testing.assert_array_equal(np.sort(d.argmin(axis=1)), np.arange(6))
    np.testing.assert_allclose(d.min(axis=1), 0.0, atol=1e-6)
