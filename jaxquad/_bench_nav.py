"""Navigation section of `jaxquad bench`: one MPPI tick, the costmap, the global planner and the frontier
choice, for R robots under vmap (R from --batch for MPPI, from --nav-plan-batch for the grid kernels).

Grids come from the simulator's generated warehouse (seed 0) at 0.05 m, cropped or padded with unknown
cells to --nav-grid cells square. MPPI scores --nav-samples sequences of --nav-horizon steps on a local
100 x 100 costmap window (5 m, as Nav2's rolling local costmap) with a 160-point path; robots start at
random open cells. The planner row is one cost-to-go from a goal plus the path descent, with the start
and goal about the map's width apart (its time grows with the number of steps on the longest shortest
path). The frontier rows treat everything farther than 5 m from the robot as unknown: extraction
(frontier cells, 8-connected clusters, sizes and centroids) alone, then the whole choice including
the robot's cost-to-go.
"""

from __future__ import annotations

import argparse

_RES = 0.05
_LOCAL = 100


def add_arguments(parser) -> None:
    parser.add_argument(
        "--nav-samples",
        type=int,
        default=1000,
        help="MPPI samples per robot (default 1000)",
    )
    parser.add_argument("--nav-horizon", type=int, default=40, help="MPPI steps per sample (default 40)")
    parser.add_argument(
        "--nav-grid",
        type=int,
        default=400,
        help="planner/frontier grid side, cells (default 400)",
    )
    parser.add_argument(
        "--nav-plan-batch",
        type=int,
        nargs="+",
        default=[1, 8],
        metavar="R",
        help="robots for the costmap, planner and frontier rows (default: 1 8)",
    )


def _repeats(args) -> int:
    return getattr(args, "repeats", 20)  # the kernel section's --repeats


def _occupancy(side: int):
    import numpy as np

    from jaxquad.sim import worlds

    g = worlds.occupancy_map(worlds.make_world("warehouse", 0), resolution=_RES).grid[:side, :side]
    out = np.full((side, side), -1, np.int8)
    out[: g.shape[0], : g.shape[1]] = g
    return out


def _row(kernel, batch, compile_s, run_ms, **extra):
    return {
        "kernel": kernel,
        "batch": batch,
        "compile_s": round(compile_s, 2),
        "run_ms": round(run_ms, 3),
        "per_robot_us": round(1e3 * run_ms / batch, 2),
        **extra,
    }


def _mppi_rows(args, grid, open_rc, batch: int) -> list[dict]:
    import jax
    import jax.numpy as jnp
    import numpy as np

    from jaxquad import nav
    from jaxquad.bench import time_jitted
    from jaxquad.kernels import mppi
    from jaxquad.nav.missions import footprint
    from jaxquad.robots import load

    # The closed loops' controller: the obstacle critic checks the Go2 footprint's three covering disks.
    navp = nav.NavParams.default(n_samples=args.nav_samples, horizon=args.nav_horizon, footprint=footprint(load("go2")))
    params = navp.controller
    rng = np.random.default_rng(batch)
    rc = open_rc[rng.integers(len(open_rc), size=batch)]
    r0 = np.clip(rc - _LOCAL // 2, 0, np.array(grid.shape) - _LOCAL)
    local = np.stack([grid[r : r + _LOCAL, c : c + _LOCAL] for r, c in r0])
    origin = (r0[:, ::-1] * _RES).astype(np.float32)
    pose = np.c_[(rc[:, ::-1] + 0.5) * _RES, rng.uniform(-np.pi, np.pi, batch)].astype(np.float32)
    goal = pose + np.array([2.0, 1.0, 0.5], np.float32)
    path = pose[:, None, :2] + np.linspace(0.0, 1.0, 160)[None, :, None] * (goal - pose)[:, None, :2]
    grid = jax.jit(jax.vmap(lambda g, o: nav.cost_grid(navp, g, o, _RES)))(local, jnp.asarray(origin))
    inputs = jax.vmap(mppi.MppiInputs)(  # one robot's inputs per call
        pose=jnp.asarray(pose),
        path=jnp.asarray(path, jnp.float32),
        path_valid=jnp.ones((batch, 160), bool),
        goal=jnp.asarray(goal),
        grid=grid,  # with its depth layer, as the closed loops' controller reads it
        key=jax.random.split(jax.random.key(0), batch),
    )
    states = jax.vmap(mppi.init, in_axes=(None, 0))(params, inputs.pose)
    fn = jax.jit(jax.vmap(mppi.step, in_axes=(None, 0, 0)))
    compile_s, run_ms = time_jitted(fn, params, states, inputs, repeats=_repeats(args))
    extra = {
        "samples": args.nav_samples,
        "horizon": args.nav_horizon,
        "grid": f"{_LOCAL}x{_LOCAL}",
    }
    return [_row("mppi_step", batch, compile_s, run_ms, **extra)]


def _grid_rows(args, occ, open_rc, batch: int) -> list[dict]:
    import jax
    import jax.numpy as jnp
    import numpy as np

    from jaxquad import nav
    from jaxquad.bench import time_jitted
    from jaxquad.kernels.frontiers import FrontierParams, choose_frontier, cluster_stats, frontier_mask, label_clusters
    from jaxquad.kernels.planner import cost_to_go, step_weights

    side = occ.shape[0]
    params = nav.NavParams.default()
    grids = jnp.asarray(np.broadcast_to(occ, (batch, side, side)))
    make_cost = jax.jit(jax.vmap(lambda g: nav.cost_grid(params, g, jnp.zeros(2), _RES)))
    rows = [
        _row(
            "costmap",
            batch,
            *time_jitted(make_cost, grids, repeats=_repeats(args)),
            grid=f"{side}x{side}",
        )
    ]
    cgrid = make_cost(grids)
    # Start near one side, goals near the other side, spread over the robots.
    left = open_rc[open_rc[:, 1] < open_rc[:, 1].min() + 20]
    right = open_rc[open_rc[:, 1] > open_rc[:, 1].max() - 20]
    rng = np.random.default_rng(0)
    start = left[rng.integers(len(left), size=batch)]
    goal = right[rng.integers(len(right), size=batch)]
    to_xy = lambda rc: np.c_[(rc[:, ::-1] + 0.5) * _RES, np.zeros(len(rc))].astype(np.float32)
    plan = jax.jit(jax.vmap(nav.plan, in_axes=(None, 0, 0, 0)))
    p_args = (params, cgrid, jnp.asarray(to_xy(start)), jnp.asarray(to_xy(goal)))
    timing = time_jitted(plan, *p_args, repeats=_repeats(args))
    extra = {"grid": f"{side}x{side}", "ok": int(np.sum(np.asarray(plan(*p_args).ok)))}
    rows.append(_row("plan", batch, *timing, **extra))

    # Frontiers: the map known only within 5 m of the start; cost-to-go from the robot, then the choice.
    rr, cc = np.meshgrid(np.arange(side), np.arange(side), indexing="ij")
    near = (rr[None] - start[:, 0, None, None]) ** 2 + (cc[None] - start[:, 1, None, None]) ** 2 <= (5.0 / _RES) ** 2
    partial = jnp.asarray(np.where(near, occ[None], -1).astype(np.int8))
    fparams = FrontierParams.default()

    def explore_choice(g, s):
        cost = nav.cost_grid(params, g, jnp.zeros(2), _RES).cost
        w = step_weights(cost, params.cost_weight)
        value = cost_to_go(w, jnp.zeros(w.shape, bool).at[s[0], s[1]].set(True))
        return choose_frontier(g, _RES, value, jnp.zeros(g.shape, bool), fparams)

    def clusters(g):
        mask = frontier_mask(g, fparams.free_thresh)
        return cluster_stats(mask, label_clusters(mask))

    timing = time_jitted(jax.jit(jax.vmap(clusters)), partial, repeats=_repeats(args))
    rows.append(_row("frontier_clusters", batch, *timing, grid=f"{side}x{side}"))
    choose = jax.jit(jax.vmap(explore_choice))
    f_args = (partial, jnp.asarray(start, jnp.int32))
    timing = time_jitted(choose, *f_args, repeats=_repeats(args))
    found = int(np.sum(np.asarray(choose(*f_args).found)))
    rows.append(_row("frontier_choice", batch, *timing, grid=f"{side}x{side}", ok=found))
    return rows


def run(args: argparse.Namespace) -> dict:
    import numpy as np

    if args.nav_samples < 2 or args.nav_horizon < 1 or args.nav_grid < _LOCAL or min(args.nav_plan_batch) < 1:
        raise ValueError(
            f"--nav-samples >= 2, --nav-horizon >= 1, --nav-grid >= {_LOCAL} and --nav-plan-batch >= 1 are required"
        )
    occ = _occupancy(args.nav_grid)
    open_rc = np.argwhere(occ == 0)
    open_rc = open_rc[(open_rc.min(axis=1) > 10) & (open_rc.max(axis=1) < args.nav_grid - 10)]
    rows = []
    for batch in args.batch:
        rows += _mppi_rows(args, occ, open_rc, batch)
    for batch in args.nav_plan_batch:
        rows += _grid_rows(args, occ, open_rc, batch)
    return {"rows": rows, "resolution_m": _RES}
