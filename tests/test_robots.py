"""Robot models and the loader: structure, masses, standing in MuJoCo C, user files, errors."""

import mujoco
import numpy as np
import pytest

from jaxquad.robots import LEGS, Robot, load

# facts.md Sec. 1
GO2_MASS = 6.921 + 4 * (0.678 + 1.152 + 0.241)
BADGER_MASS = 5.423 + 1.337 + 4 * (0.645 + 0.827 + 0.118)


def _tiny_mjcf(free: bool = True, foot_sites: bool = False) -> str:
    """A small quadruped: box trunk, three hinges per leg, sphere feet named <LEG>_foot (geoms)."""
    legs = []
    for leg, x, y in [("FL", 0.2, 0.05), ("FR", 0.2, -0.05), ("RL", -0.2, 0.05), ("RR", -0.2, -0.05)]:
        site = f'<site name="{leg}_foot" pos="0 0 -0.2"/>' if foot_sites else ""
        legs.append(f"""
      <body name="{leg}_hip" pos="{x} {y} 0">
        <joint name="{leg}_a" axis="1 0 0"/><geom type="sphere" size="0.03" mass="0.5" contype="0" conaffinity="0"/>
        <body name="{leg}_thigh" pos="0 {y} 0">
          <joint name="{leg}_b" axis="0 1 0"/>
          <geom type="capsule" fromto="0 0 0 0 0 -0.2" size="0.02" mass="1" contype="0" conaffinity="0"/>
          <body name="{leg}_calf" pos="0 0 -0.2">
            <joint name="{leg}_c" axis="0 1 0"/>
            <geom type="capsule" fromto="0 0 0 0 0 -0.2" size="0.01" mass="0.2" contype="0" conaffinity="0"/>
            <geom name="{leg}_foot" type="sphere" pos="0 0 -0.2" size="0.02" mass="0.05"/>{site}
          </body>
        </body>
      </body>""")
    joint = "<freejoint/>" if free else ""
    return f"""<mujoco><worldbody><body name="base" pos="0 0 0.4">{joint}
      <geom type="box" size="0.25 0.1 0.05" mass="5" contype="0" conaffinity="0"/>{"".join(legs)}
    </body></worldbody></mujoco>"""


def _tiny_urdf() -> str:
    inertia = '<inertia ixx="1e-3" iyy="1e-3" izz="1e-3" ixy="0" ixz="0" iyz="0"/>'
    parts = [f'<link name="base"><inertial><mass value="5"/>{inertia}</inertial></link>']
    for leg, x, y in [("FL", 0.2, 0.05), ("FR", 0.2, -0.05), ("RL", -0.2, 0.05), ("RR", -0.2, -0.05)]:
        chain = [
            ("base", f"{leg}_hip", f"{x} {y} 0", "1 0 0"),
            (f"{leg}_hip", f"{leg}_thigh", f"0 {y} 0", "0 1 0"),
            (f"{leg}_thigh", f"{leg}_calf", "0 0 -0.2", "0 1 0"),
        ]
        for parent, child, xyz, axis in chain:
            parts.append(f'<link name="{child}"><inertial><mass value="0.5"/>{inertia}</inertial></link>')
            parts.append(
                f'<joint name="{child}_joint" type="revolute"><parent link="{parent}"/><child link="{child}"/>'
                f'<origin xyz="{xyz}"/><axis xyz="{axis}"/>'
                f'<limit lower="-2" upper="2" effort="20" velocity="30"/></joint>'
            )
        parts.append(
            f'<link name="{leg}_foot"><collision><geometry><sphere radius="0.02"/></geometry></collision></link>'
        )
        parts.append(
            f'<joint name="{leg}_foot_fixed" type="fixed"><parent link="{leg}_calf"/><child link="{leg}_foot"/>'
            '<origin xyz="0 0 -0.2"/></joint>'
        )
    return f'<robot name="tiny">{"".join(parts)}</robot>'


@pytest.mark.parametrize("name", ["go2", "badger"])
def test_builtin_structure(name):
    r = load(name)
    assert isinstance(r, Robot) and r.name == name
    assert r.foot_names == tuple(f"{leg}_foot" for leg in LEGS)
    assert r.leg_joints.shape == (4, 3)
    assert r.nu == len(r.joint_names) == r.mj_model.nu == (13 if name == "badger" else 12)
    assert r.nq == r.mj_model.nq and r.nv == r.mj_model.nv == r.nu + 6
    assert r.spine_joint == ("spine_joint" if name == "badger" else None)
    m = r.mj_model
    for leg, joints in zip(LEGS, r.leg_joints):
        names = [r.joint_names[j] for j in joints]
        assert all(n.startswith(leg + "_") for n in names)
        assert m.jnt_axis[mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_JOINT, names[0])].tolist() == [1, 0, 0]
    # Actuator i drives joint_names[i]; the addresses point at that joint.
    for i, jn in enumerate(r.joint_names):
        j = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_JOINT, jn)
        assert m.actuator_trnid[i, 0] == j and m.actuator_gear[i, 0] == 1
        assert r.qpos_adr[i] == m.jnt_qposadr[j] and r.dof_adr[i] == m.jnt_dofadr[j]
    assert m.jnt_type[m.body_jntadr[r.base_body_id]] == mujoco.mjtJoint.mjJNT_FREE
    assert [m.site(s).name for s in r.foot_site_ids] == list(r.foot_names)
    assert [m.geom(g).name for g in r.foot_geom_ids] == list(r.foot_names)
    assert m.site(r.imu_site_id).name == "imu" and m.cam(r.camera_id).name == "depth"
    np.testing.assert_array_equal(r.q_home, r.qpos_home[r.qpos_adr])
    # Feet-only collision: the foot spheres and the floor are the only colliding geoms.
    colliding = {m.geom(g).name for g in range(m.ngeom) if m.geom_contype[g] or m.geom_conaffinity[g]}
    assert colliding == set(r.foot_names) | {"floor"}


def test_masses_match_facts():
    go2, badger = load("go2"), load("badger")
    assert go2.mass == pytest.approx(GO2_MASS, abs=0.01) and go2.mass == pytest.approx(15.2, abs=0.1)
    assert badger.mass == pytest.approx(BADGER_MASS, abs=0.01) and badger.mass == pytest.approx(13.1, abs=0.1)
    assert go2.mj_model.body_mass[go2.base_body_id] == pytest.approx(6.921)
    assert badger.mj_model.body_mass[badger.base_body_id] == pytest.approx(5.423)
    m = badger.mj_model
    rear = m.jnt_bodyid[mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_JOINT, "spine_joint")]
    assert m.body_mass[rear] == pytest.approx(1.337)
    # Every inertia satisfies the triangle inequality (a physical rigid body).
    for mm in (go2.mj_model, m):
        i = mm.body_inertia[1:]
        assert np.all(i[:, 0] + i[:, 1] >= i[:, 2]) and np.all(i[:, 1] + i[:, 2] >= i[:, 0])
        assert np.all(i[:, 0] + i[:, 2] >= i[:, 1])


def test_limits_match_facts():
    go2, badger = load("go2"), load("badger")
    np.testing.assert_allclose(go2.torque_limit, [23.7, 23.7, 45.43] * 4)
    np.testing.assert_allclose(badger.torque_limit, [16.0] * 12 + [48.0])
    np.testing.assert_allclose(go2.joint_range[:3], [[-1.0472, 1.0472], [-1.5708, 3.4907], [-2.7227, -0.8378]])
    np.testing.assert_allclose(go2.joint_range[7], [-0.5236, 4.5379])
    np.testing.assert_allclose(badger.joint_range[12], [-0.785, 0.785])
    m = go2.mj_model
    assert np.all(m.dof_armature[6:] == 0.01) and np.all(m.dof_frictionloss[6:] == 0.2)


def test_spine_joint_position():
    r = load("badger")
    m = r.mj_model
    d = mujoco.MjData(m)
    mujoco.mj_forward(m, d)
    j = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_JOINT, "spine_joint")
    R = d.xmat[r.base_body_id].reshape(3, 3)
    p = R.T @ (d.xanchor[j] - d.xpos[r.base_body_id])
    np.testing.assert_allclose(p, [-0.141, 0, 0], atol=1e-9)
    np.testing.assert_allclose(R.T @ d.xaxis[j], [0, 1, 0], atol=1e-9)


@pytest.mark.parametrize("name, height", [("go2", 0.27), ("badger", 0.316)])
def test_home_keyframe_geometry(name, height):
    r = load(name)
    m = r.mj_model
    d = mujoco.MjData(m)
    d.qpos[:] = r.qpos_home
    mujoco.mj_forward(m, d)
    assert d.qpos[2] == pytest.approx(height)
    # Camera looks along the trunk's +x (its -z axis) with its +y up.
    cam = d.cam_xmat[r.camera_id].reshape(3, 3)
    np.testing.assert_allclose(cam[:, 2], [-1, 0, 0], atol=1e-9)
    np.testing.assert_allclose(cam[:, 1], [0, 0, 1], atol=1e-9)
    foot_bottom = d.site_xpos[r.foot_site_ids, 2] - r.foot_radius
    if name == "badger":
        # Feet straight below the thigh joints, touching the floor: 2 l cos(a) = h - r.
        np.testing.assert_allclose(foot_bottom, 0.0, atol=2e-4)
        thigh = [m.jnt_bodyid[mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_JOINT, f"{leg}_thigh_joint")] for leg in LEGS]
        np.testing.assert_allclose(d.site_xpos[r.foot_site_ids, :2], d.xpos[thigh, :2], atol=2e-4)
    else:
        # Go2's published stand puts the feet within 2 cm of the floor (it settles on first contact).
        assert np.all(np.abs(foot_bottom) < 0.02)


@pytest.mark.parametrize("name, kp, kd", [("go2", 50.0, 0.5), ("badger", 20.0, 0.5)])
def test_home_stands_with_pd_hold(name, kp, kd):
    """MuJoCo C, 1 s holding `home` with a joint PD: the trunk stays up, level and in place."""
    r = load(name)
    m = r.mj_model
    d = mujoco.MjData(m)
    d.qpos[:] = r.qpos_home
    lo, hi = -r.torque_limit, r.torque_limit
    for _ in range(round(1.0 / m.opt.timestep)):
        tau = kp * (r.q_home - d.qpos[r.qpos_adr]) - kd * d.qvel[r.dof_adr]
        d.ctrl[:] = np.clip(tau, lo, hi)
        mujoco.mj_step(m, d)
    z0 = r.qpos_home[2]
    assert abs(d.qpos[2] - z0) < 0.04, d.qpos[2]
    up = d.xmat[r.base_body_id].reshape(3, 3)[:, 2]
    assert up[2] > np.cos(0.05)
    assert np.linalg.norm(d.qpos[:2]) < 0.05  # the stance sags backward a few cm as it settles
    assert np.linalg.norm(d.qvel[r.base_dof_adr : r.base_dof_adr + 3]) < 0.1
    # Every foot touches the floor; the contact sensors agree with d.contact.
    floor = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_GEOM, "floor")
    geoms = {tuple(sorted(c.geom)) for c in d.contact[: d.ncon]}
    touching = np.array([tuple(sorted((g, floor))) in geoms for g in r.foot_geom_ids])
    assert touching.all()
    found = d.sensordata[r.foot_contact_sensor_adr]
    np.testing.assert_array_equal(found > 0, touching)
    # Sensor normal forces carry the robot's weight (to within the residual motion).
    normal = d.sensordata[r.foot_contact_sensor_adr + 1]
    assert normal.sum() == pytest.approx(r.mass * 9.81, rel=0.05)


def test_load_is_cached():
    assert load("go2") is load("go2")
    assert load("badger") is not load("go2")


def test_user_mjcf_with_foot_geoms(tmp_path):
    path = tmp_path / "tiny.xml"
    path.write_text(_tiny_mjcf())
    r = load(path)
    assert r.name == "tiny" and r.nu == 12 and r.spine_joint is None
    assert r.joint_names[:3] == ("FL_a", "FL_b", "FL_c")
    np.testing.assert_array_equal(r.leg_joints, np.arange(12).reshape(4, 3))
    assert np.all(np.isinf(r.torque_limit))
    # Sites were added at the foot geoms' centres.
    m = r.mj_model
    d = mujoco.MjData(m)
    mujoco.mj_kinematics(m, d)
    np.testing.assert_allclose(d.site_xpos[r.foot_site_ids], d.geom_xpos[r.foot_geom_ids], atol=1e-12)
    np.testing.assert_allclose(r.foot_radius, 0.02)
    assert r.camera_id == -1 and np.all(r.foot_contact_sensor_adr == -1)
    assert m.site_bodyid[r.imu_site_id] == r.base_body_id


def test_user_mjcf_with_foot_names_argument(tmp_path):
    path = tmp_path / "tiny_sites.xml"
    path.write_text(_tiny_mjcf(foot_sites=True).replace('site name="FL_foot"', 'site name="toe0"'))
    r = load(path, foot_names=["toe0", "FR_foot", "RL_foot", "RR_foot"])
    assert r.foot_names[0] == "toe0"
    assert r.mj_model.site(r.foot_site_ids[0]).name == "toe0"


def test_user_urdf(tmp_path):
    path = tmp_path / "tiny.urdf"
    path.write_text(_tiny_urdf())
    r = load(path)
    m = r.mj_model
    assert m.jnt_type[0] == mujoco.mjtJoint.mjJNT_FREE and m.body(r.base_body_id).name == "base"
    assert r.nu == 12 and r.nq == 19 and r.nv == 18
    assert r.joint_names[:3] == ("FL_hip_joint", "FL_thigh_joint", "FL_calf_joint")
    np.testing.assert_allclose(r.torque_limit, 20.0)  # from the URDF effort limits
    # Foot links without <inertial> get MuJoCo's default geom density, 1000 kg/m^3.
    assert r.mass == pytest.approx(5 + 12 * 0.5 + 4 * 1000 * 4 / 3 * np.pi * 0.02**3, rel=1e-6)
    d = mujoco.MjData(m)
    mujoco.mj_kinematics(m, d)
    np.testing.assert_allclose(d.site_xpos[r.foot_site_ids[0]] - d.xpos[r.base_body_id], [0.2, 0.1, -0.4], atol=1e-9)


def test_bad_inputs(tmp_path):
    with pytest.raises(ValueError, match="unknown robot 'spot'"):
        load("spot")
    with pytest.raises(ValueError, match="robot file not found"):
        load(tmp_path / "missing.xml")
    no_free = tmp_path / "no_free.xml"
    no_free.write_text(_tiny_mjcf(free=False))
    with pytest.raises(ValueError, match="no free joint"):
        load(no_free)
    ok = tmp_path / "ok.xml"
    ok.write_text(_tiny_mjcf())
    with pytest.raises(ValueError, match="foot 'paw' not found"):
        load(ok, foot_names=["paw", "FR_foot", "RL_foot", "RR_foot"])
    with pytest.raises(ValueError, match="4 feet"):
        load(ok, foot_names=["FL_foot"])
    broken = tmp_path / "broken.xml"
    broken.write_text("<mujoco><worldbody><body></worldbody></mujoco>")
    with pytest.raises(ValueError, match="cannot parse robot file") as e:
        load(broken)
    assert "\n" not in str(e.value)


@pytest.mark.slow
def test_mjx_sensors_match_mujoco_when_standing():
    """MJX computes the models' contact sensors (found, contact-frame force), gyro and accelerometer
    as MuJoCo C does, at a settled stand with all four feet on the floor."""
    import jax
    from mujoco import mjx

    r = load("go2")
    m = r.mj_model
    d = mujoco.MjData(m)
    d.qpos[:] = r.qpos_home
    for _ in range(100):
        d.ctrl[:] = 50.0 * (r.q_home - d.qpos[r.qpos_adr]) - 0.5 * d.qvel[r.dof_adr]
        mujoco.mj_step(m, d)
    mujoco.mj_forward(m, d)
    dx = jax.jit(mjx.forward)(r.mjx_model, mjx.put_data(m, d))
    found = np.asarray(dx.sensordata)[r.foot_contact_sensor_adr]
    np.testing.assert_array_equal(found, d.sensordata[r.foot_contact_sensor_adr])
    assert np.all(found == 1)
    # MJX runs in float32 and its Newton solver stops after the models' few iterations: not bit-equal to C.
    np.testing.assert_allclose(np.asarray(dx.sensordata), d.sensordata, rtol=0.05, atol=0.5)
