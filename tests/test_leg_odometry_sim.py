"""Leg odometry on an MJX-simulated walk: each correction measured against the simulator's truth."""

import dataclasses

import jax
import numpy as np
import pytest
from scipy.spatial.transform import Rotation


@pytest.fixture(scope="module")
def walk(tmp_path_factory):
    from jaxquad.io import load_log
    from jaxquad.sim.cli import simulate
    from jaxquad.sim.fleet import FleetConfig

    out = tmp_path_factory.mktemp("walk")
    config = FleetConfig(
        robot="go2",
        world="warehouse",
        n_robots=1,
        style="aggressive",
        seed=8,
        depth=False,
    )
    return load_log(simulate(config, 6.0, out, progress=False))


def _estimate(log, **variant):
    from jaxquad.estimate import pipeline
    from jaxquad.robots import load

    robot = load("go2")
    inputs, config = pipeline.inputs_from_log(robot, log, "truth")
    config = dataclasses.replace(config, **variant)
    out = pipeline.estimate_fleet(robot, config, pipeline.PipelineParams.default(), inputs)
    return jax.tree.map(lambda a: np.asarray(a)[0], out)


@pytest.mark.slow  # one MJX fleet compile and three pipeline compiles: minutes on two shared cores
def test_rolling_contact_and_floor_reduce_the_error_against_simulated_truth(walk):
    t, gt = np.asarray(walk["t"]), np.asarray(walk["gt_pose"])[0]
    R = Rotation.from_quat(gt[:, [4, 5, 6, 3]]).as_matrix()
    v_true = np.einsum("tji,tj->ti", R, np.gradient(gt[:, :3], t, axis=0))
    point = _estimate(walk, rolling=False, robust="none", floor=False)
    full = _estimate(walk)
    ok = ~point.flags.no_stance & ~full.flags.no_stance
    ok[:5] = ok[-5:] = False
    speed = lambda v: np.linalg.norm(v[ok][:, :2], axis=1).sum()  # noqa: E731
    # Point feet under-count the speed by about r / (leg + r) (~7% for Go2); contact points do not.
    ratio_point, ratio_full = (
        speed(point.v_base) / speed(v_true),
        speed(full.v_base) / speed(v_true),
    )
    assert abs(1 - ratio_full) < 0.5 * abs(1 - ratio_point)
    assert ratio_point < 0.96
    # The floor bounds the height; without it the same model's integrated height sinks.
    z_err = lambda e: np.abs(e.p_world_base[:, 2] - gt[:, 2]).max()  # noqa: E731
    assert z_err(full) < 0.03 < z_err(_estimate(walk, floor=False))


@pytest.mark.slow  # shares the walk's MJX fleet compile
def test_a_sample_describes_one_instant(walk):
    # MuJoCo integrates q += dt qvel with the state's new velocity, so the base rotation from sample k-1
    # to k is the angular velocity of sample k's state: the gyro of the same sample must read it (up to
    # its noise and bias, a few mrad/s), not the one of the sample before (tenths of rad/s apart in a trot).
    from jaxquad.estimate.inputs import R_base_imu
    from jaxquad.robots import load

    t, gt = np.asarray(walk["t"], np.float64), np.asarray(walk["gt_pose"], np.float64)[0]
    R = Rotation.from_quat(gt[:, [4, 5, 6, 3]])
    omega = (R[:-1].inv() * R[1:]).as_rotvec() / np.diff(t)[:, None]  # base frame, samples 1..T-1
    gyro = np.asarray(walk["gyro"], np.float64)[0] @ R_base_imu(load("go2")).T
    rms = lambda a, b: np.sqrt(np.mean((a - b) ** 2))  # noqa: E731
    same, late = rms(gyro[2:], omega[1:]), rms(gyro[2:], omega[:-1])
    assert same < 0.02 and late > 5 * same
    assert t[0] == 0.0  # the first sample is the initial state
