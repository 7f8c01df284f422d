"""The pipeline on synthetic logs built with MuJoCo C: the base moves along a known trajectory while
the four feet stay fixed in the world; joint angles from damped-Newton IK, joint velocities from
J_joints qd = -J_base v_base (the foot velocity is zero)."""

import dataclasses

import jax.numpy as jnp
import mujoco
import numpy as np
import pytest

from jaxquad.estimate import pipeline
from jaxquad.robots import load

RATE_HZ = 200.0


def base_motion(t):
    """Known base pose and twist: sway in x and y, bob in z, yaw/pitch/roll oscillations."""
    w = 2 * np.pi * 0.5
    p = np.stack([0.05 * np.sin(w * t), 0.03 * np.sin(2 * w * t), 0.27 + 0.02 * np.sin(w * t)], -1)
    ang = np.stack([0.05 * np.sin(w * t), 0.04 * np.sin(w * t + 1), 0.1 * np.sin(w * t)], -1)  # roll pitch yaw
    return p, ang


def rpy_quat(r, p, y):
    q = np.zeros(4)
    mujoco.mju_euler2Quat(q, np.array([r, p, y]), "XYZ")  # extrinsic x, y, z: R = Rz Ry Rx
    return q


@pytest.fixture(scope="module")
def robot():
    return load("go2")


@pytest.fixture(scope="module")
def fixed_feet_log(robot):
    m = robot.mj_model
    d = mujoco.MjData(m)
    t = np.arange(0.0, 2.0, 1.0 / RATE_HZ)
    p, ang = base_motion(t)
    quats = np.stack([rpy_quat(*a) for a in ang])
    d.qpos[:] = robot.qpos_home
    d.qpos[:3], d.qpos[3:7] = p[0], quats[0]
    mujoco.mj_kinematics(m, d)
    feet_world = d.site_xpos[robot.foot_site_ids].copy()

    qadr, dadr = robot.qpos_adr, robot.dof_adr
    jac = np.zeros((3, m.nv))
    q_log, qd_log, gyro = [], [], []
    eps = 1e-6
    for k, tk in enumerate(t):
        d.qpos[:3], d.qpos[3:7] = p[k], quats[k]
        for _ in range(20):  # damped Newton IK on the leg joints
            mujoco.mj_kinematics(m, d)
            mujoco.mj_comPos(m, d)
            for f, s in enumerate(robot.foot_site_ids):
                mujoco.mj_jacSite(m, d, jac, None, s)
                cols = dadr[robot.leg_joints[f]]
                err = feet_world[f] - d.site_xpos[s]
                J = jac[:, cols]
                d.qpos[qadr[robot.leg_joints[f]]] += np.linalg.solve(J.T @ J + 1e-9 * np.eye(3), J.T @ err)
        # Base twist by central differences of the closed-form pose (qvel: world linear, body angular).
        pa, aa = base_motion(np.array([tk - eps, tk + eps]))
        qa, qb = rpy_quat(*aa[0]), rpy_quat(*aa[1])
        omega = np.zeros(3)
        mujoco.mju_subQuat(omega, qb, qa)
        omega /= 2 * eps
        v_world = (pa[1] - pa[0]) / (2 * eps)
        mujoco.mj_kinematics(m, d)
        mujoco.mj_comPos(m, d)
        qd = np.zeros(m.nu)
        for f, s in enumerate(robot.foot_site_ids):
            mujoco.mj_jacSite(m, d, jac, None, s)
            v_base_part = jac[:, :3] @ v_world + jac[:, 3:6] @ omega
            cols = dadr[robot.leg_joints[f]]
            qd[robot.leg_joints[f]] = np.linalg.solve(jac[:, cols], -v_base_part)
        q_log.append(d.qpos[qadr].copy())
        qd_log.append(qd)
        gyro.append(omega)
    acc = []
    for qk in quats:
        Rk = np.zeros(9)
        mujoco.mju_quat2Mat(Rk, qk)
        acc.append(Rk.reshape(3, 3).T @ [0, 0, 9.81])
    return {
        "t": t,
        "robot": np.array("go2"),
        "joint_names": np.array(robot.joint_names[::-1]),  # reversed: the pipeline reorders by name
        "q": np.array(q_log)[:, ::-1],
        "qd": np.array(qd_log)[:, ::-1],
        "gyro": np.array(gyro),
        "acc": np.array(acc),
        "quat_wxyz": quats,
        "gt_pose": np.concatenate([p, quats], 1),
        "gt_contact": np.ones((t.size, 4), bool),
    }


def run(robot, log, contacts="truth"):
    inputs, config = pipeline.inputs_from_log(robot, log, contacts)
    # The synthetic feet are pinned at their centres (they turn in place), not rolling.
    config = dataclasses.replace(config, rolling=False)
    out = pipeline.estimate_fleet(robot, config, pipeline.PipelineParams.default(), inputs)
    return out, config


def test_fixed_feet_motion_is_recovered(robot, fixed_feet_log):
    log = fixed_feet_log
    out, config = run(robot, log)
    assert config.has_qd and config.has_attitude
    p_est = np.asarray(out.p_world_base[0])
    p_true = log["gt_pose"][:, :3]
    # The twist of sample k-1 held over the step: first-order error ~ |a| dt / 2 per unit time.
    assert np.abs(p_est - p_true).max() < 3e-3
    assert not np.asarray(out.flags.no_stance[0]).any()
    assert not np.asarray(out.flags.fallen[0]).any()


def test_a_foot_that_touches_down_ramps_into_the_twist(robot, fixed_feet_log):
    # Foot 0 lifts at sample 100 and is down again from sample 150: its twist weight is its stance
    # time over settle_s (5, 10, ... ms of 32 at 200 Hz), then 1. Feet down when the log starts count
    # as settled; with `settle` off each foot's weight is its contact.
    log = dict(fixed_feet_log)
    contact = log["gt_contact"].copy()
    contact[100:150, 0] = False
    log["gt_contact"] = contact
    inputs, config = pipeline.inputs_from_log(robot, log, "truth")
    config = dataclasses.replace(config, rolling=False)  # pinned feet, as `run`
    params = pipeline.PipelineParams.default()
    weight = {
        settle: np.asarray(
            pipeline.estimate_fleet(robot, dataclasses.replace(config, settle=settle), params, inputs).twist_weight[0]
        )
        for settle in (True, False)
    }
    expected = contact.astype(np.float64)
    k = np.arange(150, 160)
    expected[k, 0] = np.minimum((k - 149) / RATE_HZ / float(params.settle_s), 1.0)
    np.testing.assert_allclose(weight[True], expected, atol=1e-5)
    assert 0.0 < weight[True][150, 0] < 0.2 and weight[True][160, 0] == 1.0
    np.testing.assert_array_equal(weight[False], contact)


def test_a_held_twist_keeps_the_last_covariance_and_grows(robot, fixed_feet_log):
    # All four feet up for samples 100-104: the twist is not observed, the last one is held, and its
    # covariance is the last observed one plus (held_accel_std x time held)^2 (not the solve's
    # "no foot" variance, which would void any constraint built on the held twist).
    log = dict(fixed_feet_log)
    contact = log["gt_contact"].copy()
    contact[100:105] = False
    log["gt_contact"] = contact
    out, _ = run(robot, log)
    no_stance = np.asarray(out.flags.no_stance[0])
    # Back down at 105, the feet ramp in over settle_s: the twist is observed again a few samples later.
    end = 105 + int(np.argmin(no_stance[105:]))
    assert no_stance[100:end].all() and not no_stance[:100].any() and not no_stance[end:].any()
    assert 105 < end <= 105 + int(np.ceil(float(pipeline.PipelineParams.default().settle_s) * RATE_HZ))
    v, cov = np.asarray(out.v_base[0], np.float64), np.asarray(out.cov_v_base[0], np.float64)
    np.testing.assert_array_equal(v[100:end], np.broadcast_to(v[99], (end - 100, 3)))
    std = float(pipeline.PipelineParams.default().held_accel_std)
    held_s = (np.arange(100, end) - 99) / RATE_HZ
    expected = cov[99] + (std * held_s)[:, None, None] ** 2 * np.eye(3)
    np.testing.assert_allclose(cov[100:end], expected, rtol=1e-5, atol=1e-9)
    assert cov[end].max() < 1.0  # observed again: the solve's own covariance


def test_a_twist_held_across_a_gap_or_a_fall_is_unobserved(robot, fixed_feet_log):
    # Feet up from sample 100 in both robots; robot 0's log has a 200 ms gap before sample 103, robot 1
    # falls at sample 103. From there the held twist (robot 1's zeroed by the fall) was not measured.
    clean = fixed_feet_log
    fleet = {k: (np.stack([v, v]) if k not in ("t", "robot", "joint_names") else v) for k, v in clean.items()}
    fleet["gt_contact"] = fleet["gt_contact"].copy()
    fleet["gt_contact"][:, 100:] = False
    fleet["t"] = clean["t"].copy()
    fleet["t"][103:] += 0.2
    fleet["quat_wxyz"] = fleet["quat_wxyz"].copy()
    fleet["quat_wxyz"][1, 103:] = [np.cos(0.75), np.sin(0.75), 0, 0]  # rolled 1.5 rad: fallen
    fleet["fallen"] = np.array([False, True])
    fleet["valid"] = np.ones((2, clean["t"].size), bool)
    inputs, config = pipeline.inputs_from_log(robot, fleet, "truth")
    config = dataclasses.replace(config, rolling=False)  # pinned feet, as `run`
    out = pipeline.estimate_fleet(robot, config, pipeline.PipelineParams.default(), inputs)
    cov = np.asarray(out.cov_v_base, np.float64)
    assert np.asarray(out.flags.no_stance)[:, 100:].all()
    assert np.asarray(out.flags.gap)[0, 103] and np.asarray(out.flags.fallen)[1, 103]
    assert (cov[:, 100:103].max(axis=(-1, -2)) < 1.0).all()  # held before the gap or the fall
    np.testing.assert_array_less(9.99e3, np.diagonal(cov[0, 103:], axis1=-2, axis2=-1))  # from the gap on
    np.testing.assert_array_less(9.99e3, np.diagonal(cov[1, 104:], axis1=-2, axis2=-1))  # after the fall


def test_bad_data_is_flagged_and_never_reaches_the_trajectory(robot, fixed_feet_log):
    """A fleet of two: robot 0 clean, robot 1 with NaN joints, NaN gyro, a fall and a time gap."""
    clean = fixed_feet_log
    t = clean["t"].copy()
    t[300:] += 0.2  # a 200 ms gap between samples 299 and 300 (shared time axis)
    fleet = {k: (np.stack([v, v]) if k not in ("t", "robot", "joint_names") else v) for k, v in clean.items()}
    fleet["t"] = t
    fleet["q"] = fleet["q"].copy()
    fleet["q"][1, 50:55, 3] = np.nan
    fleet["gyro"] = fleet["gyro"].copy()
    fleet["gyro"][1, 80:82] = np.inf
    fleet["quat_wxyz"] = fleet["quat_wxyz"].copy()
    fleet["quat_wxyz"][1, 350:] = [np.cos(0.75), np.sin(0.75), 0, 0]  # rolled 1.5 rad: fallen
    fleet["fallen"] = np.array([False, True])
    fleet["valid"] = np.ones((2, t.size), bool)

    inputs, config = pipeline.inputs_from_log(robot, fleet, "truth")
    config = dataclasses.replace(config, rolling=False)  # pinned feet, as `run`
    out = pipeline.estimate_fleet(robot, config, pipeline.PipelineParams.default(), inputs)
    p = np.asarray(out.p_world_base)
    assert np.isfinite(p).all() and np.isfinite(np.asarray(out.q_world_base)).all()
    f = out.flags
    bad_joints, bad_imu = np.asarray(f.bad_joints), np.asarray(f.bad_imu)
    assert bad_joints[1, 50:55].all() and not bad_joints[1, 55:].any() and not bad_joints[0].any()
    assert bad_imu[1, 80:82].all() and not bad_imu[0].any()
    gap = np.asarray(f.gap)
    assert gap[:, 300].all() and gap.sum() == 2
    fallen = np.asarray(f.fallen)
    assert fallen[1, 350:].all() and not fallen[1, :350].any() and not fallen[0].any()
    np.testing.assert_array_equal(p[1, 350:], np.broadcast_to(p[1, 349], p[1, 350:].shape))  # held
    # The gap is not integrated: the pose across it does not move.
    np.testing.assert_allclose(p[0, 300], p[0, 299], atol=1e-6)
    # Up to the gap the clean robot tracks the truth, and the bad robot's short dropouts cost little.
    p_true = clean["gt_pose"][:, :3]
    assert np.abs(p[0, :300] - p_true[:300]).max() < 3e-3
    assert np.abs(p[1, :300] - p_true[:300]).max() < 5e-3


def test_inputs_from_log_errors(robot, fixed_feet_log):
    log = dict(fixed_feet_log)
    with pytest.raises(ValueError, match="needs joint torques"):
        pipeline.inputs_from_log(robot, log, "mixed")
    with pytest.raises(ValueError, match="needs 'contact' or 'foot_force'"):
        pipeline.inputs_from_log(robot, log, "sensor")
    log["joint_names"] = np.array(["a"] * 12)
    with pytest.raises(ValueError, match="has no joint"):
        pipeline.inputs_from_log(robot, log, "truth")
    with pytest.raises(ValueError, match="observer_axes"):
        pipeline.PipelineConfig(contacts="mixed", observer_axes="xy")


def test_cli_end_to_end_on_a_written_log(robot, fixed_feet_log, tmp_path):
    """`jaxquad estimate` on the fixed-feet log: files written, scores from ground truth."""
    import json

    from jaxquad.cli import main
    from jaxquad.io import read_tum, save_log

    log_path = save_log(tmp_path / "log.npz", fixed_feet_log)
    params = tmp_path / "p.yaml"
    params.write_text("bandwidth: 40\nmode: mixed\nalpha: [0.3, 0.3, 0.1, 0.1]\n")  # same structure: no recompile
    args = ["--contacts", "truth", "--params", str(params), "--feet", "point"]  # pinned feet, as `run`
    assert main(["estimate", str(log_path), "--out", str(tmp_path / "out"), *args]) == 0
    summary = json.loads((tmp_path / "out" / "summary.json").read_text())
    # Every parameter used is recorded: the file's observer numbers, every other number at its default.
    recorded, default = summary["params"], pipeline.PipelineParams.default()
    assert set(recorded) == {f.name for f in dataclasses.fields(default)}
    assert recorded["observer"]["bandwidth"] == 40.0 and recorded["observer"]["alpha"] == [0.3, 0.3, 0.1, 0.1]
    assert recorded["observer"]["threshold_on"] == np.asarray(default.observer.threshold_on, np.float32).tolist()
    for name in ("imu_weight", "min_stance", "max_gap_s", "robust_scale"):
        assert recorded[name] == pytest.approx(float(getattr(default, name)), rel=1e-6), name
    assert recorded["floor"]["meas_std"] == pytest.approx(float(default.floor.meas_std), rel=1e-6)
    assert summary["config"]["rolling"] is False and summary["contacts"] == "truth"
    s = summary["robots"][0]["scores"]
    assert s["contacts"]["f1"] == 1.0  # truth contacts against truth
    assert s["trajectory"]["ate"]["rmse"] < 3e-3
    assert s["drift"]["endpoint_drift_3d_pct"] < 5.0
    traj = read_tum(tmp_path / "out" / "robot.tum")
    np.testing.assert_allclose(traj.p_world_body, fixed_feet_log["gt_pose"][:, :3], atol=3e-3)
    assert (
        main(["estimate", str(log_path), "--out", str(tmp_path / "o2"), "--params", str(tmp_path / "none.yaml")]) == 1
    )
    params.write_text("bandwith: 40\n")
    assert main(["estimate", str(log_path), "--out", str(tmp_path / "o3"), "--params", str(params)]) == 1


@pytest.mark.slow
def test_simulated_log_end_to_end(tmp_path):
    """`jaxquad simulate` then `jaxquad estimate` with ground-truth contacts on a short walk."""
    import json

    from jaxquad.cli import main

    sim = tmp_path / "sim"
    assert main(["simulate", "--robots", "1", "--seconds", "2", "--no-depth", "--no-randomize", "--out", str(sim)]) == 0
    assert main(["estimate", str(sim / "fleet.npz"), "--out", str(tmp_path / "est"), "--contacts", "truth"]) == 0
    robot = json.loads((tmp_path / "est" / "summary.json").read_text())["robots"][0]
    assert not robot["fallen"]
    assert robot["scores"]["contacts"]["f1"] == 1.0
    # Leg-inertial odometry on truth contacts: a few percent of the distance, far below dead reckoning.
    assert robot["scores"]["drift"]["endpoint_drift_3d_pct"] < 30.0
    assert robot["scores"]["trajectory"]["ate"]["rmse"] < 0.1


@pytest.fixture(scope="module")
def standing_log(robot):
    """MuJoCo C: the robot stands on its floor under joint PD; true foot forces from mj_contactForce."""
    m = robot.mj_model
    d = mujoco.MjData(m)
    d.qpos[:] = robot.qpos_home
    d.qpos[robot.base_qpos_adr + 2] += 0.01
    kp, kd = 40.0, 1.0
    rows = {k: [] for k in ("t", "q", "qd", "tau", "gyro", "acc", "quat_wxyz", "gt_pose", "gt_force")}
    foot_of_geom = {int(g): f for f, g in enumerate(robot.foot_geom_ids)}
    n_settle, n_log = 250, 150  # 1 s to settle, 0.6 s logged
    for k in range(n_settle + n_log):
        q, qd = d.qpos[robot.qpos_adr].copy(), d.qvel[robot.dof_adr].copy()
        tau = kp * (robot.q_home - q) - kd * qd
        d.ctrl[:] = tau
        mujoco.mj_step(m, d)
        if k < n_settle:
            continue
        mujoco.mj_rnePostConstraint(m, d)
        fz = np.zeros((4, 3))
        f6 = np.zeros(6)
        for i in range(d.ncon):
            c = d.contact[i]
            foot = foot_of_geom.get(int(c.geom1), foot_of_geom.get(int(c.geom2)))
            if foot is None:
                continue
            mujoco.mj_contactForce(m, d, i, f6)
            fz[foot] += np.abs(c.frame.reshape(3, 3).T @ f6[:3])
        base_q = d.qpos[robot.base_qpos_adr + 3 : robot.base_qpos_adr + 7].copy()
        R = np.zeros(9)
        mujoco.mju_quat2Mat(R, base_q)
        rows["t"].append(d.time)
        rows["q"].append(d.qpos[robot.qpos_adr].copy())
        rows["qd"].append(d.qvel[robot.dof_adr].copy())
        rows["tau"].append(tau)
        rows["gyro"].append(d.qvel[robot.base_dof_adr + 3 : robot.base_dof_adr + 6].copy())
        rows["acc"].append(R.reshape(3, 3).T @ [0, 0, 9.81])
        rows["quat_wxyz"].append(base_q)
        rows["gt_pose"].append(np.concatenate([d.qpos[robot.base_qpos_adr : robot.base_qpos_adr + 3], base_q]))
        rows["gt_force"].append(fz)
    log = {k: np.array(v) for k, v in rows.items()}
    log["robot"], log["joint_names"] = np.array("go2"), np.array(robot.joint_names)
    return log


def test_observer_forces_match_mujoco_contact_forces(robot, standing_log):
    """Plain observer (paper gains) on a standing robot: per-foot vertical force vs MuJoCo C."""
    log = standing_log
    true_fz = log["gt_force"][:, :, 2]
    assert (true_fz[-1] > 10).all() and abs(true_fz[-1].sum() - robot.mass * 9.81) < 0.05 * robot.mass * 9.81
    inputs, config = pipeline.inputs_from_log(robot, log, "observer")
    out = pipeline.estimate_fleet(robot, config, pipeline.PipelineParams.default(mode="plain"), inputs)
    fz = np.asarray(out.force_z_filtered[0])
    late = slice(75, None)  # after the observer (b = 30 rad/s) and the smoothing converged
    np.testing.assert_allclose(fz[late], true_fz[late], atol=0.1 * true_fz[-1].max())
    assert np.asarray(out.contact[0, late]).all()
    assert np.isfinite(np.asarray(out.p_world_base)).all()
    assert np.abs(np.asarray(out.p_world_base[0]) - log["gt_pose"][:, :3]).max() < 5e-3


@pytest.mark.slow  # compiling the gradient through MJX takes minutes on two shared cores
def test_derivative_through_soft_contacts(robot, standing_log):
    """d(final position)/d(observer threshold) with soft contacts, by forward-mode AD through the whole
    pipeline: finite and equal to central differences. (Forward mode suits one scalar parameter and compiles
    in a third of reverse mode's time; reverse mode through the observer is what `test_tune` exercises.)"""
    import dataclasses

    import equinox as eqx
    import jax

    log = {
        k: (v[:40] if isinstance(v, np.ndarray) and v.ndim and v.shape[0] == 150 else v)
        for k, v in standing_log.items()
    }
    inputs, config = pipeline.inputs_from_log(robot, log, "observer")
    config = dataclasses.replace(config, soft_contacts=True)
    one = jax.tree.map(lambda a: a[0], inputs)
    base = pipeline.PipelineParams.default(mode="plain")

    def loss(threshold):
        params = eqx.tree_at(lambda p: p.observer.threshold_on, base, jnp.full(4, threshold))
        out = pipeline.estimate_robot(robot, config, params, one)
        return jnp.sum(out.p_world_base[-1] ** 2) + jnp.sum(out.contact_soft)

    # One compiled program gives the derivative and, at the neighbouring thresholds, the values to difference.
    value_and_derivative = jax.jit(lambda th: jax.jvp(loss, (th,), (jnp.ones_like(th),)))
    _, g = value_and_derivative(jnp.asarray(30.0))
    h = 0.5
    fd = (value_and_derivative(jnp.asarray(30.0 + h))[0] - value_and_derivative(jnp.asarray(30.0 - h))[0]) / (2 * h)
    assert np.isfinite(float(g)) and abs(float(g)) > 1e-3
    np.testing.assert_allclose(float(g), float(fd), rtol=0.05)
