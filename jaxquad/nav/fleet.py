"""Navigation runs of a fleet: every robot walks its closed loop (`jaxquad.nav.closed_loop`) to its goals
in one world, chunk by chunk, until every run has ended.

`navigate(NavConfig(...)) -> NavResult` builds the fleet (`jaxquad.sim.build_fleet` without its
open-loop chunk), the navigation map (`MAP_SOURCES`), its costmap, likelihood field and the
cost-to-go of a pool of goals (computed once: replanning is then a descent), the robots' starts
and goal sequences, then runs a compiled chunk of `chunk_ticks` control ticks (`vmap` over robots
inside a `lax.scan` over ticks; replanning every `NavParams.replan_ticks` ticks, 0.96 s) until all
robots are done. Every attempt has a time limit, so a run always ends.

Variants (the paper's Table II): `full` = leg-inertial odometry + IMU-stabilized scans; `baseline`
= depth visual odometry alone (constant-velocity guess with the gyro's rotation, restart at the last
pose when lost: RTAB-Map's defaults) + fixed-row scans (depthimage_to_laserscan).
"""

from __future__ import annotations

import dataclasses
import math
import time
from pathlib import Path

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from jaxquad import parallel, vo
from jaxquad.estimate.pipeline import PipelineParams
from jaxquad.kernels.scan import CameraIntrinsics
from jaxquad.nav import closed_loop as cl
from jaxquad.nav import missions
from jaxquad.nav import navigate as nav
from jaxquad.nav.body import BodyParams
from jaxquad.nav.fleet_loop import compile_chunk, keep_first, loop_functions, place_robots, start_qpos

VARIANTS = {"full": ("leg", "stabilized"), "baseline": ("visual", "baseline")}
AMCL_FILE = Path(__file__).with_name("amcl.yaml")
REPLAN_TICKS = 10  # control ticks between two plans (0.96 s)
SUCCESS_XY, SUCCESS_YAW = 0.25, 0.25  # m, rad: a goal is reached when the true pose is this close (the paper's)


@dataclasses.dataclass(frozen=True)
class NavConfig:
    robot: str = "go2"
    world: str = "house"
    n_robots: int = 4
    n_goals: int = 5
    variant: str = "full"  # or "baseline"; `odometry` / `scans` override its parts
    map: str = "truth"  # a key of missions.MAP_SOURCES
    map_walk_seconds: float | None = None  # map="slam": the mapping walk's length (None: one lap of its loop)
    style: str = "aggressive"  # gait style of the robots (calm or aggressive)
    seed: int = 0  # world, starts, goals, robot variation and noise
    particles: int | None = None  # AMCL particles per robot (None: max_particles of the AMCL file, 2000)
    amcl_params: str | None = None  # AMCL parameter file (None: jaxquad/nav/amcl.yaml)
    band_height: int = 1  # scan band rows (the minimum over noisy rows biases ranges short)
    samples: int = 1000  # MPPI samples
    horizon: int = 40  # MPPI steps (of one control tick each)
    pool_size: int = 64  # distinct goal poses drawn in the world
    # m from every box, for starts and goals: room to turn in place on arrival (the Go2's farthest footprint
    # corner is 0.43 m from its base) within the arrival tolerance and the localization error.
    clearance: float = 0.75
    min_separation: float = 1.0  # m between consecutive goals
    arrive_xy: float = 0.08  # m: the controller's goal tolerance (its estimate), well inside success's 0.25 m
    arrive_yaw: float = 0.15  # rad (success: 0.25 rad)
    chunk_ticks: int = 100  # control ticks per compiled chunk (a multiple of the replan period)
    max_seconds: float | None = None  # stop after this much simulated time (whole chunks); None: when all are done
    contacts: str = "truth"  # the estimator's contact source
    odometry: str | None = None
    scans: str | None = None
    randomize: bool = True  # per-robot masses, friction, motors and noise levels
    trace_robots: int = 64  # robots whose paths are kept in the result
    devices: int | None = None  # devices the robots are split over (`jaxquad.parallel.mesh`); None: all local ones

    def __post_init__(self):
        if self.variant not in VARIANTS:
            raise ValueError(f"variant must be one of {sorted(VARIANTS)}, got {self.variant!r}")
        if self.map not in missions.MAP_SOURCES:
            raise ValueError(f"map must be one of {sorted(missions.MAP_SOURCES)}, got {self.map!r}")
        for name in (
            "n_robots",
            "n_goals",
            "particles",
            "samples",
            "horizon",
            "pool_size",
            "chunk_ticks",
            "band_height",
        ):
            if getattr(self, name) is not None and int(getattr(self, name)) < 1:
                raise ValueError(f"{name} must be >= 1, got {getattr(self, name)}")
        if self.max_seconds is not None and not self.max_seconds > 0:
            raise ValueError(f"max_seconds must be positive, got {self.max_seconds}")
        if self.chunk_ticks % REPLAN_TICKS:
            raise ValueError(f"chunk_ticks must be a multiple of {REPLAN_TICKS}, got {self.chunk_ticks}")
        self.loop_config()  # checks the overrides and reads the AMCL file now, before any heavy work

    def localize_params(self):
        """The AMCL parameters (`jaxquad.localize.LocalizeParams`) of the run."""
        from jaxquad.localize.params import load_params

        return load_params(self.amcl_params or AMCL_FILE, max_particles=self.particles)

    def loop_config(self) -> cl.LoopConfig:
        odometry, scans = VARIANTS[self.variant]
        return cl.LoopConfig(
            odometry=self.odometry or odometry,
            scans=self.scans or scans,
            n_goals=self.n_goals,
            band_height=self.band_height,
            contacts=self.contacts,
            n_particles=self.localize_params().max_particles,
        )


@dataclasses.dataclass
class NavResult:
    """A finished run, NumPy (N robots, G goals, T ticks, F frames per tick)."""

    config: NavConfig
    occ: object  # the OccupancyMap navigated on
    world: object  # sim.worlds.World (ground truth)
    starts: np.ndarray  # (N, 3) x y yaw
    goals: np.ndarray  # (N, G, 3)
    outcome: np.ndarray  # (N, G) closed_loop.OUTCOMES codes
    elapsed: np.ndarray  # (N, G) s per attempt (NaN if never ended)
    end_error: np.ndarray  # (N, G, 2) true position (m) and yaw (rad) error to the goal when the attempt ended
    t: np.ndarray  # (T,) s
    active: np.ndarray  # (T, N) the run had not ended at the tick's start
    loc_error: np.ndarray  # (T, N, F) m
    recovering: np.ndarray  # (T, N)
    true_pose: np.ndarray  # (T, n_trace, 3)
    pose: np.ndarray  # (T, n_trace, 3) localization estimate
    compile_s: float
    run_s: float  # wall time of the chunks and of copying their outputs to the host, compilation excluded
    sim_s: float  # simulated time


def loop_nav_params(
    grid_shape: tuple[int, int],
    samples: int,
    horizon: int,
    replan_ticks: int,
    tick_dt: float,
    body: BodyParams,
    footprint_padding: float = 0.0,
    outline_padding: float = 0.0,
) -> nav.NavParams:
    """The navigation numbers of a closed loop on a map of `grid_shape` cells: path capacity for a winding route
    across it (1.5 x its sides, one point every 4 cells), the robot's footprint from its body parameters (its
    covering disks padded by `footprint_padding` m in the costmap, its outline's points moved `outline_padding` m
    out), and the control tick (s) as MPPI's model step."""
    rows, cols = grid_shape
    params = nav.NavParams.default(
        n_samples=samples,
        horizon=horizon,
        n_path_points=max(32, math.ceil(1.5 * (rows + cols) / 4)),
        replan_ticks=replan_ticks,
        footprint=(body.footprint_center, body.footprint_half),
        footprint_padding=footprint_padding,
        outline_padding=outline_padding,
    )
    return eqx.tree_at(lambda p: p.controller.dt, params, jnp.asarray(tick_dt, jnp.float32))


def _params(cfg: NavConfig, loop: cl.LoopConfig, fleet, occ, tick_dt: float) -> cl.LoopParams:
    lp = cfg.localize_params()
    body = body_params(fleet, loop.odometry, lp.laser_min_range, lp.laser_max_range)
    nav_params = eqx.tree_at(
        lambda p: (p.controller.goal_xy_tol, p.controller.goal_yaw_tol),
        loop_nav_params(occ.grid.shape, cfg.samples, cfg.horizon, REPLAN_TICKS, tick_dt, body),
        tuple(jnp.asarray(v, jnp.float32) for v in (cfg.arrive_xy, cfg.arrive_yaw)),
    )
    T_bc = np.asarray(fleet.T_base_camera)
    f32 = lambda x: jnp.asarray(x, jnp.float32)  # noqa: E731
    return cl.LoopParams(
        nav=nav_params,
        amcl=lp.amcl(T_base_laser=(float(T_bc[0, 3]), float(T_bc[1, 3]), 0.0)),
        body=body,
        success_xy=f32(SUCCESS_XY),
        success_yaw=f32(SUCCESS_YAW),
        lost_error=f32(0.5),
        lost_time=f32(2.0),
        timeout_base=f32(30.0),
        timeout_speed=f32(0.1),
    )


def body_params(fleet, odometry: str, range_min: float, range_max: float) -> BodyParams:
    """The robot side's numbers: default estimator, visual odometry (`odometry="visual"`), the camera, scan
    limits (m) and the robot's footprint."""
    T_bc, K = np.asarray(fleet.T_base_camera), np.asarray(fleet.K)
    center, half = missions.footprint(fleet.robot)
    f32 = lambda x: jnp.asarray(x, jnp.float32)  # noqa: E731
    return BodyParams(
        pipeline=PipelineParams.default(len(fleet.robot.foot_names), "mixed"),
        vo=vo.VoParams.default(K, T_bc, coupling="off") if odometry == "visual" else None,
        intrinsics=CameraIntrinsics(f32(K[0, 0]), f32(K[1, 1]), f32(K[0, 2]), f32(K[1, 2])),
        range_min=f32(range_min),
        range_max=f32(range_max),
        footprint_center=f32(center),
        footprint_half=f32(half),
    )


# (robot, fleet structure, loop configuration) -> jitted (init, chunk): the functions close over static
# numbers only, so one compilation serves every fleet of that structure.
_FUNCTIONS: dict = {}


def _input_axes(fleet, inputs: cl.LoopInputs):
    """vmap axes of LoopInputs: per-robot model fields, setup and goals; the map and the replan flag shared."""
    fields = lambda x: (x.model, x.setup, x.nav_map, x.goal_ids, x.replan)  # noqa: E731
    return eqx.tree_at(fields, inputs, (fleet.model_in_axes, 0, None, 0, None))


def _compiled_functions(fleet, loop: cl.LoopConfig, mesh):
    c = dataclasses.replace(fleet.config, seed=0, n_robots=1, n_worlds=1, style="calm", randomize=True, devices=None)
    key = (fleet.robot.path, c, loop, mesh)
    if key not in _FUNCTIONS:
        fns = cl.make_loop(fleet, loop)
        _FUNCTIONS[key] = loop_functions(fns.init, fns.tick, lambda inputs: _input_axes(fleet, inputs), mesh)
    return _FUNCTIONS[key]


def navigate(cfg: NavConfig, goals: np.ndarray | None = None, starts: np.ndarray | None = None, progress=None):
    """Run the fleet; `goals` (K, 3) replaces the drawn pool and `starts` (N, 3) the drawn starts (then each
    robot visits pool goals in order, goal i % K for its i-th). Attempts still running when `max_seconds`
    stops the run stay `pending`. `progress(done, total)` is called with the goals ended after each chunk
    (first with 0 once the run is set up)."""
    from jaxquad.localize.run import field_of_map
    from jaxquad.sim import FleetConfig, build_fleet

    loop = cfg.loop_config()
    mesh = parallel.mesh(cfg.devices)
    if jax.process_count() > 1:
        raise ValueError("navigate runs in one process (its --devices split the robots over that process's devices)")
    fleet = build_fleet(
        FleetConfig(
            robot=cfg.robot,
            world=cfg.world,
            n_robots=cfg.n_robots,
            style=cfg.style,
            seed=cfg.seed,
            randomize=cfg.randomize,
        ),
        compile_chunk=False,
    )
    world = fleet.worlds[0]
    occ = missions.MAP_SOURCES[cfg.map](cfg, world)
    tick_dt = loop.frames_per_tick * fleet.frame_dt
    params = _params(cfg, loop, fleet, occ, tick_dt)
    grid = nav.cost_grid(params.nav, jnp.asarray(occ.grid), jnp.asarray(occ.origin[:2], jnp.float32), occ.resolution)
    rng = np.random.default_rng([cfg.seed, 11])
    open_cells = missions.reachable_cells(np.asarray(jax.jit(nav.step_weights)(grid.cost, params.nav.cost_weight)))
    pool = missions.draw_poses(rng, occ, open_cells, world, cfg.pool_size, cfg.clearance) if goals is None else goals
    if starts is None:
        starts = missions.draw_poses(rng, occ, open_cells, world, cfg.n_robots, cfg.clearance)
    starts = np.asarray(starts, np.float64).reshape(cfg.n_robots, 3)
    if goals is None:
        goal_ids = missions.missions(rng, pool, starts, cfg.n_goals, cfg.min_separation)
    else:
        goal_ids = np.tile(np.arange(cfg.n_goals) % len(pool), (cfg.n_robots, 1)).astype(np.int32)
    table = jax.jit(nav.goal_table)(params.nav, grid, jnp.asarray(pool, jnp.float32))
    # The field measures distances to obstacle surfaces: the map's obstacles may be filled (see likelihood_field).
    field = field_of_map(occ, cfg.localize_params().laser_likelihood_max_dist, surfaces=True)
    nav_map = cl.NavMap(grid=grid, field=field, table=table)
    inputs = cl.LoopInputs(
        model=fleet.model, setup=fleet.setup, nav_map=nav_map, goal_ids=jnp.asarray(goal_ids), replan=jnp.asarray(True)
    )

    n = cfg.n_robots
    init, chunk = _compiled_functions(fleet, loop, mesh)
    params, inputs, qpos0, keys = place_robots(
        mesh, params, inputs, lambda x: _input_axes(fleet, x), start_qpos(fleet.robot, starts), cfg.seed
    )
    t0 = time.perf_counter()
    states = init(params, inputs, qpos0, keys)
    compiled = compile_chunk(chunk, params, states, inputs, cfg.chunk_ticks, int(params.nav.replan_ticks))
    compile_s = time.perf_counter() - t0
    # Every attempt ends by its time limit: the longest possible run bounds the loop.
    finite = np.asarray(table.value)[np.isfinite(np.asarray(table.value))]
    longest_path = float(finite.max(initial=0.0)) * occ.resolution
    longest = cfg.n_goals * (float(params.timeout_base) + longest_path / float(params.timeout_speed)) + 10.0
    if cfg.max_seconds is not None:
        longest = min(longest, cfg.max_seconds)
    n_chunks_max = max(1, math.ceil(longest / (cfg.chunk_ticks * tick_dt) - 1e-9))
    outs, run_s = [], 0.0
    total = cfg.n_robots * cfg.n_goals
    if progress is not None:
        progress(0, total)
    for _ in range(n_chunks_max):
        t1 = time.perf_counter()
        states, out = compiled(params, states, inputs)
        outs.append(keep_first(out, min(cfg.trace_robots, n), ("true_pose", "pose", "odom", "cmd")))
        done = np.asarray(states.done)[:n]
        run_s += time.perf_counter() - t1  # the outputs' copy to the host included
        if progress is not None:
            progress(int((np.asarray(states.outcome)[:n] != cl.PENDING).sum()), total)
        if done.all():
            break
    trace = jax.tree.map(lambda *x: np.concatenate(x), *outs)
    return NavResult(
        config=cfg,
        occ=occ,
        world=world,
        starts=starts,
        goals=np.asarray(pool)[goal_ids],
        outcome=np.asarray(states.outcome)[:n],
        elapsed=np.asarray(states.elapsed)[:n],
        end_error=np.asarray(states.end_error)[:n],
        t=trace.t[:, 0],
        active=trace.active[:, :n],
        loc_error=trace.loc_error[:, :n],
        recovering=trace.recovering[:, :n],
        true_pose=trace.true_pose,
        pose=trace.pose,
        compile_s=compile_s,
        run_s=run_s,
        sim_s=float(trace.t[-1, 0]),
    )
