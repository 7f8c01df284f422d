"""Tuning of the contact observer: observer inputs against MuJoCo C, the vmapped grid against a
one-configuration-at-a-time loop, the gradient tuner against a bad start, params files through
`load_params`, and one-line errors. Ground truth: a floating Go2 model in MuJoCo C (no ground)
whose feet receive a known trot-like schedule of vertical forces, with noisy torque readings."""

from __future__ import annotations

import copy
import dataclasses
import json

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
import pytest

from jaxquad.estimate import tune as tn
from jaxquad.estimate.run import load_params
from jaxquad.kernels import ObserverParams
from jaxquad.robots import load

_SIM_DT, _EVERY, _SECONDS = 0.001, 4, 0.8  # physics step (s), physics steps per sample, duration
_PERIOD, _RAMP = 0.3, 0.03  # trot period and force ramp (s)
_TAU_NOISE = 0.5  # N m, on the logged torques


@pytest.fixture(scope="module")
def robot():
    return load("go2")


def _schedule(t: float, phase: float, weight: float) -> np.ndarray:
    """Vertical force on FL, FR, RL, RR (N): diagonal pairs alternate, ramps overlap so the sum
    stays at the weight."""
    s = ((t / _PERIOD + phase) % 1.0) * _PERIOD
    half = _PERIOD / 2
    up = np.clip(s / _RAMP, 0, 1) * np.clip((half + _RAMP - s) / _RAMP, 0, 1) if s < half + _RAMP else 0.0
    s2 = (s - half) % _PERIOD
    up2 = np.clip(s2 / _RAMP, 0, 1) * np.clip((half + _RAMP - s2) / _RAMP, 0, 1) if s2 < half + _RAMP else 0.0
    a, b = 0.5 * weight * up, 0.5 * weight * up2
    return np.array([a, b, b, a])


def _reference_terms(m, d_fd, qpos, qvel, tau_joints, dof_adr):
    """p = M v, tau_bar = S^T tau + Mdot v - (C v + g) + ... as in the observer's convention
    (C^T v = Mdot v - C v), J_z of the feet, from MuJoCo C with central differences for Mdot."""
    nv, eps = m.nv, 1e-6
    M, Mp, Mm = (np.zeros((nv, nv)) for _ in range(3))
    d_fd.qpos[:], d_fd.qvel[:] = qpos, qvel
    mujoco.mj_forward(m, d_fd)
    mujoco.mj_fullM(m, d_fd, M)
    bias = d_fd.qfrc_bias.copy()
    J = np.zeros((4, nv))
    jacp = np.zeros((3, nv))
    for i in range(4):
        mujoco.mj_jacSite(m, d_fd, jacp, None, m.site(["FL_foot", "FR_foot", "RL_foot", "RR_foot"][i]).id)
        J[i] = jacp[2]
    d_fd.qvel[:] = 0.0
    mujoco.mj_forward(m, d_fd)
    grav = d_fd.qfrc_bias.copy()
    for sign, out in ((1.0, Mp), (-1.0, Mm)):
        d_fd.qpos[:] = qpos
        mujoco.mj_integratePos(m, d_fd.qpos, qvel, sign * eps)
        mujoco.mj_fwdPosition(m, d_fd)
        mujoco.mj_fullM(m, d_fd, out)
    mdot_v = (Mp - Mm) @ qvel / (2 * eps)
    s_tau = np.zeros(nv)
    s_tau[dof_adr] = tau_joints
    return M @ qvel, s_tau + mdot_v - (bias - grav) - grav, J


def _simulate(robot, phase: float, seed: int):
    """One robot: its log (single-robot format) and exact observer inputs at every sample."""
    m = copy.copy(robot.mj_model)  # the loaded model is cached and shared with the simulator tests
    m.opt.disableflags |= mujoco.mjtDisableBit.mjDSBL_CONTACT
    m.opt.timestep = _SIM_DT
    d, d_fd = mujoco.MjData(m), mujoco.MjData(m)
    d.qpos[:] = robot.qpos_home
    rng = np.random.default_rng(seed)
    dof = np.asarray(robot.dof_adr)
    sites = list(robot.foot_site_ids)
    weight = -m.opt.gravity[2] * m.body_subtreemass[robot.base_body_id]
    rows = {
        k: []
        for k in (
            "t",
            "q",
            "qd",
            "tau",
            "gyro",
            "acc",
            "quat_wxyz",
            "gt_pose",
            "gt_contact",
            "gt_force",
            "p",
            "tau_bar",
            "J_z",
            "qvel",
        )
    }
    forces = np.zeros(4)
    for k in range(round(_SECONDS / _SIM_DT)):
        t = k * _SIM_DT
        mujoco.mj_forward(m, d)
        if k % _EVERY == 0:
            tau_meas = d.actuator_force + _TAU_NOISE * rng.standard_normal(robot.nu)
            p, tau_bar, J_z = _reference_terms(m, d_fd, d.qpos.copy(), d.qvel.copy(), tau_meas, dof)
            rows["t"].append(t)
            rows["q"].append(d.qpos[np.asarray(robot.qpos_adr)].copy())
            rows["qd"].append(d.qvel[dof].copy())
            rows["tau"].append(tau_meas)
            rows["gyro"].append(d.sensordata[0:3].copy())
            rows["acc"].append(d.sensordata[3:6].copy())
            rows["quat_wxyz"].append(d.qpos[3:7].copy())
            rows["gt_pose"].append(d.qpos[0:7].copy())
            rows["gt_contact"].append(forces > 0)
            rows["gt_force"].append(np.c_[np.zeros((4, 2)), forces])
            rows["p"].append(p), rows["tau_bar"].append(tau_bar), rows["J_z"].append(J_z)
            rows["qvel"].append(d.qvel.copy())
            q_des = robot.q_home + 0.1 * np.sin(2 * np.pi * 2.0 * t + np.arange(robot.nu))
            d.ctrl[:] = 40.0 * (q_des - d.qpos[np.asarray(robot.qpos_adr)]) - 0.6 * d.qvel[dof]
        # The force acting from t to t + dt is the one the next sample reports as truth.
        forces = _schedule(t + _SIM_DT, phase, weight)
        d.qfrc_applied[:] = 0.0
        for site, fz in zip(sites, forces):
            mujoco.mj_applyFT(
                m, d, np.array([0.0, 0.0, fz]), np.zeros(3), d.site_xpos[site], m.site_bodyid[site], d.qfrc_applied
            )
        mujoco.mj_step(m, d)
    return {k: np.asarray(v) for k, v in rows.items()}


@pytest.fixture(scope="module")
def sims(robot):
    return [_simulate(robot, phase, seed) for seed, phase in enumerate((0.0, 0.31, 0.62, 0.87))]


def _fleet_log(robot, sims) -> dict:
    per = ("q", "qd", "tau", "gyro", "acc", "quat_wxyz", "gt_pose", "gt_contact", "gt_force")
    log = {k: np.stack([s[k] for s in sims]) for k in per}
    n, T = log["q"].shape[:2]
    log.update(
        t=sims[0]["t"] + 0.01,
        robot=np.array("go2"),
        joint_names=np.array(robot.joint_names),
        fallen=np.zeros(n, bool),
        valid=np.ones((n, T), bool),
    )
    return log


@pytest.fixture(scope="module")
def fleet(sims):
    """Exact observer inputs (MuJoCo C) and truth of the simulated fleet, as the tuner takes them."""
    n, T = len(sims), len(sims[0]["t"])
    dt = np.full((n, T), _SIM_DT * _EVERY, np.float32)
    dt[:, 0] = np.nan
    restart = np.zeros((n, T), bool)
    restart[:, 0] = True
    stack = lambda k: jnp.asarray(np.stack([s[k] for s in sims]), jnp.float32)  # noqa: E731
    inputs = tn.ObserverInputs(
        p=stack("p"), tau_bar=stack("tau_bar"), J_z=stack("J_z"), dt=jnp.asarray(dt), restart=jnp.asarray(restart)
    )
    truth = tn.ContactTruth(
        contact=jnp.asarray(np.stack([s["gt_contact"] for s in sims])),
        force_z=stack("gt_force")[..., 2],
        valid=jnp.ones((n, T), bool),
    )
    return inputs, truth, sims[0]["t"]


_SPEC = tn.GridSpec(
    bandwidth=(15.0, 60.0),
    alpha_front=(0.1, 0.5),
    alpha_rear=(0.1, 0.5),
    threshold_on=(1.0, 5.0, 15.0),
    off_ratio=(0.5, 1.0),
)


# ---------------------------------------------------------------- observer inputs from a log


@pytest.mark.slow
def test_observer_inputs_from_a_log_match_mujoco_c(robot, sims):
    """p, tau_bar and J_z from the log (MJX) equal MuJoCo C's at the documented state: joints from
    the log, the gyro rotated into the base frame, the backward difference of gt_pose."""
    short = [{k: v[:12] for k, v in s.items()} for s in sims[:2]]
    log = _fleet_log(robot, short)
    log["tau"][1, 5, 2] = 1e3  # saturated: the step is skipped
    inputs, truth, t = tn.observer_inputs(robot, log, chunk=8, axes="z", passive=False, rows="full")
    # The defaults: joint coordinates, x, y, z force rows, passive forces.
    full, _, _ = tn.observer_inputs(robot, log, chunk=8)
    dofs = np.asarray(robot.dof_adr)
    m = robot.mj_model
    d_fd = mujoco.MjData(m)
    for i, s in enumerate(short):
        for k in range(1, 12):
            qvel = s["qvel"][k].copy()
            qvel[:3] = (s["gt_pose"][k, :3] - s["gt_pose"][k - 1, :3]) / (s["t"][k] - s["t"][k - 1])
            tau = s["tau"][k] if not (i == 1 and k == 5) else np.zeros(robot.nu)
            p, tau_bar, J_z = _reference_terms(
                m, d_fd, s["gt_pose"][k].tolist() + list(s["q"][k]), qvel, tau, np.asarray(robot.dof_adr)
            )
            np.testing.assert_allclose(inputs.p[i, k], p, rtol=1e-4, atol=1e-4)
            np.testing.assert_allclose(inputs.tau_bar[i, k], tau_bar, rtol=1e-3, atol=2e-3)
            np.testing.assert_allclose(inputs.J_z[i, k], J_z, atol=1e-5)
            np.testing.assert_allclose(full.J_z[i, k, 2::3], J_z[:, dofs], atol=1e-5)
            np.testing.assert_allclose(full.p[i, k], p[dofs], rtol=1e-4, atol=1e-4)
            d_fd.qpos[:], d_fd.qvel[:] = s["gt_pose"][k].tolist() + list(s["q"][k]), qvel
            mujoco.mj_forward(m, d_fd)
            passive = d_fd.qfrc_passive - m.dof_frictionloss * np.tanh(qvel / 0.5)
            np.testing.assert_allclose(full.tau_bar[i, k] - inputs.tau_bar[i, k, dofs], passive[dofs], atol=2e-3)
    assert np.isnan(inputs.dt[:, 0]).all() and inputs.restart[:, 0].all() and not inputs.restart[:, 1:].any()
    assert np.isnan(inputs.dt[1, 5]) and np.isfinite(np.delete(np.asarray(inputs.dt[1]), [0, 5])).all()
    np.testing.assert_array_equal(truth.contact, log["gt_contact"])
    np.testing.assert_allclose(truth.force_z, log["gt_force"][..., 2])
    assert full.axes == "xyz" and full.n_feet == 4 and full.J_z.shape[-2:] == (12, robot.nu)


def test_observer_inputs_errors(robot, sims):
    log = _fleet_log(robot, [{k: v[:4] for k, v in s.items()} for s in sims[:1]])
    for key in ("gt_contact", "tau"):
        bad = {k: v for k, v in log.items() if k != key}
        with pytest.raises(ValueError, match=key):
            tn.observer_inputs(robot, bad)
    bad = dict(log, joint_names=np.array(["x"] * 12))
    with pytest.raises(ValueError, match="no joint"):
        tn.observer_inputs(robot, bad)


def test_the_tuner_sees_the_pipelines_input_arrays(robot, sims):
    """One path from a log to the estimators' inputs: the tuner's observer inputs are what the pipeline's
    step builds from its own parsed log (`pipeline.inputs_from_log`): the same joints reordered by name,
    attitude, gyro in the base frame, torque mask, restarts and skipped steps; only the base velocity
    differs by design (ground truth here, the leg odometry's in the pipeline) and is given to both."""
    from jaxquad import dynamics
    from jaxquad.estimate import pipeline
    from jaxquad.estimate.inputs import R_base_imu, full_state, gaps, torque_ok
    from jaxquad.kernels.lie import SO3

    s = {k: v[:10] for k, v in sims[1].items()}
    perm = np.random.default_rng(3).permutation(robot.nu)  # the log lists joints in another order
    log = {k: s[k].copy() for k in ("gyro", "acc", "quat_wxyz", "gt_pose", "gt_contact", "gt_force")}
    log.update(
        q=s["q"][:, perm],
        qd=s["qd"][:, perm],
        tau=s["tau"][:, perm].copy(),
        t=s["t"] + 0.01,
        joint_names=np.array(robot.joint_names)[perm],
    )
    log["t"][6:] += 0.2  # a gap before sample 6
    log["tau"][3, 0], log["tau"][4, 5] = 1e3, np.nan  # a saturated and a missing torque
    # The IMU's attitude, not gt_pose's: 0.1 rad off in roll and not of unit norm.
    tilt = np.array([np.cos(0.05), np.sin(0.05), 0.0, 0.0])
    log["quat_wxyz"] = 1.01 * np.asarray((SO3(jnp.asarray(s["quat_wxyz"])) @ SO3(jnp.asarray(tilt))).wxyz, np.float64)

    params = pipeline.PipelineParams.default()
    inputs, config = pipeline.inputs_from_log(robot, log, "mixed")
    obs, truth, t = tn.observer_inputs(
        robot,
        log,
        max_gap_s=float(params.max_gap_s),
        torque_saturation=float(params.torque_saturation),
        axes=config.observer_axes,
        passive=config.observer_passive,
        rows=config.observer_rows,
    )
    one = jax.tree.map(lambda a: a[0], inputs)  # a single log is a fleet of one
    np.testing.assert_array_equal(one.q, np.float32(s["q"]))  # back in the model's joint order
    np.testing.assert_array_equal(truth.valid, inputs.valid)
    np.testing.assert_array_equal(t, log["t"])

    # The pipeline's step: restarts after the first sample and gaps, NaN dt where the step is skipped.
    first, gap = gaps(one.dt, params.max_gap_s)
    tau_ok = torque_ok(robot, one.tau, params.torque_saturation)
    skipped = ~(tau_ok & ~gap & ~first)
    assert int(first.sum()) == int(gap.sum()) == 1 and int((~tau_ok).sum()) == 2
    np.testing.assert_array_equal(obs.restart[0], first | gap)
    np.testing.assert_array_equal(np.isnan(obs.dt[0]), skipped)
    np.testing.assert_array_equal(np.asarray(obs.dt[0])[~skipped], np.asarray(one.dt)[~skipped])

    # ... and its momentum terms at the ground-truth velocity given to the tuner (backward differences).
    v = np.diff(s["gt_pose"][:, :3], axis=0) / np.diff(log["t"])[:, None]
    v = np.float32(np.concatenate([v[:1], v]))
    R_imu = jnp.asarray(R_base_imu(robot), jnp.float32)
    rows = np.asarray(robot.dof_adr)

    def step_terms(p, quat, q, v_world, gyro_imu, qd, tau):
        tau_obs = jnp.where(torque_ok(robot, tau, params.torque_saturation), tau, 0.0)
        qpos, qvel = full_state(robot, p, quat / jnp.linalg.norm(quat), q, v_world, R_imu @ gyro_imu, qd)
        p_mom, tau_bar, J_z = dynamics.momentum_terms(
            robot, qpos, qvel, tau_obs, passive=config.observer_passive, axes=config.observer_axes
        )
        return p_mom[rows], tau_bar[rows], J_z[:, rows]

    p_ref = jnp.asarray(s["gt_pose"][:, :3], jnp.float32)
    ref = jax.jit(jax.vmap(step_terms))(p_ref, one.quat_wxyz, one.q, v, one.gyro, one.qd, one.tau)
    for got, want in zip((obs.p[0], obs.tau_bar[0], obs.J_z[0]), ref):
        np.testing.assert_allclose(got, want, rtol=1e-5, atol=1e-4)


def test_full_force_observer_recovers_vertical_forces_under_tangential_forces(robot):
    """Constant foot forces with friction-like tangential parts on a still Go2 (p = 0, so tau_bar =
    -J^T f): the x, y, z observer's z estimates converge to the true z forces; a z-only observer
    explains the tangential parts with z forces and misses by newtons."""
    m = robot.mj_model
    d = mujoco.MjData(m)
    d.qpos[:] = robot.qpos_home
    mujoco.mj_forward(m, d)
    J = np.zeros((4, 3, m.nv))
    for f, site in enumerate(robot.foot_site_ids):
        mujoco.mj_jacSite(m, d, J[f], None, site)
    force = np.array([[8.0, -5.0, 40.0], [-6.0, 4.0, 35.0], [7.0, 6.0, 30.0], [-9.0, -3.0, 45.0]])
    T = 150
    dt = np.full(T, 0.004, np.float32)
    dt[0] = np.nan
    params = ObserverParams.paper(4, "plain", bandwidth=60.0)
    for axes, rows in (("xyz", J.reshape(12, m.nv)), ("z", J[:, 2, :])):
        inputs = tn.ObserverInputs(
            p=jnp.zeros((T, m.nv)),
            tau_bar=jnp.tile(jnp.asarray(-J.reshape(12, m.nv).T @ force.ravel(), jnp.float32), (T, 1)),
            J_z=jnp.tile(jnp.asarray(rows, jnp.float32), (T, 1, 1)),
            dt=jnp.asarray(dt),
            restart=jnp.arange(T) == 0,
            axes=axes,
        )
        est = tn.run_observer(params, inputs)
        assert est.force_z.shape == (T, 4) and inputs.n_feet == 4
        err = np.abs(np.asarray(est.force_z[-1]) - force[:, 2])
        if axes == "xyz":
            assert err.max() < 0.2, err
        else:
            assert err.max() > 3.0, err


# ---------------------------------------------------------------- grid search


def test_in_scan_counts_equal_numpy_scores_of_full_outputs(fleet):
    inputs, truth, t = fleet
    params = ObserverParams.paper(4, "mixed")
    counts = jax.jit(jax.vmap(tn.observer_counts, in_axes=(None, 0, 0)))(params, inputs, truth)
    est = jax.vmap(tn.run_observer, in_axes=(None, 0))(params, inputs)
    c, tr = np.asarray(est.contact), np.asarray(truth.contact)
    np.testing.assert_array_equal(counts.tp, (c & tr).sum(1))
    np.testing.assert_array_equal(counts.fp, (c & ~tr).sum(1))
    np.testing.assert_array_equal(counts.fn, (~c & tr).sum(1))
    sq = ((np.asarray(est.force_z_filtered, np.float64) - np.asarray(truth.force_z)) ** 2).sum(1)
    np.testing.assert_allclose(counts.force_sq, sq, rtol=1e-4)


def test_grid_finds_the_configuration_of_a_one_at_a_time_loop(fleet):
    inputs, truth, t = fleet
    base = ObserverParams.paper(4, "mixed")
    res = tn.grid_search(_SPEC, base, inputs, truth, t, chunk=7)  # 7 does not divide 48: padding used
    assert res.f1.shape == (_SPEC.size,) == (48,)

    # Reference: every configuration built by hand and scored alone (full outputs, NumPy scores).
    rows = []
    for b in _SPEC.bandwidth:
        for af in _SPEC.alpha_front:
            for ar in _SPEC.alpha_rear:
                for on in _SPEC.threshold_on:
                    for ratio in _SPEC.off_ratio:
                        p = dataclasses.replace(
                            base,
                            bandwidth=jnp.float32(b),
                            alpha=jnp.array([af, af, ar, ar], jnp.float32),
                            threshold_on=jnp.full(4, on, jnp.float32),
                            threshold_off=jnp.full(4, on * ratio, jnp.float32),
                        )
                        rows.append((p, tn.fleet_scores(p, inputs, truth, t)))
    f1 = np.array([s["f1"] for _, s in rows])
    np.testing.assert_allclose(res.f1, f1, atol=1e-6)
    order = np.argsort(-f1, kind="stable")
    cands = [i for i in order[:8] if f1[i] >= f1[order[0]] - 0.005]
    want = min(cands, key=lambda i: (tn.delay_cost(rows[i][1]), i))
    assert res.index == want
    assert res.scores == rows[want][1]
    for name in ("bandwidth", "alpha", "threshold_on", "threshold_off"):
        np.testing.assert_array_equal(getattr(res.best, name), getattr(rows[want][0], name))
    # The noisy torques make 1 N too low a threshold: the grid must beat the paper's defaults.
    assert res.scores["f1"] > tn.fleet_scores(base, inputs, truth, t)["f1"] + 0.05


def test_grid_spec_errors():
    # Rejected by the explicit check, or first by the tests' runtime type checker (a TypeError).
    with pytest.raises((ValueError, TypeError), match="size"):
        tn.GridSpec.default((3, 3))
    with pytest.raises(ValueError, match="off_ratio"):
        tn.GridSpec.default(2).__class__(
            bandwidth=(10.0,), alpha_front=(0.1,), alpha_rear=(0.1,), threshold_on=(1.0,), off_ratio=(0.0,)
        )
    with pytest.raises(ValueError, match="alpha"):
        tn.GridSpec(bandwidth=(10.0,), alpha_front=(1.5,), alpha_rear=(0.1,), threshold_on=(1.0,), off_ratio=(1.0,))
    assert tn.GridSpec.default(4).size == 4**5


# ---------------------------------------------------------------- gradient tuning


def test_unconstrained_round_trip_and_off_below_on():
    params = ObserverParams.paper(4, "mixed")
    params = dataclasses.replace(params, threshold_off=jnp.full(4, 0.5, jnp.float32))
    back = tn.Unconstrained.from_params(params).params(params)
    for name in ("bandwidth", "alpha", "threshold_on", "threshold_off"):
        np.testing.assert_allclose(getattr(back, name), getattr(params, name), rtol=1e-5)
    u = tn.Unconstrained(jnp.float32(9.0), jnp.full(4, -30.0), jnp.full(4, 40.0), jnp.full(4, 30.0))
    p = u.params(params)
    assert np.all(np.asarray(p.threshold_off) <= np.asarray(p.threshold_on)) and np.all(np.asarray(p.alpha) > 0)


def test_gradient_decreases_the_loss_and_improves_f1_from_a_bad_start(fleet):
    inputs, truth, t = fleet
    tr_in, tr_truth = tn.select_robots(inputs, [0, 1, 2]), tn.select_robots(truth, [0, 1, 2])
    bad = dataclasses.replace(
        ObserverParams.paper(4, "mixed"),
        bandwidth=jnp.float32(8.0),
        alpha=jnp.full(4, 0.03, jnp.float32),
        threshold_on=jnp.full(4, 60.0, jnp.float32),
        threshold_off=jnp.full(4, 50.0, jnp.float32),
    )
    res = tn.gradient_tune(bad, tr_in, tr_truth, steps=60, learning_rate=0.1, patience=10)
    assert res.loss[res.best_step] < 0.7 * res.loss[0]
    # Finite differences of the surrogate agree with its gradient (float32, central, one direction).
    u = tn.Unconstrained.from_params(res.best)
    g = jax.grad(tn.surrogate_loss)(u, bad, tr_in, tr_truth)
    eps = 1e-2
    hi, lo = (dataclasses.replace(u, log_bandwidth=u.log_bandwidth + s * eps) for s in (1, -1))
    fd = (tn.surrogate_loss(hi, bad, tr_in, tr_truth) - tn.surrogate_loss(lo, bad, tr_in, tr_truth)) / (2 * eps)
    np.testing.assert_allclose(g.log_bandwidth, fd, rtol=0.1, atol=1e-4)
    rest = tn.select_robots(inputs, [3]), tn.select_robots(truth, [3])
    before, after = (tn.fleet_scores(p, *rest, t)["f1"] for p in (bad, res.best))
    assert after > before + 0.2, (before, after)


# ---------------------------------------------------------------- files and the whole run


@pytest.mark.parametrize("suffix", [".json", ".yaml"])
def test_saved_params_load_back_and_reproduce_the_scores(fleet, tmp_path, suffix):
    inputs, truth, t = fleet
    spec = tn.GridSpec(
        bandwidth=(20.0, 50.0), alpha_front=(0.2,), alpha_rear=(0.3,), threshold_on=(4.0, 12.0), off_ratio=(0.5,)
    )
    best, summary = tn.tune_fleet("grid", inputs, truth, t, spec=spec, chunk=4)
    assert summary["robots_train"] == 3 and summary["robots_heldout"] == 1
    path = tn.save_params(tmp_path / f"best{suffix}", best, header="tuned by grid search")
    loaded = load_params(path, 4, "mixed").observer
    for name in ("bandwidth", "alpha", "threshold_on", "threshold_off", "f_max", "sharpness"):
        np.testing.assert_array_equal(getattr(loaded, name), getattr(best, name))
    assert loaded.mode == "mixed"
    held = tn.select_robots(inputs, [3]), tn.select_robots(truth, [3])
    assert tn.fleet_scores(loaded, *held, t) == summary["tuned_heldout"]
    assert json.loads(json.dumps(summary)) == summary  # JSON-ready


def test_bad_input_gives_one_line_errors(fleet, tmp_path):
    inputs, truth, t = fleet
    best = ObserverParams.paper(4, "mixed")
    with pytest.raises(ValueError, match="must end in"):
        tn.save_params(tmp_path / "p.txt", best)
    with pytest.raises(ValueError, match="holdout"):
        tn.split_robots(4, 1.0)
    with pytest.raises(ValueError, match="no training robot"):
        tn.split_robots(1, 0.5)
    with pytest.raises((ValueError, TypeError), match="method"):  # TypeError: the tests' runtime type checker
        tn.tune_fleet("random", inputs, truth, t)
    with pytest.raises(ValueError, match="steps"):
        tn.gradient_tune(best, inputs, truth, steps=0)


def test_cli_one_line_errors(tmp_path, capsys):
    from jaxquad.cli import main

    assert (
        main(["tune", "--log", str(tmp_path / "none.npz"), "--method", "grid", "--out", str(tmp_path / "p.yaml")]) == 1
    )
    assert "log file not found" in capsys.readouterr().err
    assert (
        main(["tune", "--log", str(tmp_path / "none.npz"), "--method", "grid", "--out", str(tmp_path / "p.txt")]) == 1
    )
    err = capsys.readouterr().err.strip()
    assert "--out must end in" in err and "\n" not in err


@pytest.mark.slow
def test_cli_end_to_end_on_a_written_log(robot, sims, tmp_path, capsys):
    from jaxquad.cli import main
    from jaxquad.io import save_log

    log = _fleet_log(robot, [{k: v[:12] for k, v in s.items()} for s in sims[:2]])
    save_log(tmp_path / "fleet.npz", log)
    out = tmp_path / "best.json"
    args = [
        "tune",
        "--log",
        str(tmp_path / "fleet.npz"),
        "--method",
        "grid",
        "--grid-size",
        "1,1,1,2,1",
        "--out",
        str(out),
    ]
    assert main(args) == 0
    summary = json.loads(capsys.readouterr().out)  # pretty-printed: the whole of stdout
    assert summary["configurations"] == 2 and summary["robots_heldout"] == 1
    assert json.loads((tmp_path / "best.summary.json").read_text()) == summary
    loaded = load_params(out, 4, "mixed").observer
    np.testing.assert_allclose(loaded.bandwidth, summary["params"]["bandwidth"])
