"""Robot structure: the MuJoCo/MJX models of a quadruped and the ids the rest of jaxquad needs."""

from __future__ import annotations

import dataclasses
import functools
import os
from pathlib import Path

import jax
import mujoco
import numpy as np

from jaxquad._mjx import mjx

_XML_DIR = Path(__file__).resolve().parent / "xmls"
BUILTIN_ROBOTS = ("go2", "badger")
LEGS = ("FL", "FR", "RL", "RR")


@dataclasses.dataclass(frozen=True, eq=False)
class Robot:
    """Static structure of one quadruped model (hashable by identity: usable as a jit static arg).

    "Actuated joints" are the joints driven by the model's actuators, in actuator order: joint i is
    driven by ``ctrl[i]`` (torque, N m, gear 1). Feet are in ``foot_names`` order (FL, FR, RL, RR by
    default). Integer ids index the MuJoCo model; -1 marks an absent optional item.
    """

    name: str
    path: str
    joint_names: tuple[str, ...]  # actuated joints, in actuator order
    foot_names: tuple[str, ...]  # foot sites, in leg order
    leg_joints: np.ndarray  # (4, 3) int: per leg, indices into joint_names, from hip to foot
    spine_joint: str | None  # the actuated joint shared by a leg pair (badger), else None
    mj_model: mujoco.MjModel
    mjx_model: mjx.Model
    base_body_id: int  # body carrying the free joint
    base_qpos_adr: int  # free joint: qpos[adr:adr+3] position (m), qpos[adr+3:adr+7] quat (w, x, y, z)
    base_dof_adr: int  # free joint: qvel[adr:adr+3] linear (world), qvel[adr+3:adr+6] angular (body)
    foot_site_ids: np.ndarray  # (4,) int
    foot_geom_ids: np.ndarray  # (4,) int: the colliding geom of each foot
    foot_radius: np.ndarray  # (4,) float, m: radius of the foot geom (0 if not a sphere)
    foot_contact_sensor_adr: np.ndarray  # (4,) int: sensordata address of each foot's contact sensor, -1 if none
    imu_site_id: int
    camera_id: int  # the depth camera, -1 if the model has none
    qpos_adr: np.ndarray  # (nu,) int: qpos address of each actuated joint
    dof_adr: np.ndarray  # (nu,) int: qvel/dof address of each actuated joint
    joint_range: np.ndarray  # (nu, 2) float, rad: position limits (-inf, inf if unlimited)
    torque_limit: np.ndarray  # (nu,) float, N m: |ctrl| limit (inf if unlimited)
    q_home: np.ndarray  # (nu,) float, rad: actuated joint angles of the `home` keyframe (else qpos0)
    qpos_home: np.ndarray  # (nq,) float: full home configuration
    nq: int
    nv: int
    nu: int
    mass: float  # kg, total


def load(
    name_or_path: str | os.PathLike,
    *,
    foot_names: tuple[str, ...] | list[str] | None = None,
    imu_site: str = "imu",
    camera: str = "depth",
) -> Robot:
    """Load a built-in robot ("go2", "badger") or a user's MJCF/URDF file.

    Feet are found by name (default ``FL_foot, FR_foot, RL_foot, RR_foot``) as a site, else a body
    (a site is added at its first sphere geom, else its origin), else a geom (a site is added at its
    centre). A URDF gets a free joint on its root link (URDF cannot express a floating base); a model
    without actuators gets one torque motor per hinge/slide joint. A missing IMU site is added at the
    base body origin. Results are cached: loading the same file twice returns the same object.
    """
    key = str(name_or_path)
    if key in BUILTIN_ROBOTS:
        path = _XML_DIR / f"{key}.xml"
    else:
        path = Path(key).expanduser()
        if path.suffix.lower() not in (".xml", ".urdf", ".mjcf"):
            raise ValueError(
                f"unknown robot {key!r}: expected one of {', '.join(BUILTIN_ROBOTS)} or a path to an .xml/.urdf file"
            )
        if not path.is_file():
            raise ValueError(f"robot file not found: {path}")
        path = path.resolve()
    feet = tuple(f"{leg}_foot" for leg in LEGS) if foot_names is None else tuple(foot_names)
    if len(feet) != 4:
        raise ValueError(f"foot_names must name 4 feet, got {len(feet)}: {feet}")
    return _load_cached(str(path), path.stat().st_mtime_ns, feet, imu_site, camera)


@functools.lru_cache(maxsize=16)
def _load_cached(path: str, mtime_ns: int, feet: tuple[str, ...], imu_site: str, camera: str) -> Robot:
    del mtime_ns  # part of the cache key only: an edited file is reloaded
    is_urdf = Path(path).suffix.lower() == ".urdf" or _root_tag(path) == "robot"
    try:
        spec = mujoco.MjSpec.from_file(path)
    except ValueError as e:
        raise ValueError(f"cannot parse robot file {path}: {_first_line(e)}") from None
    if is_urdf:
        # Keep fixed-joint links (feet) as bodies, and float the root link.
        spec.compiler.fusestatic = False
        root = spec.worldbody.first_body()
        if root is not None and root.first_joint() is None:
            root.add_freejoint(name="root")
    m0 = _compile(spec, path)

    free = np.nonzero(m0.jnt_type == mujoco.mjtJoint.mjJNT_FREE)[0]
    if free.size != 1:
        what = "no free joint (floating base)" if free.size == 0 else f"{free.size} free joints"
        raise ValueError(f"robot model {path} has {what}")
    base_body = int(m0.jnt_bodyid[free[0]])

    for foot in feet:
        _ensure_foot_site(spec, m0, foot, path)
    if mujoco.mj_name2id(m0, mujoco.mjtObj.mjOBJ_SITE, imu_site) < 0:
        spec.body(m0.body(base_body).name).add_site(name=imu_site)
    if m0.nu == 0:
        for j in range(m0.njnt):
            if m0.jnt_type[j] in (int(mujoco.mjtJoint.mjJNT_HINGE), int(mujoco.mjtJoint.mjJNT_SLIDE)):
                lim = m0.jnt_actfrcrange[j] if m0.jnt_actfrclimited[j] else None
                act = spec.add_actuator(name=m0.joint(j).name, target=m0.joint(j).name)
                act.trntype = mujoco.mjtTrn.mjTRN_JOINT
                act.set_to_motor()
                if lim is not None:
                    act.ctrllimited = True
                    act.ctrlrange = lim
    m = _compile(spec, path)
    return _structure(m, path, feet, imu_site, camera, base_body)


def _structure(
    m: mujoco.MjModel, path: str, feet: tuple[str, ...], imu_site: str, camera: str, base_body: int
) -> Robot:
    if np.any(m.actuator_trntype != mujoco.mjtTrn.mjTRN_JOINT):
        raise ValueError(f"robot model {path}: every actuator must drive a joint directly")
    jnt = m.actuator_trnid[:, 0].astype(int)
    if len(set(jnt.tolist())) != m.nu:
        raise ValueError(f"robot model {path}: a joint is driven by more than one actuator")
    if np.any((m.jnt_type[jnt] != mujoco.mjtJoint.mjJNT_HINGE) & (m.jnt_type[jnt] != mujoco.mjtJoint.mjJNT_SLIDE)):
        raise ValueError(f"robot model {path}: actuated joints must be hinge or slide joints")
    joint_names = tuple(m.joint(j).name for j in jnt)
    pos_of_joint = {int(j): i for i, j in enumerate(jnt)}

    site_ids = np.array([mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_SITE, f) for f in feet])
    # Actuated joints on each foot's path to the base, hip first.
    chains = []
    for s in site_ids:
        chain, b = [], int(m.site_bodyid[s])
        while b != base_body:
            if b == 0:
                raise ValueError(f"robot model {path}: foot site {m.site(s).name!r} is not below the base body")
            for j in range(m.body_jntadr[b], m.body_jntadr[b] + m.body_jntnum[b]):
                if j in pos_of_joint:
                    chain.append(pos_of_joint[j])
            b = int(m.body_parentid[b])
        chains.append(chain[::-1])
    counts = {}
    for c in chains:
        for j in c:
            counts[j] = counts.get(j, 0) + 1
    legs = [[j for j in c if counts[j] == 1] for c in chains]
    for f, leg in zip(feet, legs):
        if len(leg) != 3:
            raise ValueError(f"robot model {path}: foot {f!r} has {len(leg)} leg joints, expected 3")
    others = [i for i in range(m.nu) if not any(i in leg for leg in legs)]
    if len(others) > 1:
        names = ", ".join(joint_names[i] for i in others)
        raise ValueError(f"robot model {path}: more than one actuated non-leg joint ({names})")

    geom_ids, radii = [], []
    for f, s in zip(feet, site_ids):
        g = _foot_geom(m, int(s))
        if g < 0:
            raise ValueError(f"robot model {path}: foot {f!r} has no colliding geom on its body")
        geom_ids.append(g)
        radii.append(float(m.geom_size[g, 0]) if m.geom_type[g] == mujoco.mjtGeom.mjGEOM_SPHERE else 0.0)

    sensor_adr = np.full(4, -1)
    contact = np.nonzero(m.sensor_type == mujoco.mjtSensor.mjSENS_CONTACT)[0]
    for i, g in enumerate(geom_ids):
        own = [k for k in contact if m.sensor_objtype[k] == mujoco.mjtObj.mjOBJ_GEOM and m.sensor_objid[k] == g]
        if own:
            sensor_adr[i] = m.sensor_adr[own[0]]

    key = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_KEY, "home")
    qpos_home = (m.key_qpos[key] if key >= 0 else m.qpos0).copy()
    qpos_adr = m.jnt_qposadr[jnt].astype(int)
    limited = m.jnt_limited[jnt].astype(bool)
    joint_range = np.where(limited[:, None], m.jnt_range[jnt], np.array([-np.inf, np.inf]))
    ctrl_limited = m.actuator_ctrllimited.astype(bool)
    torque_limit = np.where(ctrl_limited, np.abs(m.actuator_ctrlrange).max(axis=1), np.inf)
    free = int(m.body_jntadr[base_body])
    try:
        # This process's first device: MJX's default, jax.devices()[0], belongs to process 0 in a
        # multi-process run.
        mjx_model = mjx.put_model(m, device=jax.local_devices()[0])
    except NotImplementedError as e:
        raise ValueError(f"robot model {path} is not supported by MJX: {_first_line(e)}") from None

    return Robot(
        name=Path(path).stem,
        path=path,
        joint_names=joint_names,
        foot_names=feet,
        leg_joints=_frozen(np.array(legs, dtype=np.int32)),
        spine_joint=joint_names[others[0]] if others else None,
        mj_model=m,
        mjx_model=mjx_model,
        base_body_id=base_body,
        base_qpos_adr=int(m.jnt_qposadr[free]),
        base_dof_adr=int(m.jnt_dofadr[free]),
        foot_site_ids=_frozen(site_ids.astype(np.int32)),
        foot_geom_ids=_frozen(np.array(geom_ids, np.int32)),
        foot_radius=_frozen(np.array(radii)),
        foot_contact_sensor_adr=_frozen(sensor_adr.astype(np.int32)),
        imu_site_id=mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_SITE, imu_site),
        camera_id=mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_CAMERA, camera),
        # Index arrays in int32, JAX's index type: int64 arrays do not index under strict promotion.
        qpos_adr=_frozen(qpos_adr.astype(np.int32)),
        dof_adr=_frozen(m.jnt_dofadr[jnt].astype(np.int32)),
        joint_range=_frozen(joint_range),
        torque_limit=_frozen(torque_limit),
        q_home=_frozen(qpos_home[qpos_adr]),
        qpos_home=_frozen(qpos_home),
        nq=int(m.nq),
        nv=int(m.nv),
        nu=int(m.nu),
        mass=float(m.body_subtreemass[0]),
    )


def _ensure_foot_site(spec: mujoco.MjSpec, m: mujoco.MjModel, foot: str, path: str) -> None:
    """Make sure a site named `foot` exists, adding one at the foot body's/geom's centre if needed."""
    if mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_SITE, foot) >= 0:
        return
    body = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_BODY, foot)
    if body >= 0:
        spheres = [
            g
            for g in range(m.body_geomadr[body], m.body_geomadr[body] + m.body_geomnum[body])
            if m.geom_type[g] == mujoco.mjtGeom.mjGEOM_SPHERE
        ]
        pos = m.geom_pos[spheres[0]] if spheres else np.zeros(3)
        spec.body(foot).add_site(name=foot, pos=pos)
        return
    geom = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_GEOM, foot)
    if geom >= 0:
        spec.body(m.body(m.geom_bodyid[geom]).name).add_site(name=foot, pos=m.geom_pos[geom])
        return
    raise ValueError(f"robot model {path}: foot {foot!r} not found as a site, body or geom")


def _foot_geom(m: mujoco.MjModel, site: int) -> int:
    """The colliding geom on the foot site's body nearest to the site, or -1."""
    body = int(m.site_bodyid[site])
    geoms = [
        g
        for g in range(m.body_geomadr[body], m.body_geomadr[body] + m.body_geomnum[body])
        if m.geom_contype[g] or m.geom_conaffinity[g]
    ]
    if not geoms:
        return -1
    dist = [np.linalg.norm(m.geom_pos[g] - m.site_pos[site]) for g in geoms]
    return int(geoms[int(np.argmin(dist))])


def _compile(spec: mujoco.MjSpec, path: str) -> mujoco.MjModel:
    try:
        return spec.compile()
    except ValueError as e:
        raise ValueError(f"cannot compile robot file {path}: {_first_line(e)}") from None


def _root_tag(path: str) -> str:
    with open(path, "rb") as f:
        head = f.read(4096).decode("utf-8", "replace")
    for token in head.split("<")[1:]:
        if token[:1] not in ("?", "!"):
            return token.split(None, 1)[0].rstrip(">/")
    return ""


def _first_line(e: Exception) -> str:
    lines = [ln.strip() for ln in str(e).splitlines() if ln.strip()]
    return "; ".join(lines[:2]) if lines else type(e).__name__


def _frozen(a: np.ndarray) -> np.ndarray:
    a.setflags(write=False)
    return a
