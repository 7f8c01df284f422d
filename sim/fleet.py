"""Batched fleet runner: N robots walking route loops in generated worlds, with all sensors.

Rates: physics at the robot model's timestep (0.004 s for the built-in robots); the controller
and route follower run every physics step; IMU, encoders, torques and ground truth are logged
every `log_every` physics steps (default 1: 250 Hz); the depth camera renders every
`camera_every` physics steps (default: nearest to 30 Hz, i.e. 8 steps = 31.25 Hz at 0.004 s).

Time is split into chunks of `frames_per_chunk` camera periods. One chunk is a nested
`lax.scan` (frames -> log samples -> physics steps), jitted once for the whole fleet under
`jax.vmap`, so depth is cast only on camera frames and device memory holds one chunk at a time;
the host streams each chunk to disk.

Per-robot variation is a vmapped `mjx.Model` with an explicit `in_axes` tree (`model_in_axes`):
body masses and inertias (x U(0.9, 1.1)), sliding friction of every geom (U(0.5, 1.2)) and motor
strength (actuator gear x U(0.9, 1.1); the torque sensor still reports the commanded actuator
force), plus per-robot sensor noise levels (`SensorNoise` x U(0.5, 1.5)). A robot whose base
drops below half its stance height, tilts past 60 deg, or whose state turns non-finite is flagged
`fallen` and frozen (its state no longer advances) while the others go on. World boxes are not in
the physics model (see `jaxquad.sim.worlds`); a base entering a box footprint is flagged too.

Ground truth of the feet: `gt_force` (T, 4, 3) is the force of the floor (every contact of the
foot geom) on each foot, world frame, N: the constraint solver's contact forces, which are the
forces that moved the robot because the built-in models let the solver converge (see their
`<option>`; a one-iteration solver reports forces inconsistent with the motion). `gt_contact`
(T, 4) is load-bearing contact: the foot's total normal force exceeds `GT_CONTACT_MIN_FORCE`
(1 N). Geometric touch (penetration of the foot sphere) outlasts it by a few samples at lift-off,
when the soft contact is still compressed but no longer pushes.
"""

from __future__ import annotations

import dataclasses
import math

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Bool, Float, Int, PRNGKeyArray

from jaxquad.kernels.lie import yaw_of
from jaxquad.kernels.raycast import Boxes, cast_depth, pinhole_rays

from . import sensors as S
from .locomotion import Gait, GaitParams, GaitState, gait_init, gait_step
from .route_follow import RouteParams, RouteState, route_init, route_step
from .routes import plan_loop
from .worlds import World, make_world

_MAX_TILT_COS = 0.5  # cos(60 deg)
GT_CONTACT_MIN_FORCE = 1.0  # N: normal force above which a foot counts as in contact (0.7% of go2's weight)
# MuJoCo cameras look along -z with +y up; the optical frame looks along +z with +y down.
_R_MJCAM_OPTICAL = np.diag([1.0, -1.0, -1.0])


@dataclasses.dataclass(frozen=True)
class FleetConfig:
    robot: str = "go2"
    world: str = "house"
    n_robots: int = 4
    n_worlds: int = 1  # distinct worlds; robot i walks world i % n_worlds
    style: str = "calm"  # or "aggressive"
    seed: int = 0
    depth: bool = True
    width: int = 160
    height: int = 120
    camera_hz: float = 30.0
    log_every: int = 1  # physics steps per log sample
    frames_per_chunk: int = 30  # camera periods per chunk (~1 s)
    randomize: bool = True
    n_waypoints: int = 96

    def __post_init__(self):
        if self.style not in ("calm", "aggressive"):
            raise ValueError(f"unknown style {self.style!r}; choose calm or aggressive")
        for name in ("n_robots", "n_worlds", "width", "height", "log_every", "frames_per_chunk"):
            if int(getattr(self, name)) < 1:
                raise ValueError(f"{name} must be >= 1, got {getattr(self, name)}")


class RobotState(eqx.Module):
    """State of one robot between physics steps."""

    data: object  # mjx.Data
    gait: GaitState
    route: RouteState
    imu: S.ImuState
    key: PRNGKeyArray
    t: Float[Array, ""]  # s
    fallen: Bool[Array, ""]
    collided: Bool[Array, ""]
    fall_step: Int[Array, ""]  # physics step of the fall, -1 while upright


class RobotSetup(eqx.Module):
    """Per-robot constants of a run (vmapped with the state)."""

    gait_params: GaitParams
    route_params: RouteParams
    noise: S.SensorNoise
    waypoints: Float[Array, "K 2"]
    boxes: Boxes


@dataclasses.dataclass
class Fleet:
    """Everything static about a fleet run; `init()` and `chunk()` are the jitted entry points."""

    config: FleetConfig
    robot: object
    gait: Gait
    worlds: list[World]
    model: object  # batched mjx.Model
    model_in_axes: object
    setup: RobotSetup
    rays: np.ndarray  # (H, W, 3)
    K: np.ndarray
    T_base_camera: np.ndarray
    dt: float
    camera_every: int
    logs_per_frame: int
    _init: object = None
    _chunk: object = None

    @property
    def log_dt(self) -> float:
        return self.dt * self.config.log_every

    @property
    def frame_dt(self) -> float:
        return self.dt * self.camera_every

    @property
    def samples_per_chunk(self) -> int:
        return self.logs_per_frame * self.config.frames_per_chunk


def _world_start(waypoints: np.ndarray, rng: np.random.Generator) -> tuple[np.ndarray, float]:
    i = int(rng.integers(len(waypoints)))
    a, b = waypoints[i], waypoints[(i + 1) % len(waypoints)]
    return a, float(np.arctan2(b[1] - a[1], b[0] - a[0]))


def _sensor_addr(m, sensor_type, site: int) -> int:
    for i in range(m.nsensor):
        if m.sensor_type[i] == sensor_type and m.sensor_objid[i] == site:
            return int(m.sensor_adr[i])
    raise ValueError(f"robot model needs a {sensor_type.name} sensor on its IMU site")


def build_fleet(config: FleetConfig) -> Fleet:
    """Load the robot, generate worlds and routes, draw per-robot variation (NumPy, seeded)."""
    import mujoco

    from jaxquad import robots

    robot = robots.load(config.robot)
    gait = Gait.for_robot(robot)
    m = robot.mj_model
    dt = float(m.opt.timestep)
    if config.depth and robot.camera_id < 0:
        raise ValueError(f"robot {config.robot!r} has no camera named 'depth'")
    camera_every = max(1, round(1.0 / (config.camera_hz * dt) / config.log_every)) * config.log_every
    n = config.n_robots
    rng = np.random.default_rng([config.seed, 7])
    worlds = [make_world(config.world, config.seed * 1000 + w) for w in range(config.n_worlds)]
    loops = [plan_loop(w, n_waypoints=config.n_waypoints) for w in worlds]
    which = np.arange(n) % config.n_worlds

    # Initial base poses: on a random waypoint of the robot's loop, facing along the route.
    qpos0 = np.tile(robot.qpos_home, (n, 1))
    for i in range(n):
        xy, yaw = _world_start(loops[which[i]], rng)
        a = robot.base_qpos_adr
        qpos0[i, a : a + 2] = xy
        qpos0[i, a + 3 : a + 7] = [np.cos(yaw / 2), 0.0, 0.0, np.sin(yaw / 2)]

    model = robot.mjx_model
    scale = lambda lo, hi, shape: rng.uniform(lo, hi, shape) if config.randomize else np.ones(shape)  # noqa: E731
    mass_scale = scale(0.9, 1.1, (n, m.nbody))
    friction = np.repeat(np.asarray(m.geom_friction)[None], n, 0)
    friction[..., 0] = scale(0.5, 1.2, (n, 1)) if config.randomize else friction[..., 0]
    gear = np.asarray(m.actuator_gear)[None] * np.ones((n, 1, 1))
    gear[..., 0] *= scale(0.9, 1.1, (n, m.nu))
    batched = {
        "body_mass": jnp.asarray(np.asarray(m.body_mass)[None] * mass_scale, jnp.float32),
        "body_inertia": jnp.asarray(np.asarray(m.body_inertia)[None] * mass_scale[..., None], jnp.float32),
        "geom_friction": jnp.asarray(friction, jnp.float32),
        "actuator_gear": jnp.asarray(gear, jnp.float32),
    }
    model = model.tree_replace(batched)
    in_axes = jax.tree_util.tree_map(lambda _: None, robot.mjx_model)
    in_axes = in_axes.tree_replace({k: 0 for k in batched})

    params = GaitParams.calm(gait) if config.style == "calm" else GaitParams.aggressive(gait)
    v_route = 0.4 if config.style == "calm" else 0.8
    stack = lambda tree: jax.tree_util.tree_map(lambda x: jnp.broadcast_to(x, (n,) + jnp.shape(x)), tree)  # noqa: E731
    noise = stack(S.SensorNoise.default())
    if config.randomize:
        noise = jax.vmap(S.SensorNoise.scaled)(noise, jnp.asarray(rng.uniform(0.5, 1.5, n), jnp.float32))
    boxes = Boxes(
        center=jnp.asarray(np.stack([worlds[w].center for w in which])),
        half=jnp.asarray(np.stack([worlds[w].half for w in which])),
        yaw=jnp.asarray(np.stack([worlds[w].yaw for w in which])),
    )
    setup = RobotSetup(
        gait_params=stack(params),
        route_params=stack(RouteParams.default(v_route)),
        noise=noise,
        waypoints=jnp.asarray(np.stack([loops[w] for w in which]), jnp.float32),
        boxes=boxes,
    )
    K = S.intrinsics(config.width, config.height)
    # Camera pose in the base body (static: the camera hangs on the base body of both robots).
    cam_body = int(m.cam_bodyid[robot.camera_id]) if robot.camera_id >= 0 else robot.base_body_id
    if config.depth and cam_body != robot.base_body_id:
        raise ValueError("the depth camera must be mounted on the base body")
    T_base_camera = np.eye(4)
    if robot.camera_id >= 0:
        R = np.zeros(9)
        mujoco.mju_quat2Mat(R, m.cam_quat[robot.camera_id])
        T_base_camera[:3, :3] = R.reshape(3, 3) @ _R_MJCAM_OPTICAL
        T_base_camera[:3, 3] = m.cam_pos[robot.camera_id]

    fleet = Fleet(
        config=config,
        robot=robot,
        gait=gait,
        worlds=worlds,
        model=model,
        model_in_axes=in_axes,
        setup=setup,
        rays=pinhole_rays(K, config.height, config.width),
        K=K,
        T_base_camera=T_base_camera,
        dt=dt,
        camera_every=camera_every,
        logs_per_frame=camera_every // config.log_every,
    )
    gyro_adr = _sensor_addr(m, mujoco.mjtSensor.mjSENS_GYRO, robot.imu_site_id)
    acc_adr = _sensor_addr(m, mujoco.mjtSensor.mjSENS_ACCELEROMETER, robot.imu_site_id)
    fleet._init, fleet._chunk = _bind(fleet, jnp.asarray(qpos0, jnp.float32), gyro_adr, acc_adr)
    return fleet


def _make_functions(fleet: Fleet, gyro_adr: int, acc_adr: int):
    from mujoco import mjx
    from mujoco.mjx._src.support import contact_force  # not re-exported by mjx

    robot, gait, cfg = fleet.robot, fleet.gait, fleet.config
    dt = jnp.float32(fleet.dt)
    qa, da = robot.base_qpos_adr, robot.base_dof_adr
    qpos_adr, dof_adr = np.asarray(robot.qpos_adr), np.asarray(robot.dof_adr)
    foot_geoms = jnp.asarray(robot.foot_geom_ids)
    min_height = 0.5 * float(gait.body_height)
    rays = jnp.asarray(fleet.rays)
    cam_id = robot.camera_id

    def init_one(model, setup: RobotSetup, qpos, key) -> RobotState:
        # Derived quantities (sensors, camera pose) are filled by the first physics step.
        data = mjx.make_data(model).replace(qpos=qpos)
        k_imu, key = jax.random.split(key)
        return RobotState(
            data=data,
            gait=gait_init(gait, setup.gait_params),
            route=route_init(setup.waypoints, qpos[qa : qa + 2]),
            imu=S.imu_init(setup.noise, k_imu),
            key=key,
            t=jnp.zeros(()),
            fallen=jnp.zeros((), bool),
            collided=jnp.zeros((), bool),
            fall_step=jnp.full((), -1, jnp.int32),
        )

    def physics_step(model, setup: RobotSetup, s: RobotState) -> RobotState:
        d = s.data
        quat = d.qpos[qa + 3 : qa + 7]
        yaw = yaw_of(quat)
        pose = jnp.stack([d.qpos[qa], d.qpos[qa + 1], yaw])
        cmd, route, _ = route_step(setup.route_params, s.route, setup.waypoints, pose)
        tau, g = gait_step(gait, setup.gait_params, s.gait, d.qpos, d.qvel, cmd, s.t, dt)
        d_new = mjx.step(model, d.replace(ctrl=tau))
        w, x, y, _ = d_new.qpos[qa + 3 : qa + 7]
        up_z = 1 - 2 * (x * x + y * y)  # world z of the base's z axis
        finite = jnp.all(jnp.isfinite(d_new.qpos)) & jnp.all(jnp.isfinite(d_new.qvel))
        down = ~finite | (d_new.qpos[qa + 2] < min_height) | (up_z < _MAX_TILT_COS)
        fallen = s.fallen | down
        # Freeze a fallen robot: keep its last valid state (a non-finite one never enters).
        keep = lambda old, new: jnp.where(fallen, old, new)  # noqa: E731
        step_no = jnp.round(s.t / dt).astype(jnp.int32)
        return RobotState(
            data=jax.tree_util.tree_map(keep, d, d_new),
            gait=jax.tree_util.tree_map(keep, s.gait, g),
            route=jax.tree_util.tree_map(keep, s.route, route),
            imu=s.imu,
            key=s.key,
            t=s.t + dt,
            fallen=fallen,
            collided=s.collided,
            fall_step=jnp.where(down & ~s.fallen, step_no + 1, s.fall_step),
        )

    def sample(model, setup: RobotSetup, s: RobotState) -> tuple[RobotState, dict]:
        d = s.data
        key, k_imu, k_enc, k_tau = jax.random.split(s.key, 4)
        quat = d.qpos[qa + 3 : qa + 7]
        gyro, acc, quat_meas, imu = S.imu_step(
            setup.noise, s.imu, k_imu, d.sensordata[gyro_adr : gyro_adr + 3], d.sensordata[acc_adr : acc_adr + 3], quat, fleet.log_dt
        )
        q, qd = S.encoders(setup.noise, k_enc, d.qpos[qpos_adr], d.qvel[dof_adr])
        tau = S.joint_torque(setup.noise, k_tau, d.actuator_force)
        # Force of each contact in its frame (normal first; the normal points from geom 0 to geom 1)
        # and in the world frame; summed per foot with the sign of the force on the foot geom.
        con = d._impl.contact
        f_con = jnp.stack([contact_force(model, d, i)[:3] for i in range(con.geom.shape[0])])
        f_world = jnp.einsum("ci,cij->cj", f_con, con.frame)
        sign = jnp.where(con.geom[:, 1:2] == foot_geoms[None], 1.0, 0.0) - jnp.where(con.geom[:, 0:1] == foot_geoms[None], 1.0, 0.0)
        gt_force = jnp.einsum("cf,cj->fj", sign, f_world)
        contact = jnp.abs(sign).T @ f_con[:, 0] > GT_CONTACT_MIN_FORCE
        xy = d.qpos[qa : qa + 2]
        inside = _inside_any_box(setup.boxes, xy)
        s = eqx.tree_at(lambda r: (r.imu, r.key, r.collided), s, (imu, key, s.collided | inside))
        out = dict(
            q=q, qd=qd, tau=tau, gyro=gyro, acc=acc, quat_wxyz=quat_meas,
            gt_pose=jnp.concatenate([d.qpos[qa : qa + 3], quat]),
            gt_contact=contact, gt_force=gt_force, valid=~s.fallen,
        )  # fmt: skip
        return s, out

    def frame(model, setup: RobotSetup, s: RobotState):
        def log_period(s, _):
            s = jax.lax.fori_loop(0, cfg.log_every, lambda _, s: physics_step(model, setup, s), s)
            return sample(model, setup, s)

        s, outs = jax.lax.scan(log_period, s, None, length=fleet.logs_per_frame)
        if not cfg.depth:
            return s, outs
        d = s.data
        R_world_cam = d.cam_xmat[cam_id] @ jnp.asarray(_R_MJCAM_OPTICAL, jnp.float32)
        depth_true = cast_depth(d.cam_xpos[cam_id], R_world_cam, rays, setup.boxes)
        key, k_depth = jax.random.split(s.key)
        depth = S.depth_camera(setup.noise, k_depth, depth_true, rays)
        s = eqx.tree_at(lambda r: r.key, s, key)
        return s, (outs, depth)

    def chunk_one(model, setup: RobotSetup, s: RobotState):
        s, outs = jax.lax.scan(lambda s, _: frame(model, setup, s), s, None, length=cfg.frames_per_chunk)
        if cfg.depth:
            outs, depth = outs
            outs = dict(outs, depth=depth)
        # (frames, logs_per_frame, ...) -> (samples, ...)
        outs = {k: (v if k == "depth" else v.reshape((-1,) + v.shape[2:])) for k, v in outs.items()}
        return s, outs

    init = jax.jit(jax.vmap(init_one, in_axes=(fleet.model_in_axes, 0, 0, 0)))
    chunk = jax.jit(jax.vmap(chunk_one, in_axes=(fleet.model_in_axes, 0, 0)), donate_argnums=(2,))
    return init, chunk


# Jitted functions per static structure, so fleets differing only in seeds, sizes, styles or
# randomization reuse one compilation (everything else enters as arguments).
_COMPILED: dict = {}


def _bind(fleet: Fleet, qpos0: Array, gyro_adr: int, acc_adr: int):
    cfg = fleet.config
    key = (dataclasses.replace(cfg, seed=0, n_robots=1, n_worlds=1, style="calm", randomize=True), gyro_adr, acc_adr)
    if key not in _COMPILED:
        _COMPILED[key] = _make_functions(fleet, gyro_adr, acc_adr)
    init, chunk = _COMPILED[key]
    keys = jax.random.split(jax.random.key(cfg.seed), cfg.n_robots)
    return (lambda: init(fleet.model, fleet.setup, qpos0, keys)), (lambda s: chunk(fleet.model, fleet.setup, s))


def _inside_any_box(boxes: Boxes, xy: Float[Array, " 2"]) -> Bool[Array, ""]:
    p = xy - boxes.center[:, :2]
    c, s = jnp.cos(boxes.yaw), jnp.sin(boxes.yaw)
    lx, ly = c * p[:, 0] + s * p[:, 1], -s * p[:, 0] + c * p[:, 1]
    return jnp.any((jnp.abs(lx) < boxes.half[:, 0]) & (jnp.abs(ly) < boxes.half[:, 1]))


def init(fleet: Fleet) -> RobotState:
    """Batched initial state (leading axis N)."""
    return fleet._init()


def run_chunk(fleet: Fleet, state: RobotState) -> tuple[RobotState, dict[str, Array]]:
    """Advance every robot by one chunk; returns the new state (the old one is donated) and the
    chunk's samples: per-robot arrays (N, samples_per_chunk, ...) and `depth` (N, frames, H, W)."""
    return fleet._chunk(state)


def n_chunks(fleet: Fleet, seconds: float) -> int:
    return max(1, math.ceil(seconds / (fleet.frame_dt * fleet.config.frames_per_chunk) - 1e-9))
