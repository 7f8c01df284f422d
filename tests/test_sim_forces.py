"""Ground-truth foot forces and contact flags of the MJX fleet runner against physics.

One short go2 trot through the fleet's own jitted chunks (the configuration of test_fleet.py, so a
joint run compiles the chunk once). References independent of the solver: Newton's second law (the
floor carries the weight on average over whole gait cycles) and MuJoCo C with a converged solver on
the fleet's own states.
"""

import copy

import jax
import mujoco
import numpy as np
import pytest

from jaxquad.sim.fleet import GT_CONTACT_MIN_FORCE, FleetConfig, build_fleet, init, run_chunk

_CFG = FleetConfig(robot="go2", n_robots=2, n_worlds=2, frames_per_chunk=16, seed=1, width=32, height=24)
_CHUNKS = 4  # 4 x 0.512 s


@pytest.fixture(scope="module")
def run():
    fleet = build_fleet(_CFG)
    state = init(fleet)
    outs, ends = [], []
    for _ in range(_CHUNKS):
        state, out = run_chunk(fleet, state)
        outs.append({k: np.swapaxes(v, 0, 1) for k, v in jax.device_get(out).items()})  # time-major chunks
        # The chunk's last sample was logged from this state (copied before it is donated).
        d = state.data
        ends.append(jax.device_get(dict(qpos=d.qpos, qvel=d.qvel, qacc=d.qacc, ctrl=d.ctrl)))
    log = {k: np.concatenate([o[k] for o in outs], axis=1) for k in ("gt_force", "gt_contact", "valid")}
    return fleet, log, ends


def _weight(fleet, i):
    m = fleet.robot.mj_model
    return float(np.asarray(fleet.model.body_mass)[i].sum()) * -float(m.opt.gravity[2])


@pytest.mark.slow
def test_gt_force_carries_the_weight_without_spikes(run):
    fleet, log, _ = run
    assert log["valid"].all()
    params = fleet.setup.gait_params
    for i in range(_CFG.n_robots):
        mg = _weight(fleet, i)
        per = int(round(1.0 / (float(params.step_freq[i]) * fleet.log_dt)))  # samples per gait cycle
        fz = log["gt_force"][i, :, :, 2]
        cycles = len(fz) // per - 1  # whole cycles after the first (the drop onto the floor)
        assert cycles >= 3
        # Vertical momentum does not grow over whole cycles: the floor's mean push is m g.
        np.testing.assert_allclose(fz[-cycles * per :].sum(1).mean(), mg, rtol=0.05)
        # A trot stands on two feet (m g / 2 each); allowing the base's vertical acceleration to
        # double that gives m g. A touchdown at ~0.5 m/s stopping ~1 kg of leg within one 4 ms step
        # adds ~125 N at most, so no single sample reaches 2 m g (the unconverged solver gave kN).
        assert np.percentile(fz, 99) < mg
        assert fz.max() < 2 * mg


@pytest.mark.slow
def test_gt_contact_is_load_bearing_and_steady(run):
    fleet, log, _ = run
    f, contact = log["gt_force"], log["gt_contact"]
    np.testing.assert_array_equal(contact, f[..., 2] > GT_CONTACT_MIN_FORCE)  # flat floor: normal = z
    assert np.all(f[..., 2] >= -1e-3)  # the floor only pushes
    # Stance and swing of the calm 2.5 Hz trot last ~0.2 s each; a run of fewer than 10 samples
    # (40 ms) inside the walk is touchdown bouncing, which the unconverged solver showed.
    for i in range(_CFG.n_robots):
        per = int(round(1.0 / (float(fleet.setup.gait_params.step_freq[i]) * fleet.log_dt)))
        for foot in range(4):
            c = contact[i, per:, foot].astype(int)
            edges = np.flatnonzero(np.diff(c)) + 1
            assert len(edges) >= 2 * (len(c) // per) - 2, "the foot stopped stepping"
            assert np.diff(edges).min() >= 10, f"robot {i} foot {foot} flickers: {np.diff(edges)}"


@pytest.mark.slow
def test_gt_force_matches_converged_mujoco_c(run):
    """Each chunk's last logged force against MuJoCo C (converged) on the state it came from."""
    fleet, log, ends = run
    robot = fleet.robot
    m = copy.deepcopy(robot.mj_model)
    m.opt.iterations, m.opt.ls_iterations, m.opt.tolerance = 200, 50, 1e-12
    dt = float(m.opt.timestep)
    data = mujoco.MjData(m)
    f6 = np.zeros(6)
    checked = 0
    for i in range(_CFG.n_robots):
        for key in ("body_mass", "body_inertia", "geom_friction", "actuator_gear"):
            getattr(m, key)[:] = np.asarray(getattr(fleet.model, key))[i]
        for c, end in enumerate(ends):
            # Undo the explicit Euler step (eulerdamp off): v = v' - dt a, q = q' (-) dt v'.
            data.qvel[:] = end["qvel"][i] - dt * end["qacc"][i]
            data.qpos[:] = end["qpos"][i]
            mujoco.mj_integratePos(m, data.qpos, end["qvel"][i].astype(np.float64), -dt)
            data.ctrl[:] = end["ctrl"][i]
            mujoco.mj_forward(m, data)
            f_c = np.zeros((4, 3))
            for k in range(data.ncon):
                con = data.contact[k]
                mujoco.mj_contactForce(m, data, k, f6)
                f_world = f6[:3] @ con.frame.reshape(3, 3)
                f_c[robot.foot_geom_ids == con.geom2] += f_world
                f_c[robot.foot_geom_ids == con.geom1] -= f_world
            logged = log["gt_force"][i, (c + 1) * fleet.samples_per_chunk - 1]
            np.testing.assert_allclose(logged, f_c, atol=2.0, rtol=0.02)
            checked += int((f_c[:, 2] > 10).sum())
    assert checked >= 2 * len(ends)  # stance feet were compared, not only feet in the air
