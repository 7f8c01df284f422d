"""The contact observer's generalized coordinates (`estimate.inputs.observer_rows`) on a spined robot.

References independent of the code under test: joint names and degrees of freedom from MuJoCo C,
the mass matrix and foot Jacobians from MuJoCo C (`mj_fullM`, `mj_jacSite`), and NumPy's least
squares. The observer's steady state under a constant momentum-rate disturbance d is the least-squares
force f = argmin |J^T f - d| (its residual settles orthogonal to J's rows), so a base-velocity error
that grows at a rate a (what leg odometry feeds the observer) reads as the forces lstsq(J^T, M_rb a).
Negative control: on the Badger the old rows (every actuated joint, the spine's included) read a
vertical velocity-rate error as five times the rear-foot force that the legs' rows read.
"""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
import pytest

from jaxquad import dynamics
from jaxquad.estimate import PipelineConfig
from jaxquad.estimate.inputs import observer_rows
from jaxquad.kernels import ContactObserver, ObserverParams
from jaxquad.robots import load

_OBS = ContactObserver()


def _mujoco_terms(robot):
    """Mass matrix (nv, nv) and world foot Jacobians (4, 3, nv) at the home pose, from MuJoCo C."""
    m = robot.mj_model
    d = mujoco.MjData(m)
    d.qpos[:] = robot.qpos_home
    mujoco.mj_forward(m, d)
    M = np.zeros((m.nv, m.nv))
    mujoco.mj_fullM(m, d, M)
    J = np.zeros((4, 3, m.nv))
    for f, site in enumerate(robot.foot_site_ids):
        mujoco.mj_jacSite(m, d, J[f], None, int(site))
    return M, J


@pytest.mark.parametrize("name", ["go2", "badger"])
def test_rows_against_mujoco_joint_names(name):
    robot = load(name)
    m = robot.mj_model
    hinge = [j for j in range(m.njnt) if m.jnt_type[j] == mujoco.mjtJoint.mjJNT_HINGE]
    leg_dofs = sorted(int(m.jnt_dofadr[j]) for j in hinge if "spine" not in m.joint(j).name)
    all_dofs = sorted(int(m.jnt_dofadr[j]) for j in hinge)
    np.testing.assert_array_equal(observer_rows(robot, "legs"), leg_dofs)
    np.testing.assert_array_equal(np.sort(observer_rows(robot, "joints")), all_dofs)
    np.testing.assert_array_equal(observer_rows(robot, "full"), np.arange(m.nv))
    assert len(leg_dofs) == 12 and len(all_dofs) == (13 if name == "badger" else 12)
    assert PipelineConfig().observer_rows == "legs"
    with pytest.raises(ValueError, match="observer rows"):
        observer_rows(robot, "spine")
    with pytest.raises(ValueError, match="observer_rows"):
        PipelineConfig(observer_rows="spine")


@jax.jit
def _steady_force(params, p_rate, J_rows, dt):
    """Observer over 300 samples of momentum p_k = p_rate t_k with tau_bar = 0 (no contact: the true
    force is zero); its final force estimate."""
    n_force = J_rows.shape[0]
    state = _OBS.init(params, jnp.zeros_like(p_rate), n_force)

    def body(state, k):
        p = p_rate * (k.astype(p_rate.dtype) * dt)
        return _OBS.step(params, state, p, jnp.zeros_like(p_rate), J_rows, dt)[0], None

    state, _ = jax.lax.scan(body, state, jnp.arange(1, 301))
    return state.f_hat


def _plain(n_force: int) -> ObserverParams:
    p = ObserverParams.paper(n_force, "plain", bandwidth=150.0)
    return dataclasses.replace(p, pinv_damping=jnp.float32(1e-7))


def test_spine_row_reads_base_velocity_errors_as_rear_foot_force():
    """A vertical base-velocity error growing at 10 m/s^2 (0.04 m/s per 4 ms sample, the size of leg
    odometry's sample-to-sample errors): the observer on the library's momentum terms settles at
    NumPy's least-squares forces on MuJoCo C's matrices, for both row sets; the spine's row makes it
    read over 5 N on each rear foot (0.2 of the weight a rear foot carries), the legs' rows under 2.5 N."""
    robot = load("badger")
    M, J = _mujoco_terms(robot)
    a = np.zeros(robot.nv)
    a[robot.base_dof_adr + 2] = 10.0  # m/s^2, world z
    qpos = jnp.asarray(robot.qpos_home, jnp.float32)
    zero = jnp.zeros(robot.nu, jnp.float32)
    # p = M v is linear in v: the library's momentum at the unit-time velocity a is the momentum rate.
    p_rate, _, J_lib = dynamics.momentum_terms(robot, qpos, jnp.asarray(a, jnp.float32), zero, axes="xyz")
    rear_z = {}
    for rows in ("joints", "legs"):
        idx = observer_rows(robot, rows)
        ref = np.linalg.lstsq(J.reshape(12, -1)[:, idx].T, (M @ a)[idx], rcond=None)[0]
        f = np.asarray(_steady_force(_plain(12), p_rate[idx], J_lib[:, idx], jnp.float32(0.004)))
        np.testing.assert_allclose(f, ref, atol=0.05 * np.abs(ref).max())
        rear_z[rows] = np.abs(f[2::3][2:])  # RL, RR
    assert np.all(rear_z["joints"] > 5.0), rear_z  # negative control: the old rows
    assert np.all(rear_z["legs"] < 2.5), rear_z
    assert np.all(rear_z["joints"] > 4.0 * rear_z["legs"]), rear_z


def test_legs_rows_are_the_joint_rows_without_a_spine():
    """On the Go2 (no spine) the legs' rows are every actuated joint's: its estimates do not change."""
    robot = load("go2")
    np.testing.assert_array_equal(observer_rows(robot, "legs"), observer_rows(robot, "joints"))
