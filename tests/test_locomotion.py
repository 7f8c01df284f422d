"""Trot controller on the built-in robots: long walks in MuJoCo C, one batched MJX rollout."""

import copy
import functools

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
import pytest
from mujoco import mjx

from jaxquad.robots import load
from jaxquad.sim.gait_structure import Gait
from jaxquad.sim.locomotion import GaitParams, gait_init, gait_step
from jaxquad.sim.route_follow import RouteParams, route_init, route_step

ROBOTS = ("go2", "badger")
_step = jax.jit(gait_step)


@functools.cache
def _robot_gait(name):
    robot = load(name)
    return robot, Gait.for_robot(robot)


def _roll_pitch(quat):
    w, x, y, z = quat.T
    roll = np.arctan2(2 * (w * x + y * z), 1 - 2 * (x * x + y * y))
    pitch = np.arcsin(np.clip(2 * (w * y - z * x), -1.0, 1.0))
    return np.degrees(roll), np.degrees(pitch)


def _walk_c(name, style, command, seconds, iterations=None):
    """MuJoCo C rollout with the jitted controller; ground-truth normal forces from mj_contactForce."""
    robot, gait = _robot_gait(name)
    model = robot.mj_model
    if iterations is not None:
        model = copy.copy(model)
        model.opt.iterations = iterations
        model.opt.ls_iterations = iterations
    params = getattr(GaitParams, style)(gait)
    data = mujoco.MjData(model)
    data.qpos[:] = robot.qpos_home
    data.qpos[2] = float(gait.body_height) + 0.005
    state = gait_init(gait, params)
    dt = model.opt.timestep
    cmd = jnp.asarray(command, jnp.float32)
    qpos, tau, phase, fz = [], [], [], []
    force = np.zeros(6)
    for i in range(int(round(seconds / dt))):
        state, u = _step(
            gait,
            params,
            state,
            jnp.asarray(data.qpos, jnp.float32),
            jnp.asarray(data.qvel, jnp.float32),
            cmd,
            jnp.float32(i * dt),
            jnp.float32(dt),
        )
        data.ctrl[:] = np.asarray(u)
        mujoco.mj_step(model, data)
        total = 0.0
        for c in range(data.ncon):
            mujoco.mj_contactForce(model, data, c, force)
            total += force[0]
        qpos.append(data.qpos.copy())
        tau.append(np.asarray(u))
        phase.append(float(state.phase))
        fz.append(total)
    assert bool(state.ok)
    return dict(qpos=np.array(qpos), tau=np.array(tau), phase=np.array(phase), fz=np.array(fz), dt=dt)


@functools.cache
def _walk(name, style):
    speed = 0.5 if style == "calm" else 1.0
    return _walk_c(name, style, (speed, 0.0, 0.0), 10.0)


def _check_upright(name, run, max_tilt_deg):
    _, gait = _robot_gait(name)
    h = run["qpos"][:, 2]
    roll, pitch = _roll_pitch(run["qpos"][:, 3:7])
    assert h.min() > 0.75 * float(gait.body_height), "base dropped: the robot fell"
    assert h.max() < 1.25 * float(gait.body_height)
    assert np.abs(roll).max() < max_tilt_deg and np.abs(pitch).max() < max_tilt_deg


@pytest.mark.parametrize("name", ROBOTS)
def test_calm_walks_3m_in_10s(name):
    run = _walk(name, "calm")
    _check_upright(name, run, max_tilt_deg=12.0)
    assert np.hypot(*run["qpos"][-1, :2]) >= 3.0
    robot, _ = _robot_gait(name)
    assert np.all(np.abs(run["tau"]) <= robot.torque_limit + 1e-4)


@pytest.mark.parametrize("name", ROBOTS)
def test_aggressive_walks_and_swings_attitude(name):
    run = _walk(name, "aggressive")
    _check_upright(name, run, max_tilt_deg=35.0)
    assert np.hypot(*run["qpos"][-1, :2]) >= 3.0
    roll, pitch = _roll_pitch(run["qpos"][:, 3:7])
    for angle in (roll, pitch):
        assert angle.max() >= 8.0 and angle.min() <= -8.0
    # Stop-and-go: the forward speed visits both standstill and near the top speed.
    vx = np.diff(run["qpos"][:, 0]) / run["dt"]
    smooth = np.convolve(vx, np.ones(100) / 100, mode="valid")  # 0.4 s averages
    assert smooth.min() < 0.25 and smooth.max() > 0.75


def test_badger_spine_follows_the_trot():
    robot, gait = _robot_gait("badger")
    run = _walk("badger", "calm")
    q_spine = run["qpos"][:, gait.spine_qpos]
    ref = np.sin(2 * np.pi * run["phase"])
    late = slice(len(ref) // 2, None)
    assert np.corrcoef(q_spine[late], ref[late])[0, 1] > 0.7
    assert np.ptp(q_spine[late]) > 0.04  # calm amplitude 0.05 rad: about a full swing


def test_walking_robot_follows_a_loop():
    robot, gait = _robot_gait("go2")
    model, params, route = robot.mj_model, GaitParams.calm(gait), RouteParams.default(v_max=0.4)
    wp = jnp.array([[0.0, 0.0], [3.0, 0.0], [3.0, 2.0], [0.0, 2.0]])
    data = mujoco.MjData(model)
    data.qpos[:] = robot.qpos_home
    state, rstate = gait_init(gait, params), route_init(wp, jnp.zeros(2))
    dt = model.opt.timestep

    @jax.jit
    def control(state, rstate, qpos, qvel, t):
        w, x, y, z = qpos[3:7]
        yaw = jnp.arctan2(2 * (w * z + x * y), 1 - 2 * (y * y + z * z))
        rstate, (cmd, _) = route_step(route, rstate, wp, jnp.stack([qpos[0], qpos[1], yaw]))
        state, u = gait_step(gait, params, state, qpos, qvel, cmd, t, jnp.float32(dt))
        return u, state, rstate

    xy, targets = [], []
    for i in range(int(20.0 / dt)):
        u, state, rstate = control(
            state, rstate, jnp.asarray(data.qpos, jnp.float32), jnp.asarray(data.qvel, jnp.float32), jnp.float32(i * dt)
        )
        data.ctrl[:] = np.asarray(u)
        mujoco.mj_step(model, data)
        xy.append(data.qpos[:2].copy())
        targets.append(int(rstate.target))
    xy = np.array(xy)
    assert {1, 2, 3} <= set(targets)  # went round three corners (8 m at 0.4 m/s would close the loop)
    assert np.linalg.norm(xy - np.array([3.0, 2.0]), axis=1).min() < 0.3
    late = xy[len(xy) // 2 :: 25]
    edges = [(wp[i], wp[(i + 1) % 4]) for i in range(4)]
    dist = [min(_segment_distance(p, np.asarray(a), np.asarray(b)) for a, b in edges) for p in late]
    assert max(dist) < 0.3 and np.median(dist) < 0.1


def _segment_distance(p, a, b):
    u = np.clip(np.dot(p - a, b - a) / np.dot(b - a, b - a), 0.0, 1.0)
    return np.linalg.norm(p - (a + u * (b - a)))


@pytest.mark.parametrize("name", ROBOTS)
def test_contact_forces_average_body_weight(name):
    # The controller's force balance, checked in MuJoCo C with a fully converged contact solver
    # (the fleet's own MJX forces are checked in test_sim_forces.py).
    robot, gait = _robot_gait(name)
    run = _walk_c(name, "calm", (0.4, 0.0, 0.0), 4.0, iterations=30)
    params = GaitParams.calm(gait)
    per_cycle = int(round(1.0 / (float(params.step_freq) * run["dt"])))
    cycles = 4
    fz = run["fz"][-cycles * per_cycle :]
    np.testing.assert_allclose(fz.mean(), robot.mass * 9.81, rtol=0.05)


def test_params_vmap_and_bad_input_is_contained():
    robot, gait = _robot_gait("badger")
    params = jax.tree.map(lambda a, b: jnp.stack([a, b]), GaitParams.calm(gait), GaitParams.aggressive(gait))
    states = jax.vmap(gait_init, in_axes=(None, 0))(gait, params)
    qpos = jnp.stack([jnp.asarray(robot.qpos_home, jnp.float32)] * 2)
    qpos = qpos.at[1, 9].set(jnp.nan)  # robot 1 gets a NaN joint angle
    qvel = jnp.zeros((2, robot.nv))
    cmd = jnp.array([[0.4, 0.0, 0.1], [1.0, 0.0, 0.0]])
    batched = jax.jit(jax.vmap(gait_step, in_axes=(None, 0, 0, 0, 0, 0, None, None)))
    new, tau = batched(gait, params, states, qpos, qvel, cmd, jnp.float32(0.1), jnp.float32(0.004))
    p0 = jax.tree.map(lambda x: x[0], params)
    _, tau0 = _step(gait, p0, gait_init(gait, p0), qpos[0], qvel[0], cmd[0], jnp.float32(0.1), jnp.float32(0.004))
    # Torques are PD gains times joint targets from float32 inverse kinematics: the batched and the single
    # program round differently by ~1e-6 rad, up to ~1e-4 N m of torque (the flag, below, is exact).
    np.testing.assert_allclose(tau[0], tau0, rtol=1e-5, atol=1e-3)
    assert np.all(np.isfinite(np.asarray(tau[0]))) and np.any(np.asarray(tau[0]) != 0.0)
    assert not bool(new.ok[1]) and bool(new.ok[0])
    np.testing.assert_array_equal(np.asarray(tau[1]), 0.0)
    # The flag latches: a finite input afterwards still gives zero torque.
    again, tau1 = _step(
        gait, p0, jax.tree.map(lambda x: x[1], new), qpos[0], qvel[0], cmd[0], jnp.float32(0.2), jnp.float32(0.004)
    )
    assert not bool(again.ok)
    np.testing.assert_array_equal(np.asarray(tau1), 0.0)


@pytest.mark.slow
def test_mjx_batched_rollout_walks():
    """The fleet's path: gait_step + mjx.step in a jitted lax.scan, vmapped over robot parameters."""
    robot, gait = _robot_gait("badger")
    params = jax.tree.map(lambda a, b: jnp.stack([a, b]), GaitParams.calm(gait), GaitParams.aggressive(gait))
    cmd = jnp.array([[0.5, 0.0, 0.0], [1.0, 0.0, 0.0]])
    model = robot.mjx_model
    dt = float(robot.mj_model.opt.timestep)
    steps = int(2.5 / dt)
    qpos0 = jnp.asarray(robot.qpos_home, jnp.float32).at[2].set(float(gait.body_height) + 0.005)

    def rollout(p, c):
        def body(carry, i):
            d, s = carry
            s, u = gait_step(gait, p, s, d.qpos, d.qvel, c, i.astype(jnp.float32) * dt, jnp.float32(dt))
            d = mjx.step(model, d.replace(ctrl=u))
            return (d, s), (d.qpos, u)

        d0 = mjx.make_data(model).replace(qpos=qpos0)
        (_, s), out = jax.lax.scan(body, (d0, gait_init(gait, p)), jnp.arange(steps))
        return out, s.ok

    (qpos, tau), ok = jax.jit(jax.vmap(rollout))(params, cmd)
    qpos, tau = np.asarray(qpos), np.asarray(tau)
    assert np.all(np.asarray(ok))
    assert np.all(np.abs(tau) <= robot.torque_limit + 1e-4)
    for k in range(2):
        assert qpos[k, :, 2].min() > 0.75 * float(gait.body_height)
        roll, pitch = _roll_pitch(qpos[k, :, 3:7])
        assert np.abs(roll).max() < 35.0 and np.abs(pitch).max() < 35.0
        assert qpos[k, -1, 0] > 0.6  # accelerating from rest at 0.5 m/s^2 (calm) or 3 m/s^2


def test_from_model_rejects_bad_structure():
    robot, _ = _robot_gait("go2")
    legs = (("FL_hip_joint", "FL_thigh_joint", "FL_calf_joint"),) * 3 + (("RR_hip_joint", "RR_thigh", "x"),)
    with pytest.raises(ValueError, match="no joint named 'RR_thigh'"):
        Gait.from_model(robot.mj_model, legs, robot.foot_names)
    with pytest.raises(ValueError, match="expected 4 legs"):
        Gait.from_model(robot.mj_model, legs[:2], robot.foot_names)
