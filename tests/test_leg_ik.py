"""Analytic leg IK/FK against MuJoCo C forward kinematics of the built-in robots."""

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
import pytest

from jaxquad.robots import load
from jaxquad.sim.gait_structure import Gait
from jaxquad.sim.leg_ik import leg_fk, leg_ik
from jaxquad.sim.locomotion import base_to_leg_trunk

ROBOTS = ("go2", "badger")


@pytest.fixture(scope="module", params=ROBOTS)
def robot_gait(request):
    robot = load(request.param)
    return robot, Gait.for_robot(robot)


def _random_poses(robot, gait, rng, n):
    """Joint configurations with every foot well below its hip and the knee clearly bent."""
    lo = np.asarray(gait.legs.q_min)
    hi = np.asarray(gait.legs.q_max)
    bend = np.asarray(gait.legs.knee_bend) * np.asarray(gait.legs.axis_sign[:, 2])
    poses = []
    while len(poses) < n:
        q = np.stack(
            [
                rng.uniform(-0.5, 0.5, 4),
                rng.uniform(-0.4, 1.2, 4),
                np.abs(rng.uniform(0.5, 2.2, 4)) * np.sign(np.asarray(gait.legs.axis_sign[:, 2]) * bend),
            ],
            -1,
        )
        q = np.clip(q, lo + 1e-3, hi - 1e-3)
        p = np.asarray(leg_fk(gait.legs, jnp.asarray(q, jnp.float32)))
        if np.all(p[:, 2] < np.asarray(gait.legs.p_trunk_hip)[:, 2] - 0.08):
            poses.append(q)
    return np.stack(poses)


def _mujoco_feet(robot, q_leg, q_spine):
    """Foot sites in the base frame from MuJoCo C, base at the origin with identity attitude."""
    m = robot.mj_model
    d = mujoco.MjData(m)
    d.qpos[:] = 0.0
    d.qpos[robot.base_qpos_adr + 3] = 1.0
    d.qpos[robot.qpos_adr[np.asarray(robot.leg_joints)]] = q_leg
    if robot.spine_joint is not None:
        d.qpos[m.joint(robot.spine_joint).qposadr[0]] = q_spine
    mujoco.mj_kinematics(m, d)
    return d.site_xpos[robot.foot_site_ids].copy()


def test_fk_matches_mujoco(robot_gait):
    robot, gait = robot_gait
    rng = np.random.default_rng(0)
    for q in _random_poses(robot, gait, rng, 10):
        p_ref = _mujoco_feet(robot, q, 0.0)
        p = np.asarray(leg_fk(gait.legs, jnp.asarray(q, jnp.float32)))
        np.testing.assert_allclose(p, p_ref, atol=2e-6)


def test_ik_round_trip_against_mujoco(robot_gait):
    robot, gait = robot_gait
    rng = np.random.default_rng(1)
    ik = jax.jit(lambda p, qs: leg_ik(gait.legs, base_to_leg_trunk(gait, p, qs)))
    for q in _random_poses(robot, gait, rng, 20):
        q_spine = rng.uniform(-0.3, 0.3) if robot.spine_joint is not None else 0.0
        p_base = _mujoco_feet(robot, q, q_spine)
        q_ik, reachable = ik(jnp.asarray(p_base, jnp.float32), jnp.float32(q_spine))
        assert np.all(np.asarray(reachable))
        np.testing.assert_allclose(np.asarray(q_ik), q, atol=1e-4)
        # The solved angles put MuJoCo's feet on the targets too.
        np.testing.assert_allclose(_mujoco_feet(robot, np.asarray(q_ik), q_spine), p_base, atol=1e-5)


def test_ik_vmaps_over_robots(robot_gait):
    robot, gait = robot_gait
    q = _random_poses(robot, gait, np.random.default_rng(2), 6)
    p = jax.vmap(leg_fk, in_axes=(None, 0))(gait.legs, jnp.asarray(q, jnp.float32))
    q_ik, _ = jax.jit(jax.vmap(leg_ik, in_axes=(None, 0)))(gait.legs, p)
    np.testing.assert_allclose(np.asarray(q_ik), q, atol=1e-4)


def test_unreachable_targets_are_clamped_and_finite(robot_gait):
    robot, gait = robot_gait
    hip = np.asarray(gait.legs.p_trunk_hip)
    far = hip + np.array([0.0, 0.0, -2.0])  # far below: beyond full stretch
    at_hip = hip.copy()  # singular: the target on the abduction axis
    for target in (far, at_hip, hip + np.array([5.0, 0.0, 0.0])):
        q, reachable = leg_ik(gait.legs, jnp.asarray(target, jnp.float32))
        q = np.asarray(q)
        assert np.all(np.isfinite(q))
        assert not np.any(np.asarray(reachable))
        assert np.all(q >= np.asarray(gait.legs.q_min) - 1e-6) and np.all(q <= np.asarray(gait.legs.q_max) + 1e-6)
    # Straight down beyond reach: the leg stretches (to its knee limit) below the home stance.
    q, _ = leg_ik(gait.legs, jnp.asarray(far, jnp.float32))
    p = np.asarray(leg_fk(gait.legs, q))
    assert np.all(p[:, 2] < np.asarray(gait.p_base_foot_home)[:, 2] - 0.05)
