"""jaxquad.dynamics against MuJoCo C, pytorch-kinematics FK and finite differences.

Comparisons with MuJoCo C run in double precision: the fixture builds a float64 mjx.Model and
evaluates every function inside `jax.enable_x64(True)` (local to this module's calls), so the
tolerances are tight (1e-9). A float32 run of the default model is checked at 1e-4 relative.
"""

import dataclasses

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
import pytest
import pytorch_kinematics as pk
import pytorch_kinematics.mjcf as pk_mjcf
import torch
from mujoco import mjx

from jaxquad import dynamics as dyn
from jaxquad.robots import load

N_STATES = 3
FD_STEP = 1e-6


def _random_states(robot, n, seed):
    """Configurations around the stand (random attitude, joints +-0.4 rad), random velocities."""
    rng = np.random.default_rng(seed)
    qpos = np.tile(robot.qpos_home, (n, 1))
    quat = rng.normal(size=(n, 4))
    qpos[:, 3:7] = quat / np.linalg.norm(quat, axis=1, keepdims=True)
    qpos[:, robot.qpos_adr] += rng.uniform(-0.4, 0.4, size=(n, robot.nu))
    qvel = rng.normal(size=(n, robot.nv))
    tau = rng.uniform(-0.9, 0.9, size=(n, robot.nu)) * robot.torque_limit
    return qpos, qvel, tau


def _all_terms(robot, m, qpos, qvel, tau):
    p, tau_bar, j_z = dyn.momentum_terms(robot, qpos, qvel, tau, m)
    return dict(
        M=dyn.mass_matrix(m, qpos),
        h=dyn.bias_forces(m, qpos, qvel),
        g=dyn.gravity_forces(m, qpos),
        ctv=dyn.coriolis_transpose_v(m, qpos, qvel),
        q_step=dyn.integrate_pos(m, qpos, qvel, FD_STEP),
        p_world=dyn.p_world_foot(robot, qpos, m),
        p_base=dyn.p_base_foot(robot, qpos, m),
        J_world=dyn.foot_jacobians_world(robot, qpos, m),
        J_base=dyn.foot_jacobians_base(robot, qpos, m),
        v_base=dyn.v_base_foot(robot, qpos, qvel, m),
        p=p,
        tau_bar=tau_bar,
        J_z=j_z,
    )


@pytest.fixture(scope="module", params=["go2", "badger"])
def case(request):
    """Float64 model, random states, and every dynamics output at those states (one compile)."""
    robot = load(request.param)
    with jax.enable_x64(True):
        m64 = mjx.put_model(robot.mj_model)
        robot64 = dataclasses.replace(robot, mjx_model=m64)
        qpos, qvel, tau = _random_states(robot, N_STATES, seed=len(request.param))
        fn = jax.jit(jax.vmap(lambda q, v, t: _all_terms(robot64, m64, q, v, t)))
        out = jax.tree_util.tree_map(np.asarray, fn(qpos, qvel, tau))
    return robot, qpos, qvel, tau, out


def _c_state(robot, qpos, qvel=None, ctrl=None):
    m = robot.mj_model
    d = mujoco.MjData(m)
    d.qpos[:] = qpos
    if qvel is not None:
        d.qvel[:] = qvel
    if ctrl is not None:
        d.ctrl[:] = ctrl
    mujoco.mj_forward(m, d)
    return d


def _c_full_m(robot, qpos):
    m = robot.mj_model
    d = _c_state(robot, qpos)
    M = np.zeros((m.nv, m.nv))
    mujoco.mj_fullM(m, d, M)
    return M


def _c_p_base(robot, qpos):
    d = _c_state(robot, qpos)
    b = robot.base_body_id
    return (d.site_xpos[robot.foot_site_ids] - d.xpos[b]) @ d.xmat[b].reshape(3, 3)


def _c_mdot_v(robot, qpos, qvel):
    """Central difference of M along the path q(t) = mj_integratePos(q, v, t), times v."""
    m = robot.mj_model
    qp, qm = qpos.copy(), qpos.copy()
    mujoco.mj_integratePos(m, qp, qvel, FD_STEP)
    mujoco.mj_integratePos(m, qm, qvel, -FD_STEP)
    return (_c_full_m(robot, qp) - _c_full_m(robot, qm)) @ qvel / (2 * FD_STEP)


def test_mass_matrix_and_bias_match_mujoco(case):
    robot, qpos, qvel, _, out = case
    for i in range(N_STATES):
        d = _c_state(robot, qpos[i], qvel[i])
        np.testing.assert_allclose(out["M"][i], _c_full_m(robot, qpos[i]), atol=1e-9)
        np.testing.assert_allclose(out["h"][i], d.qfrc_bias, atol=1e-9)
        np.testing.assert_allclose(out["g"][i], _c_state(robot, qpos[i]).qfrc_bias, atol=1e-9)


def test_foot_positions_and_jacobians_match_mujoco(case):
    robot, qpos, _, _, out = case
    m = robot.mj_model
    for i in range(N_STATES):
        d = _c_state(robot, qpos[i])
        np.testing.assert_allclose(out["p_world"][i], d.site_xpos[robot.foot_site_ids], atol=1e-9)
        np.testing.assert_allclose(out["p_base"][i], _c_p_base(robot, qpos[i]), atol=1e-9)
        jac = np.zeros((4, 3, m.nv))
        for f, s in enumerate(robot.foot_site_ids):
            mujoco.mj_jacSite(m, d, jac[f], None, s)
        np.testing.assert_allclose(out["J_world"][i], jac, atol=1e-9)
        np.testing.assert_allclose(out["J_z"][i], jac[:, 2, :], atol=1e-9)


def test_base_frame_jacobian_and_velocity_by_finite_differences(case):
    """d p_base_foot / d q_joint column by column, and J qdot, from MuJoCo C positions."""
    robot, qpos, qvel, _, out = case
    for i in range(N_STATES):
        cols = []
        for k in range(robot.nu):
            qp, qm = qpos[i].copy(), qpos[i].copy()
            qp[robot.qpos_adr[k]] += FD_STEP
            qm[robot.qpos_adr[k]] -= FD_STEP
            cols.append((_c_p_base(robot, qp) - _c_p_base(robot, qm)) / (2 * FD_STEP))
        jac_fd = np.stack(cols, axis=-1)
        np.testing.assert_allclose(out["J_base"][i], jac_fd, atol=1e-8)
        np.testing.assert_allclose(out["v_base"][i], jac_fd @ qvel[i, robot.dof_adr], atol=1e-7)
    if robot.spine_joint is not None:
        # Rear feet move with the spine in the base frame, front feet do not.
        spine = robot.joint_names.index(robot.spine_joint)
        assert np.all(np.abs(out["J_base"][:, 2:, :, spine]).max(axis=-1) > 1e-2)
        np.testing.assert_allclose(out["J_base"][:, :2, :, spine], 0.0, atol=1e-12)


def test_foot_positions_match_pytorch_kinematics(case):
    robot, qpos, _, _, out = case
    # pytorch-kinematics keys its joint-type table by MuJoCo enum members, which no longer compare
    # equal to the model's integer joint types in this MuJoCo version; key it by the integer values.
    table = {int(k): v for k, v in pk_mjcf.JOINT_TYPE_MAP.items()}
    pk_mjcf.JOINT_TYPE_MAP.clear()
    pk_mjcf.JOINT_TYPE_MAP.update(table)
    base = robot.mj_model.body(robot.base_body_id).name
    chain = pk.build_chain_from_mjcf(open(robot.path).read(), body=base).to(dtype=torch.float64)
    names = chain.get_joint_parameter_names()
    assert sorted(names) == sorted(robot.joint_names)
    for i in range(N_STATES):
        angles = {n: float(qpos[i, robot.qpos_adr[robot.joint_names.index(n)]]) for n in names}
        fk = chain.forward_kinematics(angles)
        T_base = fk[base].get_matrix()[0]
        p = [(torch.linalg.inv(T_base) @ fk[f].get_matrix()[0])[:3, 3].numpy() for f in robot.foot_names]
        np.testing.assert_allclose(out["p_base"][i], np.stack(p), atol=1e-6)


def test_integrate_pos_matches_mujoco(case):
    robot, qpos, qvel, _, out = case
    for i in range(N_STATES):
        q = qpos[i].copy()
        mujoco.mj_integratePos(robot.mj_model, q, qvel[i], FD_STEP)
        np.testing.assert_allclose(out["q_step"][i], q, atol=1e-12)


def test_coriolis_transpose_by_finite_differences(case):
    """C^T v = Mdot v - C v with Mdot from finite differences of M along the MuJoCo path, and C v
    from MuJoCo's bias minus gravity: equivalently Mdot v = C v + C^T v."""
    robot, qpos, qvel, _, out = case
    for i in range(N_STATES):
        mdot_v = _c_mdot_v(robot, qpos[i], qvel[i])
        c_v = _c_state(robot, qpos[i], qvel[i]).qfrc_bias - _c_state(robot, qpos[i]).qfrc_bias
        np.testing.assert_allclose(out["ctv"][i], mdot_v - c_v, atol=1e-6)
        np.testing.assert_allclose(mdot_v, c_v + out["ctv"][i], atol=1e-6)
        assert np.abs(out["ctv"][i]).max() > 1e-2  # the check is not vacuous


def test_momentum_terms_match_mujoco(case):
    """p = M v, tau_bar = S^T tau + Mdot v - h (= S^T tau + C^T v - g), all from MuJoCo C."""
    robot, qpos, qvel, tau, out = case
    for i in range(N_STATES):
        d = _c_state(robot, qpos[i], qvel[i], ctrl=tau[i])
        np.testing.assert_allclose(out["p"][i], _c_full_m(robot, qpos[i]) @ qvel[i], atol=1e-9)
        expected = d.qfrc_actuator + _c_mdot_v(robot, qpos[i], qvel[i]) - d.qfrc_bias
        np.testing.assert_allclose(out["tau_bar"][i], expected, atol=1e-6)


def test_float32_jit_compiles_once_per_model():
    """Default float32 model: one trace for new states and for a traced mass sweep; values agree
    with MuJoCo C to float32 precision."""
    robot = load("badger")
    traces = []

    @jax.jit
    def terms(m, qpos, qvel, tau):
        traces.append(1)
        return dyn.momentum_terms(robot, qpos, qvel, tau, m)

    qpos, qvel, tau = _random_states(robot, 2, seed=3)
    m = robot.mjx_model
    p0, _, _ = terms(m, jnp.asarray(qpos[0], jnp.float32), jnp.asarray(qvel[0], jnp.float32), jnp.asarray(tau[0], jnp.float32))
    p1, tb1, _ = terms(m, jnp.asarray(qpos[1], jnp.float32), jnp.asarray(qvel[1], jnp.float32), jnp.asarray(tau[1], jnp.float32))
    heavier = m.replace(body_mass=m.body_mass * 1.2)
    p1_heavy, _, _ = terms(heavier, jnp.asarray(qpos[1], jnp.float32), jnp.asarray(qvel[1], jnp.float32), jnp.asarray(tau[1], jnp.float32))
    assert len(traces) == 1
    assert p0.dtype == jnp.float32
    M1 = _c_full_m(robot, qpos[1])
    np.testing.assert_allclose(p1, M1 @ qvel[1], rtol=1e-4, atol=1e-4 * np.abs(M1 @ qvel[1]).max())
    d = _c_state(robot, qpos[1], qvel[1], ctrl=tau[1])
    expected = d.qfrc_actuator + _c_mdot_v(robot, qpos[1], qvel[1]) - d.qfrc_bias
    np.testing.assert_allclose(tb1, expected, atol=1e-4 * np.abs(expected).max())
    # Linear momentum scales with the trunk/leg masses (not exactly 1.2x: armature does not scale).
    assert np.abs(p1_heavy[:3]).sum() > np.abs(p1[:3]).sum()


def test_grad_of_foot_position_and_zero_velocity():
    """grad through the kinematics matches finite differences; C^T v and its gradient are finite
    (and C^T v is zero) at zero velocity, where the exponential map is singular."""
    robot = load("go2")
    with jax.enable_x64(True):
        m = mjx.put_model(robot.mj_model)
        r64 = dataclasses.replace(robot, mjx_model=m)
        qpos, _, _ = _random_states(robot, 1, seed=7)
        q = jnp.asarray(qpos[0])
        height = lambda q: dyn.p_base_foot(r64, q, m)[0, 2] + dyn.p_world_foot(r64, q, m)[3, 0]
        grad = np.asarray(jax.jit(jax.grad(height))(q))
        zero = jnp.zeros(robot.nv)
        ctv_norm = lambda v: jnp.sum(dyn.coriolis_transpose_v(m, q, v) ** 2)
        ctv0, ctv_grad0 = jax.jit(jax.value_and_grad(ctv_norm))(zero)
        direction = np.random.default_rng(0).normal(size=robot.nq)
        direction[3:7] = 0.0  # keep the quaternion on its manifold
        both = jax.jit(jax.vmap(height))(jnp.stack([q + FD_STEP * direction, q - FD_STEP * direction]))
    fd = float(both[0] - both[1]) / (2 * FD_STEP)
    assert grad @ direction == pytest.approx(fd, abs=1e-7)
    assert float(ctv0) == 0.0
    assert np.all(np.isfinite(ctv_grad0)) and np.all(np.asarray(ctv_grad0) == 0.0)
