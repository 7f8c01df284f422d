"""jaxquad.dynamics against MuJoCo C, pytorch-kinematics FK and finite differences.

The badger (spine included) is checked in double precision: its fixture builds a float64 mjx.Model
and evaluates every function inside `jax.enable_x64(True)` (local to that fixture), so tolerances
are tight (1e-9; 1e-6 where MuJoCo's side is a finite difference). The go2 is checked with the
default float32 model as the simulator uses it, at float32 tolerances. Each fixture compiles one
vmapped function once, which keeps the module's compile time small.
"""

import copy
from pathlib import Path

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
    _, tau_bar_rigid, j_xyz = dyn.momentum_terms(robot, qpos, qvel, tau, m, passive=False, axes="xyz")
    legs = dyn.leg_kinematics(robot, qpos, qvel, m)
    return dict(
        M=dyn.mass_matrix(m, qpos),
        h=dyn.bias_forces(m, qpos, qvel),
        g=dyn.gravity_forces(m, qpos),
        ctv=dyn.coriolis_transpose_v(m, qpos, qvel),
        q_step=dyn.integrate_pos(m, qpos, qvel, FD_STEP),
        p_world=legs.p_world_foot,
        p_base=legs.p_base_foot,
        J_world=legs.J_world_foot,
        J_base=legs.J_base_foot,
        v_base=legs.v_base_foot,
        p=p,
        tau_bar=tau_bar,
        tau_bar_rigid=tau_bar_rigid,
        J_xyz=j_xyz,
        J_z=j_z,
        passive=dyn.passive_forces(m, qpos, qvel),
        passive_slow=dyn.passive_forces(m, qpos, qvel, friction_velocity=2.0),
    )


@pytest.fixture(scope="module")
def case():
    """Badger, float64 model, random states plus one at zero velocity; every output (one compile)."""
    robot = load("badger")
    with jax.enable_x64(True):
        m64 = mjx.put_model(robot.mj_model)
        qpos, qvel, tau = _random_states(robot, N_STATES, seed=1)
        qvel[-1] = 0.0
        fn = jax.jit(jax.vmap(lambda q, v, t: _all_terms(robot, m64, q, v, t)))
        out = jax.tree_util.tree_map(np.asarray, fn(qpos, qvel, tau))
    return robot, qpos, qvel, tau, out


@pytest.fixture(scope="module")
def go2_case():
    """Go2, default float32 model, one jitted function counted at trace time."""
    robot = load("go2")
    traces = []

    def terms(m, qpos, qvel, tau):
        traces.append(1)
        height = lambda q: dyn.p_base_foot(robot, q, m)[0, 2] + dyn.leg_kinematics(robot, q, qvel, m).p_world_foot[3, 0]
        return dict(
            momentum=dyn.momentum_terms(robot, qpos, qvel, tau, m),
            legs=dyn.leg_kinematics(robot, qpos, qvel, m),
            v_base=dyn.v_base_foot(robot, qpos, qvel, m),
            J_base=dyn.foot_jacobians_base(robot, qpos, m),
            J_world=dyn.foot_jacobians_world(robot, qpos, m),
            grad=jax.grad(height)(qpos),
        )

    fn = jax.jit(jax.vmap(terms, in_axes=(None, 0, 0, 0)))
    qpos, qvel, tau = _random_states(robot, N_STATES, seed=2)
    f32 = lambda x: jnp.asarray(x, jnp.float32)
    out = jax.tree_util.tree_map(np.asarray, fn(robot.mjx_model, f32(qpos), f32(qvel), f32(tau)))
    return robot, qpos, qvel, tau, out, fn, traces


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
        np.testing.assert_allclose(out["J_xyz"][i], jac.reshape(12, m.nv), atol=1e-9)


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
    assert np.abs(out["ctv"][0]).max() > 1e-2  # the check is not vacuous


def _friction_model(robot, qvel, friction_velocity=0.5):
    """-frictionloss tanh(qvel / friction_velocity), the documented smooth friction-loss model."""
    return -robot.mj_model.dof_frictionloss * np.tanh(qvel / friction_velocity)


def test_momentum_terms_match_mujoco(case):
    """p = M v, tau_bar = S^T tau + Mdot v - h (= S^T tau + C^T v - g) plus MuJoCo's qfrc_passive and
    the friction model (default), or the rigid-body part alone (passive=False), all from MuJoCo C."""
    robot, qpos, qvel, tau, out = case
    for i in range(N_STATES):
        d = _c_state(robot, qpos[i], qvel[i], ctrl=tau[i])
        np.testing.assert_allclose(out["p"][i], _c_full_m(robot, qpos[i]) @ qvel[i], atol=1e-9)
        rigid = d.qfrc_actuator + _c_mdot_v(robot, qpos[i], qvel[i]) - d.qfrc_bias
        np.testing.assert_allclose(out["tau_bar_rigid"][i], rigid, atol=1e-6)
        passive = d.qfrc_passive + _friction_model(robot, qvel[i])
        np.testing.assert_allclose(out["passive"][i], passive, atol=1e-9)
        np.testing.assert_allclose(out["tau_bar"][i], rigid + passive, atol=1e-6)
        np.testing.assert_allclose(
            out["passive_slow"][i], d.qfrc_passive + _friction_model(robot, qvel[i], 2.0), atol=1e-9
        )
    assert np.abs(out["passive"][:-1, robot.dof_adr]).max() > 0.1  # damping and friction present


def test_passive_forces_match_mujoco_damping_and_steady_friction():
    """Damping against MuJoCo C's qfrc_passive, and the friction model against the converged friction-
    loss constraint forces (efc rows, which saturate at -frictionloss sign(qdot)) with every joint moving
    at 2-4 rad/s, where tanh(qdot / 0.5) is within 1e-3 of the sign."""
    robot = load("go2")
    m = copy.copy(robot.mj_model)
    m.opt.iterations, m.opt.ls_iterations = 100, 50
    m.opt.disableflags |= mujoco.mjtDisableBit.mjDSBL_CONTACT
    rng = np.random.default_rng(5)
    qpos, qvel, _ = _random_states(robot, N_STATES, seed=5)
    qvel[:, robot.dof_adr] = rng.choice([-1.0, 1.0], (N_STATES, robot.nu)) * rng.uniform(2.0, 4.0, (N_STATES, robot.nu))
    fn = jax.jit(jax.vmap(lambda q, v: dyn.passive_forces(robot.mjx_model, q, v)))
    ours = np.asarray(fn(jnp.asarray(qpos, jnp.float32), jnp.asarray(qvel, jnp.float32)))
    for i in range(N_STATES):
        d = mujoco.MjData(m)
        d.qpos[:], d.qvel[:] = qpos[i], qvel[i]
        mujoco.mj_forward(m, d)
        rows = d.efc_type == mujoco.mjtConstraint.mjCNSTR_FRICTION_DOF
        friction = np.zeros(m.nv)
        friction[d.efc_id[rows]] = d.efc_force[rows]
        assert rows.sum() == robot.nu and np.all(np.abs(friction[robot.dof_adr]) > 0.19)
        np.testing.assert_allclose(d.qfrc_passive, -m.dof_damping * qvel[i], atol=1e-12)
        np.testing.assert_allclose(ours[i], d.qfrc_passive + friction, atol=1e-3)


def test_passive_forces_gradient_and_zero_velocity():
    """At rest the force is zero and its velocity Jacobian is the closed form -diag(damping +
    frictionloss / friction_velocity) (finite, jit and jacfwd)."""
    robot = load("go2")
    m = robot.mjx_model
    q = jnp.asarray(robot.qpos_home, jnp.float32)
    zero = jnp.zeros(robot.nv, jnp.float32)
    jac = jax.jit(jax.jacfwd(lambda v: dyn.passive_forces(m, q, v, 0.25)))(zero)
    mc = robot.mj_model
    np.testing.assert_allclose(np.asarray(jac), -np.diag(mc.dof_damping + mc.dof_frictionloss / 0.25), rtol=1e-6)
    np.testing.assert_array_equal(np.asarray(dyn.passive_forces(m, q, zero)), 0.0)
    with pytest.raises(ValueError, match="axes"):
        dyn.momentum_terms(robot, q, zero, jnp.zeros(robot.nu), axes="x")


def test_zero_velocity_is_finite(case):
    """At zero velocity (singular exponential map on the path) C^T v is exactly zero, p is zero and
    tau_bar = S^T tau - g."""
    robot, qpos, qvel, tau, out = case
    assert np.all(np.isfinite(out["ctv"])) and np.all(np.isfinite(out["tau_bar"]))
    np.testing.assert_array_equal(out["ctv"][-1], 0.0)
    np.testing.assert_array_equal(out["p"][-1], 0.0)
    s_tau = np.zeros(robot.nv)
    s_tau[robot.dof_adr] = tau[-1]
    np.testing.assert_allclose(out["tau_bar"][-1], s_tau - out["g"][-1], atol=1e-12)
    np.testing.assert_allclose(out["tau_bar_rigid"][-1], s_tau - out["g"][-1], atol=1e-12)


def test_integrate_pos_gradient_at_zero_rate():
    """d q(t) / dt at t = 0 and zero angular rate: closed form 0.5 quat * (0, omega) = 0 for the quaternion."""
    robot = load("go2")
    m = robot.mjx_model
    q = jnp.asarray(robot.qpos_home, jnp.float32)
    v = jnp.zeros(robot.nv, jnp.float32).at[0].set(1.0).at[6].set(2.0)
    dq = jax.jit(jax.jacfwd(lambda t: dyn.integrate_pos(m, q, v, t)))(jnp.float32(0.0))
    expected = np.zeros(robot.nq)
    expected[0], expected[7] = 1.0, 2.0
    np.testing.assert_array_equal(np.asarray(dq), expected)
    grad_v = jax.jit(jax.grad(lambda w: dyn.integrate_pos(m, q, w, 0.1)[3:7] @ jnp.arange(4.0)))(v)
    assert np.all(np.isfinite(grad_v))
    # Quaternion part: d/domega of quat * exp(0.1 omega) at omega = 0 is 0.05 quat * (0, e_k).
    np.testing.assert_allclose(np.asarray(grad_v[3:6]), 0.05 * np.array([1.0, 2.0, 3.0]), atol=1e-6)


def test_go2_float32_matches_mujoco(go2_case):
    robot, qpos, qvel, tau, out, _, _ = go2_case
    m = robot.mj_model
    p, tau_bar, j_z = out["momentum"]
    for i in range(N_STATES):
        d = _c_state(robot, qpos[i], qvel[i], ctrl=tau[i])
        pv = _c_full_m(robot, qpos[i]) @ qvel[i]
        np.testing.assert_allclose(p[i], pv, atol=2e-5 * np.abs(pv).max())
        expected = d.qfrc_actuator + _c_mdot_v(robot, qpos[i], qvel[i]) - d.qfrc_bias
        expected += d.qfrc_passive + _friction_model(robot, qvel[i])
        np.testing.assert_allclose(tau_bar[i], expected, atol=2e-5 * np.abs(expected).max())
        jac = np.zeros((4, 3, m.nv))
        for f, s in enumerate(robot.foot_site_ids):
            mujoco.mj_jacSite(m, d, jac[f], None, s)
        np.testing.assert_allclose(j_z[i], jac[:, 2, :], atol=1e-5)
        np.testing.assert_allclose(out["J_world"][i], jac, atol=1e-5)
        np.testing.assert_allclose(out["legs"].J_world_foot[i], jac, atol=1e-5)
        np.testing.assert_allclose(out["legs"].p_base_foot[i], _c_p_base(robot, qpos[i]), atol=1e-6)
        np.testing.assert_allclose(out["legs"].p_world_foot[i], d.site_xpos[robot.foot_site_ids], atol=1e-5)
    np.testing.assert_allclose(out["v_base"], out["legs"].v_base_foot, rtol=1e-6, atol=1e-7)
    np.testing.assert_allclose(out["J_base"], out["legs"].J_base_foot, rtol=1e-6, atol=1e-7)


def test_go2_grad_matches_finite_differences(go2_case):
    """jax.grad through the kinematics against central differences of MuJoCo C positions."""
    robot, qpos, _, _, out, _, _ = go2_case

    def height(q):
        d = _c_state(robot, q)
        return _c_p_base(robot, q)[0, 2] + d.site_xpos[robot.foot_site_ids[3], 0]

    for i in range(N_STATES):
        for k in [0, 1, 2, int(robot.qpos_adr[1]), int(robot.qpos_adr[11])]:
            qp, qm = qpos[i].copy(), qpos[i].copy()
            qp[k] += FD_STEP
            qm[k] -= FD_STEP
            fd = (height(qp) - height(qm)) / (2 * FD_STEP)
            assert out["grad"][i, k] == pytest.approx(fd, abs=1e-5)


def test_go2_compiles_once_per_model(go2_case):
    """New states and a traced mass sweep of the same model reuse the compiled function."""
    robot, qpos, qvel, tau, out, fn, traces = go2_case
    m = robot.mjx_model
    f32 = lambda x: jnp.asarray(x, jnp.float32)
    fn(m, f32(qpos[::-1]), f32(qvel), f32(tau))
    heavier = m.replace(body_mass=m.body_mass * 1.2, body_inertia=m.body_inertia * 1.2)
    heavy = fn(heavier, f32(qpos), f32(qvel), f32(tau))
    assert len(traces) == 1
    # Momentum of the free joint's linear part scales with the (non-armature) masses.
    np.testing.assert_allclose(heavy["momentum"][0][:, :3], 1.2 * out["momentum"][0][:, :3], rtol=1e-5)


@pytest.mark.parametrize("name", ["go2", "badger"])
def test_foot_positions_match_pytorch_kinematics(name, case, go2_case):
    robot, qpos, _, _, out = case if name == "badger" else go2_case[:5]
    p_base = out["p_base"] if name == "badger" else out["legs"].p_base_foot
    # pytorch-kinematics keys its joint-type table by MuJoCo enum members, which no longer compare
    # equal to the model's integer joint types in this MuJoCo version; key it by the integer values.
    table = {int(k): v for k, v in pk_mjcf.JOINT_TYPE_MAP.items()}
    pk_mjcf.JOINT_TYPE_MAP.clear()
    pk_mjcf.JOINT_TYPE_MAP.update(table)
    base = robot.mj_model.body(robot.base_body_id).name
    chain = pk.build_chain_from_mjcf(Path(robot.path).read_text(), body=base).to(dtype=torch.float64)
    names = chain.get_joint_parameter_names()
    assert sorted(names) == sorted(robot.joint_names)
    for i in range(N_STATES):
        angles = {n: float(qpos[i, robot.qpos_adr[robot.joint_names.index(n)]]) for n in names}
        fk = chain.forward_kinematics(angles)
        T_base = fk[base].get_matrix()[0]
        p = [(torch.linalg.inv(T_base) @ fk[f].get_matrix()[0])[:3, 3].numpy() for f in robot.foot_names]
        np.testing.assert_allclose(p_base[i], np.stack(p), atol=1e-6)
