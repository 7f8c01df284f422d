"""Batched fleet runner: N robots walking route loops in generated worlds, with all sensors.

Rates: physics at the robot model's timestep (0.004 s for the built-in robots); the controller
and route follower run every physics step; IMU, encoders, torques and ground truth are logged
every `log_every` physics steps (default 1: 250 Hz); the depth camera renders every
`camera_every` physics steps (default: nearest to 30 Hz, i.e. 8 steps = 31.25 Hz at 0.004 s).

Time is split into chunks of `frames_per_chunk` camera periods. One chunk is a nested
`lax.scan` (frames -> log samples -> physics steps), compiled once for the whole fleet under
`jax.vmap`, so depth is cast only on camera frames and device memory holds one chunk at a time.
The chunk length is chosen from the device's free memory and the chunk's footprint as XLA reports
it (`jaxquad.sim.memory`), or an explicit length is checked, before anything is allocated: a fleet
that cannot fit raises one line naming the largest robot count that fits. The robots are split over
`config.devices` devices (default all; `jaxquad.parallel`): each device runs the chunk on its own
block of robots (padded to a multiple of the device count with copies of the last robot), and the
memory plan is made per device.

The per-robot functions (`Fleet.functions`: init, physics step, log sample, camera frame, chunk)
are pure and single-robot; closed-loop work drives the same physics step with its own commands.

Per-robot variation is a vmapped `mjx.Model` with an explicit `in_axes` tree (`model_in_axes`):
body masses and inertias (x U(0.9, 1.1)), sliding friction of every geom (U(0.5, 1.2)) and motor
strength (actuator gear x U(0.9, 1.1); the torque sensor still reports the commanded actuator
force), plus per-robot sensor noise levels (`SensorNoise` x U(0.5, 1.5)). A robot whose base
drops below half its stance height, tilts past 60 deg, or whose state turns non-finite is flagged
`fallen` and frozen (its state no longer advances) while the others go on. World boxes are not in
the physics model (see `jaxquad.sim.worlds`); a base entering a box footprint is flagged too.
"""

from __future__ import annotations

import dataclasses
import functools
import math

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array

from jaxquad import parallel
from jaxquad.kernels.raycast import Boxes, pinhole_rays

from . import memory
from . import sensors as S
from .robot_step import _R_MJCAM_OPTICAL, GT_CONTACT_MIN_FORCE, FleetFunctions, RobotSetup, RobotState, make_functions

__all__ = [
    "GT_CONTACT_MIN_FORCE",
    "MAX_FRAMES_PER_CHUNK",
    "Fleet",
    "FleetConfig",
    "FleetFunctions",
    "RobotSetup",
    "RobotState",
    "build_fleet",
    "init",
    "n_chunks",
    "run_chunk",
]
from .gait_structure import Gait
from .locomotion import GaitParams
from .route_follow import RouteParams
from .routes import plan_loop
from .worlds import World, make_world

MAX_FRAMES_PER_CHUNK = 30  # camera periods per chunk when memory allows (~1 s)
NOISE_SCALE = (0.5, 1.5)  # randomized fleets: each robot's noise levels times a uniform draw from this range


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
    frames_per_chunk: int | None = None  # camera periods per chunk; None: sized from free memory (<= 30)
    randomize: bool = True
    n_waypoints: int = 96
    devices: int | None = None  # devices the robots are split over (`jaxquad.parallel.mesh`); None: all

    def __post_init__(self):
        if self.style not in ("calm", "aggressive"):
            raise ValueError(f"unknown style {self.style!r}; choose calm or aggressive")
        for name in ("n_robots", "n_worlds", "width", "height", "log_every", "frames_per_chunk", "devices"):
            if getattr(self, name) is not None and int(getattr(self, name)) < 1:
                raise ValueError(f"{name} must be >= 1, got {getattr(self, name)}")


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
    frames_per_chunk: int = 0  # resolved chunk length (camera frames)
    functions: FleetFunctions | None = None
    chunk_bytes: int = 0  # device memory one chunk call holds on each device (XLA's analysis)
    mesh: object = None  # jax.sharding.Mesh the robot axis is split over
    n_batch: int = 0  # robots on the devices: n_robots rounded up to a multiple of the device count
    _structure: object = None
    _placed: tuple = ()  # (model, setup) padded to n_batch robots and split over the mesh
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
        return self.logs_per_frame * self.frames_per_chunk


def _world_start(waypoints: np.ndarray, rng: np.random.Generator) -> tuple[np.ndarray, float]:
    i = int(rng.integers(len(waypoints)))
    a, b = waypoints[i], waypoints[(i + 1) % len(waypoints)]
    return a, float(np.arctan2(b[1] - a[1], b[0] - a[0]))


def _sensor_addr(m, sensor_type, site: int) -> int:
    for i in range(m.nsensor):
        if m.sensor_type[i] == sensor_type and m.sensor_objid[i] == site:
            return int(m.sensor_adr[i])
    raise ValueError(f"robot model needs a {sensor_type.name} sensor on its IMU site")


def build_fleet(config: FleetConfig, compile_chunk: bool = True) -> Fleet:
    """Load the robot, generate worlds and routes, draw per-robot variation (NumPy, seeded).

    compile_chunk=False leaves out the open-loop chunk (no memory plan, no compile): only the pure
    per-robot functions are attached, for callers that drive them in their own loop."""
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
        noise = jax.vmap(S.SensorNoise.scaled)(noise, jnp.asarray(rng.uniform(*NOISE_SCALE, n), jnp.float32))
    boxes = jax.vmap(Boxes)(  # one world per robot
        center=jnp.asarray(np.stack([worlds[w].center for w in which])),
        half=jnp.asarray(np.stack([worlds[w].half for w in which])),
        yaw=jnp.asarray(np.stack([worlds[w].yaw for w in which])),
    )
    setup = jax.vmap(RobotSetup)(  # every field carries the robot axis
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
    if compile_chunk:
        _bind(fleet, jnp.asarray(qpos0, jnp.float32), gyro_adr, acc_adr)
    else:
        fleet.functions = make_functions(fleet, gyro_adr, acc_adr)
    return fleet


# reuse one compilation (everything else enters as arguments).
_FUNCTIONS: dict = {}
_COMPILED: dict = {}


def _batched_chunk(fleet: Fleet, frames: int):
    fn = functools.partial(fleet.functions.chunk, frames=frames)
    # Outputs stay time-major (samples, N, ...): the scan's own layout, so no device-side transpose
    # doubles the largest buffer (depth); the host reorders while copying.
    axes = (fleet.model_in_axes, 0, 0)
    fn = parallel.shard_batched(jax.vmap(fn, in_axes=axes, out_axes=(0, 1)), fleet.mesh, axes, (0, 1))
    return jax.jit(fn, donate_argnums=(2,))


def _compile_chunk(fleet: Fleet, state_shape, frames: int):
    shapes = tuple((x.shape, str(x.dtype)) for x in jax.tree.leaves((fleet._placed, state_shape)))
    key = (fleet._structure, fleet.mesh, shapes, frames)
    if key not in _COMPILED:
        _COMPILED[key] = _batched_chunk(fleet, frames).lower(*fleet._placed, state_shape).compile()
    return _COMPILED[key]


def _nbytes(tree) -> int:
    """Bytes of a pytree of arrays or shape structs (PRNG keys count as two uint32 words)."""
    total = 0
    for x in jax.tree.leaves(tree):
        shape, dtype = np.shape(x), x.dtype if hasattr(x, "dtype") else np.asarray(x).dtype
        itemsize = 8 if jax.dtypes.issubdtype(dtype, jax.dtypes.prng_key) else np.dtype(dtype).itemsize
        total += int(np.prod(shape)) * itemsize
    return total


def _bind(fleet: Fleet, qpos0: Array, gyro_adr: int, acc_adr: int) -> None:
    """Attach the compiled init and chunk functions, with the chunk length planned (see sim.memory).

    The plan is made before compiling (compilation itself allocates buffers of the chunk's size on
    a GPU, to autotune): outputs per camera frame are known exactly from the traced shapes, the
    robots' state, model and setup from theirs; a length is chosen that keeps their sum within
    `memory.PLAN_FRACTION` of the budget, then XLA's analysis of the compiled chunk is checked.
    """
    cfg = fleet.config
    fleet._structure = (
        dataclasses.replace(
            cfg, seed=0, n_robots=1, n_worlds=1, style="calm", randomize=True, frames_per_chunk=None, devices=None
        ),
        gyro_adr,
        acc_adr,
    )
    fleet.mesh = parallel.mesh(cfg.devices)
    fleet.n_batch = parallel.padded_size(cfg.n_robots, fleet.mesh)
    axes = (fleet.model_in_axes, 0, 0, 0)
    if (fleet._structure, fleet.mesh) not in _FUNCTIONS:
        fns = make_functions(fleet, gyro_adr, acc_adr)
        init_jit = jax.jit(parallel.shard_batched(jax.vmap(fns.init, in_axes=axes), fleet.mesh, axes, 0))
        _FUNCTIONS[fleet._structure, fleet.mesh] = (fns, init_jit)
    fleet.functions, init_jit = _FUNCTIONS[fleet._structure, fleet.mesh]
    # Robots past n_robots (filling the last device) are copies of the last robot; `rollout` drops them.
    keys = jax.random.split(jax.random.key(cfg.seed), cfg.n_robots)
    args = parallel.place(parallel.pad((fleet.model, fleet.setup, qpos0, keys), fleet.n_batch, axes), fleet.mesh, axes)
    fleet._placed = args[:2]
    if fleet.n_batch == cfg.n_robots:  # one copy of the per-robot constants, split over the devices
        fleet.model, fleet.setup = fleet._placed
    fleet._init = lambda: init_jit(*args)
    state_shape = jax.eval_shape(fleet._init)
    # The plan is per device: each holds n_batch / devices robots (the replicated model part is small).
    share = 1.0 / fleet.mesh.size
    per_frame = int(share * _nbytes(jax.eval_shape(_batched_chunk(fleet, 1), *fleet._placed, state_shape)[1]))
    fixed = int(share * (2 * _nbytes(state_shape) + _nbytes(fleet._placed)))
    budget = int(memory.MEMORY_FRACTION * min(memory.free_bytes(d) for d in fleet.mesh.local_devices))
    want = cfg.frames_per_chunk or MAX_FRAMES_PER_CHUNK
    frames = memory.plan_frames(fixed + per_frame * want, want, per_frame, int(memory.PLAN_FRACTION * budget))
    total = fixed + per_frame * frames
    measured = None  # (frames, XLA's footprint) of the last chunk compiled
    if frames >= 1:
        compiled = _compile_chunk(fleet, state_shape, frames)
        total = memory.footprint_bytes(compiled)
        measured = (frames, total)
        if total > budget:  # temporaries larger than planned: shrink once by XLA's own figure
            frames = memory.plan_frames(total, frames, per_frame, budget)
            if frames >= 1:
                compiled = _compile_chunk(fleet, state_shape, frames)
                total = memory.footprint_bytes(compiled)
                measured = (frames, total)
    if frames < 1 or total > budget or (cfg.frames_per_chunk is not None and frames < cfg.frames_per_chunk):
        # A 1-frame chunk's footprint: XLA's figure where a chunk was compiled, else the planned buffers
        # with the planning headroom; both scale with the robot count.
        at_one = (
            measured[1] - per_frame * (measured[0] - 1) if measured else int((fixed + per_frame) / memory.PLAN_FRACTION)
        )
        n_max = memory.largest_fleet(fleet.n_batch // fleet.mesh.size, at_one, budget) * fleet.mesh.size
        what = (
            f"a chunk of {cfg.frames_per_chunk} frames"
            if cfg.frames_per_chunk and frames >= 1
            else "even a 1-frame chunk"
        )
        per = f" per device on {fleet.mesh.size} devices" if fleet.mesh.size > 1 else ""
        raise ValueError(
            f"a fleet of {cfg.n_robots} robots does not fit: {what} needs more than the "
            f"{budget / memory.GIB:.1f} GiB free{per}; the largest fleet that fits has about {n_max} robots"
        )
    fleet.frames_per_chunk, fleet.chunk_bytes, fleet._chunk = frames, total, compiled


def init(fleet: Fleet) -> RobotState:
    """Batched initial state (leading axis `fleet.n_batch`, split over `fleet.mesh`)."""
    return fleet._init()


def run_chunk(fleet: Fleet, state: RobotState) -> tuple[RobotState, dict[str, Array]]:
    """Advance every robot by one chunk; returns the new state (the old one is donated) and the
    chunk's samples, time-major: per-sample arrays (samples_per_chunk, N, ...) and `depth`
    (frames, N, H, W), with N = `fleet.n_batch` (robots from n_robots on are padding copies)."""
    return fleet._chunk(*fleet._placed, state)


def n_chunks(fleet: Fleet, seconds: float) -> int:
    return max(1, math.ceil(seconds / (fleet.frame_dt * fleet.frames_per_chunk) - 1e-9))
