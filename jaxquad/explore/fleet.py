"""Exploration runs of a fleet: every robot explores the same unknown world with its own closed loop
(`jaxquad.explore.loop`), chunk by chunk, for a fixed simulated time.

`explore(ExploreConfig(...)) -> ExploreResult` builds the fleet (`jaxquad.sim.build_fleet` without its
open-loop chunk), draws the robots' starts on the world's true free space (the truth sets the task and
judges; the robots never read it), sizes the SLAM (its map on the true map's cells: the building's
outline plus 0.5 m, an operator's figure; node slots for the whole run), then runs a compiled chunk of
`chunk_ticks` control ticks (`vmap` over robots inside a `lax.scan` over ticks; a planning period every
`REPLAN_TICKS` ticks, 0.96 s) until `seconds` have passed or every run has ended, and closes each
robot's graph (`jaxquad.slam.finish`: a last optimization and the map at the optimized poses).

Variants: `full` = leg-inertial odometry, IMU-stabilized scans and the SLAM's preintegrated
leg-odometry edges; `baseline` = depth visual odometry (constant-velocity guess, RTAB-Map's defaults),
fixed-row scans and no leg-odometry edges (Karto's scan matching alone).
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

from jaxquad import parallel, slam
from jaxquad.explore import checkpoint as ckpt
from jaxquad.explore import loop as xl
from jaxquad.kernels.low_obstacles import LowObstacleParams
from jaxquad.kernels.occupancy import occupancy_values
from jaxquad.metrics import narrow_gaps
from jaxquad.nav import explore as nav_explore
from jaxquad.nav import missions, revisit
from jaxquad.nav.fleet import REPLAN_TICKS, body_params, loop_nav_params
from jaxquad.nav.fleet_loop import compile_chunk, keep_first, loop_functions, place_robots, start_qpos

VARIANTS = {"full": ("leg", "stabilized", "preintegrated"), "baseline": ("visual", "baseline", "off")}
TRACED = ("true_pose", "pose", "goal", "mode")  # outputs kept for the first `trace_robots` robots only
SCAN_RANGE = 8.0  # m, the scans' range limit (the depth camera's); scan matching reads up to match_max_range
# m/s: prior std of each robot's leg-odometry sideways bias, which the full variant's SLAM estimates from its matches
# (`jaxquad.slam.leg_bias`). The Badger's drifts 2.5-3.5 mm/s at exploration's pace: 100 warehouse runs, 240 s,
# lost 19 -> 6. The Go2's (0.1-0.5 mm/s) lies under the estimate's spread: not estimated (README, exploration).
LEG_BIAS_SIDEWAYS = {"badger": 0.01}


def leg_bias_sideways(robot: str, value: float | None) -> float:
    """m/s: `value`, or the robot's default (`LEG_BIAS_SIDEWAYS`, else 0: not estimated) when None."""
    return LEG_BIAS_SIDEWAYS.get(robot, 0.0) if value is None else float(value)


@dataclasses.dataclass(frozen=True)
class ExploreConfig:
    robot: str = "go2"
    world: str = "house"
    n_robots: int = 2
    seconds: float = 60.0  # simulated time of the run
    variant: str = "full"  # or "baseline"
    seed: int = 0  # world, starts, robot variation and noise
    style: str = "aggressive"  # gait style (calm or aggressive)
    samples: int = 256  # MPPI samples
    horizon: int = 30  # MPPI steps (of one control tick each)
    chunk_ticks: int = 50  # control ticks per compiled chunk (a multiple of REPLAN_TICKS)
    slam_params: str | None = None  # SLAM parameter file (None: jaxquad/slam/slam.yaml)
    clearance: float = 0.75  # m from every box for the starts (a robot turning in place sweeps ~0.4 m)
    map_range: float = 4.0  # m: longer readings are no-returns for the map (depth noise, 1 % of z^2, is 16 cm at 4 m)
    # m: readings from map_range up to this mark no wall but clear the map along their ray, stopping three noise std
    # short of the reading (`kernels.occupancy`; the SLAM file's occupancy_clear_margin); in place of the file's
    # occupancy_clear_range, at most SCAN_RANGE; 0 (or at most map_range): not beyond map_range.
    # 100 Go2 runs, H200, 0 -> 8 m: warehouse 900 s runs at 95 % 47 -> 56 (of the clear cells 56 -> 70), lost 13 ->
    # 16; house 600 s 78 -> 75 (92 -> 93), coverage at 2 min 0.795 -> 0.813 (README, exploration).
    map_clear_range: float = SCAN_RANGE
    # The map's miss probability (a cell a ray crosses), in place of the SLAM file's: at 0.3 a cell is free after two
    # crossing scans (0.35 needs three), and cells seen from few nodes near the walls become free. 100 Go2 runs in the
    # house: coverage 0.896 -> 0.919, runs with 95 % of the clear cells 29 -> 57 (README, exploration).
    map_miss_probability: float = 0.3
    # Cells (0-1): a return marks the map cell this far beyond it along the ray, in place of the SLAM file's
    # `occupancy_hit_offset_cells` (half a cell). The cell a box's face passes through is free in the true map when its
    # centre lies in front of the face; a whole cell beyond the reading leaves it to the ray's free evidence also when
    # the face is met obliquely, and under pose error moves the scatter of returns into the box. 100 runs per robot in
    # the house, 600 s, runs at 95 %: Go2 1 / 44 / 71, Badger 4 (half) / 22 at offsets 0 / half / whole (README).
    map_hit_offset_cells: float = 1.0
    # The full variant's SLAM takes heading priors from the walls' directions (`kernels.wall_heading`), in place of the
    # SLAM file's `wall_heading`; the baseline's never does. 100 Go2 runs, H200: warehouse 240 s lost 11 -> 3, SLAM
    # position error at 4 min 0.216 -> 0.117 m (median); house 600 s coverage 0.918 against 0.919, runs with 95 % of
    # the clear cells 57 -> 72 (README, exploration).
    wall_heading: bool = True
    # m added to the footprint's covering disks in the costmap (the planner's and MPPI's inscribed radius), against
    # the SLAM pose's error (median 0.05 m Go2, 0.12 m Badger) and a map whose faces lie up to a cell inside the boxes
    # (the hit offset above). 100 runs per robot in the house, 600 s, 0.1 -> 0.15: collided + lost Go2 14 -> 3,
    # Badger 48 -> 23; runs at 95 % Go2 84 -> 78, Badger 22 -> 24 (README, exploration).
    footprint_padding: float = 0.15
    # m/s: prior std of the leg odometry's sideways velocity bias, which the SLAM estimates from its scan matches and
    # takes out of its leg edges (`jaxquad.slam.leg_bias`), in place of the SLAM file's leg_bias_std_sideways; 0: not
    # estimated; None: the robot's default (`LEG_BIAS_SIDEWAYS`).
    leg_bias_sideways: float | None = None
    spin_rate: float = 0.6  # rad/s, turning in place without a goal
    finish_time: float = 12.0  # s without a goal before exploration counts as finished (one turn and more)
    # Obstacles under the camera's scan plane (a pallet lower than the camera), marked from the depth image's points
    # below it in the full variant's costmap (`kernels.low_obstacles`); off, and always in the baseline: the costmap is
    # the SLAM map's alone. 100 Go2 runs in the warehouse, H200: collided 14 -> 0 in 240 s (README, exploration).
    low_obstacles: bool = True
    # Once no reachable frontier is left, walk to where one out of reach lies in plain view and look at it
    # (`nav.explore`, `kernels.view_goals`); the baseline variant's explorer never does (explore_lite's). 100 runs per
    # robot in the house, 600 s, H200, their first version: runs at 95 % Go2 65 -> 71, Badger 18 -> 25 (README).
    view_goals: bool = True
    # s without an accepted loop closure before the robot drives back to a place mapped a minute or more ago to close
    # one (active loop closing, `jaxquad.nav.revisit`); 0: never.
    revisit_after: float = 0.0
    contacts: str = "truth"  # the estimator's contact source
    band_height: int = 1  # scan band rows
    band_reduce: str = "median"  # each ray's range from its band: "median" or the paper's "min" (kernels.scan)
    randomize: bool = True  # per-robot masses, friction, motors and noise levels
    trace_robots: int = 8  # robots whose paths are kept in the result
    devices: int | None = None  # devices the robots are split over (`jaxquad.parallel.mesh`); None: all local ones

    def __post_init__(self):
        if self.variant not in VARIANTS:
            raise ValueError(f"variant must be one of {sorted(VARIANTS)}, got {self.variant!r}")
        for name in ("n_robots", "samples", "horizon", "chunk_ticks", "band_height", "trace_robots"):
            if int(getattr(self, name)) < 1:
                raise ValueError(f"{name} must be >= 1, got {getattr(self, name)}")
        for name in ("seconds", "spin_rate", "finish_time", "map_range"):
            if not getattr(self, name) > 0:
                raise ValueError(f"{name} must be positive, got {getattr(self, name)}")
        for name in ("revisit_after", "footprint_padding", "map_clear_range"):  # 0: never, none, off
            if not (math.isfinite(getattr(self, name)) and getattr(self, name) >= 0):
                raise ValueError(f"{name} must be a finite number >= 0, got {getattr(self, name)}")
        bias = leg_bias_sideways(self.robot, self.leg_bias_sideways)
        if not (math.isfinite(bias) and bias >= 0):
            raise ValueError(f"leg_bias_sideways must be a finite number >= 0, got {self.leg_bias_sideways}")
        if not 0.0 < self.map_miss_probability < 0.5:
            raise ValueError(f"map_miss_probability must lie in (0, 0.5), got {self.map_miss_probability}")
        if not 0.0 <= self.map_hit_offset_cells <= 1.0:
            raise ValueError(f"map_hit_offset_cells must lie in [0, 1], got {self.map_hit_offset_cells}")
        if self.chunk_ticks % REPLAN_TICKS:
            raise ValueError(f"chunk_ticks must be a multiple of {REPLAN_TICKS}, got {self.chunk_ticks}")
        self.slam_values()  # reads and checks the SLAM file now, before any heavy work

    def loop_config(self) -> xl.ExploreLoopConfig:
        odometry, scans, lo = VARIANTS[self.variant]
        return xl.ExploreLoopConfig(
            odometry=odometry,
            scans=scans,
            lo_constraints=lo,
            band_height=self.band_height,
            band_reduce=self.band_reduce,
            contacts=self.contacts,
            low_obstacles=self.low_obstacles and self.variant == "full",
        )

    def slam_values(self) -> dict:
        """The SLAM parameters, with node slots for a node every `minimum_time_interval` of the run, the map's
        range `map_range` (at most the longest reading the SLAM file reads), clearing to `map_clear_range`, its miss
        probability `map_miss_probability`, its hit offset `map_hit_offset_cells`, and wall-heading priors for the
        full variant when `wall_heading`, and the sideways leg-odometry bias's prior `leg_bias_sideways`."""
        values = slam.load_params(self.slam_params)
        if not values["occupancy_clamp_min_probability"] < self.map_miss_probability:
            source = self.slam_params or slam.params.DEFAULTS_FILE
            raise ValueError(
                f"params file {source}: occupancy_clamp_min_probability ({values['occupancy_clamp_min_probability']}) "
                f"must lie below map_miss_probability ({self.map_miss_probability})"
            )
        nodes = math.ceil(self.seconds / max(values["minimum_time_interval"], 0.1)) + 2
        nodes = max(values["node_capacity"] if self.slam_params else 0, nodes)
        return values | {
            "node_capacity": nodes,
            "occupancy_hit_offset_cells": self.map_hit_offset_cells,
            "max_laser_range": min(slam.map_max_range(values), self.map_range),
            "occupancy_clear_range": min(self.map_clear_range, SCAN_RANGE),
            "occupancy_miss_probability": self.map_miss_probability,
            "wall_heading": int(self.wall_heading and self.variant == "full"),
            # the baseline's SLAM has no leg edges to correct
            "leg_bias_std_sideways": leg_bias_sideways(self.robot, self.leg_bias_sideways) * (self.variant == "full"),
        }


@dataclasses.dataclass
class ExploreResult:
    """A finished run, NumPy (N robots, T ticks)."""

    config: ExploreConfig
    world: object  # sim.worlds.World (ground truth)
    truth: object  # OccupancyMap: the world's true map, on the cells of the robots' maps
    reachable: np.ndarray  # (H, W) bool: true free cells connected to the starts, `metrics.narrow_gaps` left out
    # (coverage's denominator)
    clear: np.ndarray  # (H, W) bool: the reachable cells whose whole square is off every box (coverage_clear's)
    maps: np.ndarray  # (N, H, W) int8: each robot's final SLAM map (-1 unknown, 0..100)
    low: np.ndarray  # (N, H, W) bool: the obstacles under the scan plane each robot marked ((N, 0, 0) when off)
    starts: np.ndarray  # (N, 3) x y yaw
    outcome: np.ndarray  # (N,) loop.OUTCOMES codes
    end_t: np.ndarray  # (N,) s when the run ended (NaN: running at the end)
    distance: np.ndarray  # (N,) m walked
    nodes: np.ndarray  # (N,) SLAM nodes
    loops: np.ndarray  # (N,) loop closures accepted
    revisits: np.ndarray  # (N,) revisits begun (`ExploreConfig.revisit_after`)
    revisits_closed: np.ndarray  # (N,) revisits that ended with a loop closure
    t: np.ndarray  # (T,) s
    coverage: np.ndarray  # (T, N)
    error: np.ndarray  # (T, N) m, SLAM position error
    active: np.ndarray  # (T, N)
    revisiting: np.ndarray  # (T, N) the goal was a revisit
    viewing: np.ndarray  # (T, N) the goal was a view goal
    loop_closed: np.ndarray  # (T, N) the SLAM accepted a loop closure on the tick
    loop_chi2: np.ndarray  # (T, N) consistency chi-square of a loop candidate past the match tests (NaN: none)
    lo_bias: np.ndarray  # (N, 2) m/s: the SLAM's last estimate of the leg odometry's velocity bias, base frame
    true_pose: np.ndarray  # (T, n_trace, 3)
    pose: np.ndarray  # (T, n_trace, 3) SLAM pose
    goal: np.ndarray  # (T, n_trace, 3) the frontier or view goal (or revisited node), x y yaw
    mode: np.ndarray  # (T, n_trace) int8: what commanded the robot (loop.MODES)
    compile_s: float
    run_s: float  # wall time of the chunks and of copying their outputs to the host, compilation excluded
    chunk_s: np.ndarray  # (K,) that wall time per chunk, s, over all sittings
    sim_s: float


def clear_cells(world, truth, reachable: np.ndarray) -> np.ndarray:
    """(H, W) bool: the `reachable` cells of the map `truth` whose square overlaps none of `world`'s boxes (exact:
    the separating-axis test of `kernels.footprint`). A cell a box's face passes through is free in the true map
    when its centre is outside, yet holds the range returns off that face."""
    from jaxquad.kernels.footprint import footprint_overlaps
    from jaxquad.kernels.raycast import Boxes

    boxes = Boxes(*(jnp.asarray(a, jnp.float32) for a in (world.center, world.half, world.yaw)))
    xy = jnp.asarray(truth.cell_centers(), jnp.float32).reshape(-1, 2)
    poses = jnp.concatenate([xy, jnp.zeros((xy.shape[0], 1), jnp.float32)], axis=1)
    half = jnp.full(2, 0.5 * truth.resolution, jnp.float32)
    hit = jax.jit(jax.vmap(lambda p: jnp.any(footprint_overlaps(boxes, p, half))))(poses)
    return np.asarray(reachable) & ~np.asarray(hit).reshape(reachable.shape)


def _params(cfg: ExploreConfig, loop: xl.ExploreLoopConfig, fleet, truth, tick_dt: float) -> xl.ExploreLoopParams:
    body = body_params(fleet, loop.odometry, 0.2, SCAN_RANGE)
    nav_params = loop_nav_params(
        truth.grid.shape, cfg.samples, cfg.horizon, REPLAN_TICKS, tick_dt, body, cfg.footprint_padding
    )
    values = cfg.slam_values()
    T_bc = np.asarray(fleet.T_base_camera)
    grid = slam.grid_spec_like(truth, slam.map_max_range(values))
    spec, slam_params = slam.slam_config(values, grid, loop.lo_constraints, (float(T_bc[0, 3]), float(T_bc[1, 3]), 0.0))
    spec = dataclasses.replace(spec, refresh_map=False)  # the loop redraws its map once per planning period
    f32 = lambda x: jnp.asarray(x, jnp.float32)  # noqa: E731
    return xl.ExploreLoopParams(
        nav=nav_params,
        # A known cell more likely free than not is free for the frontiers (the map format's 0.196 needs four
        # free readings of a cell in this SLAM's log-odds, so the edge of what was seen would never be a frontier).
        explore=nav_explore.ExploreParams.default(
            view_goals=cfg.view_goals and cfg.variant == "full", free_thresh=50.0
        ),
        revisit=revisit.RevisitParams.default(after=cfg.revisit_after or np.inf),
        # The camera's height above the floor when the robot stands at its home pose.
        low=LowObstacleParams.default(float(fleet.robot.qpos_home[2] + T_bc[2, 3])),
        slam_spec=spec,
        slam=slam_params,
        body=body,
        yaw_rate_std=f32(values["leg_yaw_rate_std"]),
        spin_rate=f32(cfg.spin_rate),
        finish_time=f32(cfg.finish_time),
        lost_error=f32(0.5),
        lost_time=f32(2.0),
    )


def _input_axes(fleet, inputs: xl.ExploreInputs):
    """vmap axes of ExploreInputs: per-robot model fields and setup; the judge's mask and the flag shared."""
    fields = lambda x: (x.model, x.setup, x.reachable, x.replan)  # noqa: E731
    return eqx.tree_at(fields, inputs, (fleet.model_in_axes, 0, None, None))


# (robot, fleet structure, loop configuration, mesh) -> jitted (init, chunk, finish).
_FUNCTIONS: dict = {}


def _compiled_functions(fleet, loop: xl.ExploreLoopConfig, mesh):
    c = dataclasses.replace(fleet.config, seed=0, n_robots=1, n_worlds=1, style="calm", randomize=True, devices=None)
    key = (fleet.robot.path, c, loop, mesh)
    if key not in _FUNCTIONS:
        fns = xl.make_explore_loop(fleet, loop)

        def finish(params, states):
            def one(s):
                final = slam.finish(params.slam_spec, params.slam, s.slam)
                return occupancy_values(final.grid), final.n_nodes, final.loops

            return parallel.shard_batched(jax.vmap(one), mesh, (0,), 0)(states)

        init, chunk = loop_functions(fns.init, fns.tick, lambda inputs: _input_axes(fleet, inputs), mesh)
        _FUNCTIONS[key] = (init, chunk, jax.jit(finish))
    return _FUNCTIONS[key]


def _joined(outs: list):
    """Chunks' outputs (host, time-major) as one."""
    return jax.tree.map(lambda *x: np.concatenate(x), *outs)


def _kept_like(out, n_trace: int):
    """The structure, shapes and types of one chunk's outputs (`jax.ShapeDtypeStruct`s) as `keep_first` keeps them
    (mapped over the tree: the output's own constructor would check its fields' types)."""

    def kept(path, x):
        robots = n_trace if path[-1].name in TRACED else x.shape[1]
        return jax.ShapeDtypeStruct((x.shape[0], robots, *x.shape[2:]), x.dtype)

    return jax.tree_util.tree_map_with_path(kept, out)


def explore(
    cfg: ExploreConfig,
    starts: np.ndarray | None = None,
    progress=None,
    checkpoint: str | Path | None = None,
    wall_budget_s: float | None = None,
) -> ExploreResult:
    """Run the fleet; `starts` (N, 3) replaces the drawn starts. `progress(done_s, total_s)` is called with
    the simulated seconds after each chunk (first with those done once the run is set up).

    With a `checkpoint` file the run goes on from it when it exists (`jaxquad.explore.checkpoint`: same
    settings and starts, else ValueError); once `wall_budget_s` of wall time have passed since the call,
    the run is saved there at the end of a chunk and `checkpoint.Paused` is raised. The file is left in
    place when the run finishes: the caller removes it once the results are safe."""
    if wall_budget_s is not None and (checkpoint is None or not wall_budget_s > 0):
        raise ValueError("a wall-clock budget needs a checkpoint file to save the run to, and must be positive")
    t_call = time.perf_counter()
    from jaxquad.sim import FleetConfig, build_fleet
    from jaxquad.sim.worlds import occupancy_map

    loop = cfg.loop_config()
    mesh = parallel.mesh(cfg.devices)
    if jax.process_count() > 1:
        raise ValueError("explore runs in one process (its --devices split the robots over that process's devices)")
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
    truth = occupancy_map(world)
    # Gaps a cell wide between boxes (furniture 2 cm off a wall) are neither seen nor reached: not counted.
    reachable = missions.reachable_cells(np.where((truth.grid == 0) & ~narrow_gaps(truth), 1.0, np.inf))
    clear = clear_cells(world, truth, reachable)
    tick_dt = loop.frames_per_tick * fleet.frame_dt
    params = _params(cfg, loop, fleet, truth, tick_dt)
    if starts is None:
        rng = np.random.default_rng([cfg.seed, 13])
        starts = missions.draw_poses(rng, truth, reachable, world, cfg.n_robots, cfg.clearance)
    starts = np.asarray(starts, np.float64).reshape(cfg.n_robots, 3)
    inputs = xl.ExploreInputs(
        model=fleet.model, setup=fleet.setup, reachable=jnp.asarray(reachable), replan=jnp.asarray(True)
    )
    n = cfg.n_robots
    run_id = ckpt.identity(cfg, starts)
    resume = checkpoint is not None and Path(checkpoint).exists()
    if resume:
        ckpt.check(checkpoint, run_id)  # another run's file is refused before any compilation
    init, chunk, finish = _compiled_functions(fleet, loop, mesh)
    params, inputs, qpos0, keys = place_robots(
        mesh, params, inputs, lambda x: _input_axes(fleet, x), start_qpos(fleet.robot, starts), cfg.seed
    )
    t0 = time.perf_counter()
    states = init(params, inputs, qpos0, keys)
    compiled = compile_chunk(chunk, params, states, inputs, cfg.chunk_ticks, REPLAN_TICKS)
    compile_s = time.perf_counter() - t0
    n_chunks = max(1, math.ceil(cfg.seconds / (cfg.chunk_ticks * tick_dt) - 1e-9))
    sim_at = lambda k: round(min(cfg.seconds, k * cfg.chunk_ticks * tick_dt), 1)  # noqa: E731
    n_trace = min(cfg.trace_robots, n)
    outs, chunk_wall, k0 = [], [], 0
    if resume:
        saved = ckpt.load(checkpoint, run_id, states, _kept_like(compiled.out_info[1], n_trace))
        states, outs, k0, chunk_wall = saved.states, [saved.trace], saved.chunks, list(saved.chunk_s)
        compile_s += saved.compile_s
    if progress is not None:
        progress(sim_at(k0), cfg.seconds)
    ended = np.asarray(states.outcome)[:n] != xl.RUNNING
    for k in range(k0, n_chunks):
        if ended.all():
            break
        if wall_budget_s is not None and k > k0 and time.perf_counter() - t_call > wall_budget_s:  # a chunk a sitting
            ckpt.save(checkpoint, run_id, states, _joined(outs), k, chunk_wall, compile_s)
            raise ckpt.Paused(checkpoint, sim_at(k), cfg.seconds)
        t1 = time.perf_counter()
        states, out = compiled(params, states, inputs)
        outs.append(keep_first(out, n_trace, TRACED))
        ended = np.asarray(states.outcome)[:n] != xl.RUNNING
        chunk_wall.append(time.perf_counter() - t1)  # the outputs' copy to the host included
        if progress is not None:
            progress(sim_at(k + 1), cfg.seconds)
    maps, nodes, loops = (np.asarray(a)[:n] for a in jax.device_get(finish(params, states)))
    trace = _joined(outs)
    return ExploreResult(
        config=cfg,
        world=world,
        truth=truth,
        reachable=reachable,
        clear=clear,
        maps=maps,
        low=np.asarray(states.low)[:n],
        starts=starts,
        outcome=np.asarray(states.outcome)[:n],
        end_t=np.asarray(states.end_t)[:n],
        distance=np.asarray(states.distance)[:n],
        nodes=nodes,
        loops=loops,
        revisits=np.asarray(states.revisit.started)[:n],
        revisits_closed=np.asarray(states.revisit.closed)[:n],
        t=trace.t[:, 0],
        coverage=trace.coverage[:, :n],
        error=trace.error[:, :n],
        active=trace.active[:, :n],
        revisiting=trace.revisiting[:, :n],
        viewing=trace.viewing[:, :n],
        loop_closed=trace.loop_closed[:, :n],
        loop_chi2=trace.loop_chi2[:, :n],
        lo_bias=np.asarray(states.slam.lo_bias.x)[:n, 2:],
        true_pose=trace.true_pose,
        pose=trace.pose,
        goal=trace.goal,
        mode=trace.mode,
        compile_s=compile_s,
        run_s=float(sum(chunk_wall)),
        chunk_s=np.asarray(chunk_wall, np.float64),
        sim_s=float(trace.t[-1, 0]),
    )
