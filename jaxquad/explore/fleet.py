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
from jaxquad.explore.config import SCAN_RANGE, ExploreConfig, ExploreResult
from jaxquad.kernels.low_obstacles import LowObstacleParams
from jaxquad.kernels.occupancy import occupancy_values
from jaxquad.metrics import narrow_gaps
from jaxquad.nav import explore as nav_explore
from jaxquad.nav import missions, revisit
from jaxquad.nav.fleet import REPLAN_TICKS, body_params, loop_nav_params
from jaxquad.nav.fleet_loop import compile_chunk, keep_first, loop_functions, place_robots, start_qpos

TRACED = ("true_pose", "pose", "goal", "mode")  # outputs kept for the first `trace_robots` robots only


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
        truth.grid.shape,
        cfg.samples,
        cfg.horizon,
        REPLAN_TICKS,
        tick_dt,
        body,
        footprint_padding=cfg.footprint_padding,
        outline_padding=cfg.outline_padding,
    )
    v_max = nav_params.controller.v_max.at[0].set(cfg.max_speed)
    nav_params = eqx.tree_at(lambda p: p.controller.v_max, nav_params, v_max)
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
            view_goals=cfg.view_goals and cfg.variant == "full", free_thresh=50.0, gain_scale=cfg.frontier_gain
        ),
        revisit=revisit.RevisitParams.default(after=cfg.revisit_after or np.inf),
        # The camera's height above the floor when the robot stands at its home pose.
        low=LowObstacleParams.default(float(fleet.robot.qpos_home[2] + T_bc[2, 3])),
        slam_spec=spec,
        slam=slam_params,
        body=body,
        yaw_rate_std=f32(values["leg_yaw_rate_std"]),
        spin_rate=f32(cfg.spin_rate),
        near_obstacle_speed=f32(cfg.max_speed if cfg.near_obstacle_speed is None else cfg.near_obstacle_speed),
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
