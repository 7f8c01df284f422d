"""The box/floor depth caster against MuJoCo C's mj_ray and a closed-form wall depth."""

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
import pytest

from jaxquad.kernels import Boxes, cast_depth, pinhole_rays, ray_distance

_RNG = np.random.default_rng(7)
_CENTERS = np.c_[_RNG.uniform(-4, 4, (12, 2)), _RNG.uniform(0.1, 1.0, 12)]
_HALF = _RNG.uniform(0.05, 0.8, (12, 3))
_YAW = _RNG.uniform(-np.pi, np.pi, 12)
_BOXES = Boxes(jnp.asarray(_CENTERS, jnp.float32), jnp.asarray(_HALF, jnp.float32), jnp.asarray(_YAW, jnp.float32))
_K = np.array([[40.0, 0, 31.5], [0, 40.0, 23.5], [0, 0, 1]])
_cast = jax.jit(cast_depth)


def _mujoco_scene() -> tuple[mujoco.MjModel, mujoco.MjData]:
    geoms = "".join(
        f'<geom type="box" pos="{c[0]} {c[1]} {c[2]}" size="{h[0]} {h[1]} {h[2]}" euler="0 0 {y}"/>'
        for c, h, y in zip(_CENTERS, _HALF, _YAW)
    )
    xml = (
        f'<mujoco><compiler angle="radian"/><worldbody><geom name="floor" type="plane" size="0 0 1"/>{geoms}'
        "</worldbody></mujoco>"
    )
    m = mujoco.MjModel.from_xml_string(xml)
    d = mujoco.MjData(m)
    mujoco.mj_forward(m, d)
    return m, d


def _look_at(yaw: float, pitch: float, roll: float) -> np.ndarray:
    """R_world_cam of an optical frame whose z axis points along yaw/pitch (pitch > 0 looks down)."""
    # Optical axes of a level camera looking along +x: z_opt = x, x_opt = -y, y_opt = -z.
    R_level = np.array([[0, 0, 1], [-1, 0, 0], [0, -1, 0]], float)
    cz, sz, cp, sp = np.cos(yaw), np.sin(yaw), np.cos(pitch), np.sin(pitch)
    Rz = np.array([[cz, -sz, 0], [sz, cz, 0], [0, 0, 1]])
    Ry = np.array([[cp, 0, sp], [0, 1, 0], [-sp, 0, cp]])
    Rx = np.array([[1, 0, 0], [0, np.cos(roll), -np.sin(roll)], [0, np.sin(roll), np.cos(roll)]])
    return Rz @ Ry @ Rx @ R_level


@pytest.mark.parametrize(
    "pose", [((0.0, 0.0, 0.3), 0.3, 0.1, 0.0), ((1.0, -2.0, 0.5), 2.0, 0.4, 0.2), ((-3.0, 3.0, 0.25), -1.2, -0.1, -0.3)]
)
def test_matches_mj_ray(pose):
    p, yaw, pitch, roll = pose
    R = _look_at(yaw, pitch, roll)
    rays = pinhole_rays(_K, 48, 64)
    depth = np.asarray(_cast(jnp.asarray(p, jnp.float32), jnp.asarray(R, jnp.float32), jnp.asarray(rays), _BOXES))
    m, d = _mujoco_scene()
    d_world = rays.astype(np.float64) @ R.T
    ref = np.empty(depth.shape)
    geomid = np.zeros(1, np.int32)
    for idx in np.ndindex(depth.shape):
        vec = d_world[idx]
        dist = mujoco.mj_ray(m, d, np.asarray(p, float), vec, None, 1, -1, geomid)
        ref[idx] = np.inf if dist < 0 else dist  # distance in units of vec, whose optical z is 1
    # A camera inside a box sees differently in mj_ray; the chosen poses are all in free space.
    assert np.array_equal(np.isinf(depth), np.isinf(ref))
    finite = ref < 50.0  # float32 keeps ~1e-4 relative precision only up to tens of metres
    np.testing.assert_allclose(depth[finite], ref[finite], rtol=1e-4, atol=1e-4)


def test_wall_depth_closed_form():
    # A wall (x = 3) facing a camera at the origin looking along +x: z-depth is 3 m at every pixel,
    # and the slant range of pixel (u, v) is 3 * |ray|.
    wall = Boxes(jnp.array([[3.5, 0.0, 1.0]]), jnp.array([[0.5, 50.0, 50.0]]), jnp.zeros(1))
    rays = pinhole_rays(_K, 48, 64)
    depth = np.asarray(
        _cast(jnp.array([0.0, 0.0, 1.0]), jnp.asarray(_look_at(0, 0, 0), jnp.float32), jnp.asarray(rays), wall, -100.0)
    )
    np.testing.assert_allclose(depth, 3.0, rtol=1e-6)
    # Same wall rotated 30 deg about z through the optical axis point (3, 0): the depth of pixel
    # column u follows the line x cos(a) + y sin(a) = 3 cos(a), i.e. z = 3 / (1 - tan(a) * xr),
    # where xr is the ray's optical x (= -y_world per unit depth).
    a = np.deg2rad(30.0)
    tilted = Boxes(
        jnp.array([[3.0 + 0.5 * np.cos(a), 0.5 * np.sin(a), 1.0]]), jnp.array([[0.5, 50.0, 50.0]]), jnp.array([a])
    )
    depth = np.asarray(
        _cast(
            jnp.array([0.0, 0.0, 1.0]), jnp.asarray(_look_at(0, 0, 0), jnp.float32), jnp.asarray(rays), tilted, -100.0
        )
    )
    xr = rays[..., 0]
    np.testing.assert_allclose(depth, 3.0 / (1.0 - np.tan(a) * xr), rtol=1e-5)


def test_floor_only_and_parallel_rays_finite():
    # Rays exactly parallel to box faces and to the floor must give inf or a finite hit, never NaN.
    box = Boxes(jnp.array([[2.0, 0.0, 0.5]]), jnp.array([[0.5, 0.5, 0.5]]), jnp.zeros(1))
    d = jnp.array([[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, -1.0], [1.0, 0.0, -0.5]])
    t = np.asarray(jax.jit(ray_distance)(jnp.array([0.0, 0.0, 0.5]), d, box))
    np.testing.assert_allclose(t, [1.5, np.inf, 0.5, 1.0])


def test_vmap_over_cameras():
    rays = jnp.asarray(pinhole_rays(_K, 12, 16))
    p = jnp.array([[0.0, 0.0, 0.3], [1.0, -2.0, 0.5]])
    R = jnp.stack([jnp.asarray(_look_at(0.3, 0.1, 0.0)), jnp.asarray(_look_at(2.0, 0.4, 0.2))]).astype(jnp.float32)
    batched = jax.vmap(cast_depth, in_axes=(0, 0, None, None))(p, R, rays, _BOXES)
    for i in range(2):
        np.testing.assert_allclose(np.asarray(batched[i]), np.asarray(_cast(p[i], R[i], rays, _BOXES)), rtol=1e-6)
