"""Point-to-point navigation for one robot: costmap, global plan, MPPI ticks.

`plan` is the global planner (cost-to-go from the goal, descent from the robot); `step` is one control
tick of MPPI along the current plan. On a static map, `goal_table` computes the cost-to-go of a set of
goals once and `plan_to` replans by descent alone (what a fleet navigating a known map calls). Both are
pure with static shapes, so a fleet calls them per robot under `vmap` from inside its `lax.scan`.
Replanning is a separate call on purpose: under `vmap` a `lax.cond` runs both branches, so a fleet loop
replans in an outer scan (every `replan_ticks` ticks) around an inner scan of control ticks, as
`simulate_kinematic` does with the ideal kinematic model.
"""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
from jaxtyping import Array, Bool, Float, Int, Key

from jaxquad.kernels import mppi
from jaxquad.kernels.costmap import CostGrid, CostmapParams, costmap_layers
from jaxquad.kernels.footprint import footprint_disks, footprint_outline
from jaxquad.kernels.planner import cost_to_go, descend, nearest_open_cell, step_weights


class NavParams(eqx.Module):
    costmap: CostmapParams
    controller: mppi.MppiParams
    cost_weight: Float[Array, ""]  # planner step weight = 1 + cost_weight * cost / 252
    goal_tolerance: Float[Array, ""]  # m: a blocked goal (or start) moves to the nearest open cell this close
    n_path_points: int = eqx.field(static=True)
    path_stride: int = eqx.field(static=True)  # grid cells between two path points
    replan_ticks: int = eqx.field(static=True)  # control ticks between two plans

    @classmethod
    def default(
        cls,
        n_samples: int = 1000,
        horizon: int = 40,
        n_path_points: int = 160,
        path_stride: int = 4,
        replan_ticks: int = 10,
        footprint: tuple | None = None,
        footprint_padding: float = 0.0,
        outline_padding: float = 0.0,
    ) -> NavParams:
        """`footprint`: (centre, half extents) of the robot's planform rectangle in the base frame (m,
        `nav.missions.footprint`); the controller then checks the 3 disks covering it, with the costmap's
        inscribed radius at their radius, and keeps its corners and long sides' middles off lethal and unknown
        cells. Without it the robot is a disk of 0.2 m. `footprint_padding`
        (m) is added to that radius: room for the error of the pose the robot navigates by. With `footprint`,
        `outline_padding` (m) moves the outline's 6 points out of the rectangle (its corners by that much on each
        axis, its long sides' middles across), so that the body keeps about that margin also from unknown cells,
        which the costmap does not inflate."""
        costmap, controller = CostmapParams.default(), mppi.MppiParams.default(n_samples=n_samples, horizon=horizon)
        if footprint is not None:
            center, half = (jnp.asarray(a, jnp.float32) for a in footprint)
            disks, radius = footprint_disks(center, half)
            costmap = eqx.tree_at(lambda c: c.inscribed_radius, costmap, radius)
            outline = footprint_outline(center, half + outline_padding)
            controller = eqx.tree_at(lambda c: (c.footprint_disks, c.footprint_outline), controller, (disks, outline))
        costmap = eqx.tree_at(lambda c: c.inscribed_radius, costmap, costmap.inscribed_radius + footprint_padding)
        # 0.5 m goal tolerance of the planner: NavFn's in the authors' configuration.
        return cls(
            costmap=costmap,
            controller=controller,
            cost_weight=jnp.asarray(3.0, jnp.float32),
            goal_tolerance=jnp.asarray(0.5, jnp.float32),
            n_path_points=n_path_points,
            path_stride=path_stride,
            replan_ticks=replan_ticks,
        )


class Plan(eqx.Module):
    path: Float[Array, "P 2"]  # world x, y (m) from the robot towards the goal
    valid: Bool[Array, " P"]
    ok: Bool[Array, ""]  # start and goal found open and connected, path within n_path_points
    goal_rc: Int[Array, " 2"]  # the goal cell the plan leads to


class NavState(eqx.Module):
    controller: mppi.MppiState
    plan: Plan


class NavInputs(eqx.Module):
    pose: Float[Array, " 3"]  # estimated x, y (m), yaw (rad)
    goal: Float[Array, " 3"]
    grid: CostGrid
    key: Key[Array, ""]


def cost_grid(
    params: NavParams,
    occupancy: Int[Array, "H W"],
    origin: Float[Array, " 2"],
    resolution: float | Float[Array, ""],
) -> CostGrid:
    """The inflated cost grid of an occupancy grid (-1 unknown, 0..100) placed at `origin` (lower-left corner),
    with its depth layer (MPPI grades a trajectory inside the inscribed radius by it)."""
    cost, depth = costmap_layers(occupancy, resolution, params.costmap)
    return CostGrid(
        cost=cost,
        origin=jnp.asarray(origin, jnp.float32),
        resolution=jnp.asarray(resolution, jnp.float32),
        depth=depth,
    )


class GoalTable(eqx.Module):
    """Cost-to-go grids of K goals on one static map, computed once: a plan to goal k from anywhere is
    then a descent (`plan_to`), with no relaxation per robot or per replan."""

    goals: Float[Array, "K 3"]  # x, y (m), yaw (rad)
    value: Float[Array, "K H W"]  # cost-to-go of each goal's cell (cells x weight); inf where unreachable
    weight: Float[Array, "H W"]  # the planner's step weights of the map
    goal_rc: Int[Array, "K 2"]  # the goal cell each grid leads to
    goal_ok: Bool[Array, " K"]  # an open cell was found within goal_tolerance of the goal


def _goal_value(params: NavParams, grid: CostGrid, weight, goal) -> tuple[Array, Array, Array]:
    tol_cells = params.goal_tolerance / grid.resolution
    goal_rc, goal_ok = nearest_open_cell(weight, grid.cell_of(goal[:2]), tol_cells)
    source = jnp.zeros(weight.shape, bool).at[goal_rc[0], goal_rc[1]].set(goal_ok)
    return cost_to_go(weight, source), goal_rc, goal_ok


def _descent_plan(params: NavParams, grid: CostGrid, weight, value, goal_rc, goal_ok, pose, goal, layer=None) -> Plan:
    tol_cells = params.goal_tolerance / grid.resolution
    start_rc, start_ok = nearest_open_cell(weight, grid.cell_of(pose[:2]), tol_cells)
    cells, valid, complete = descend(value, weight, start_rc, params.n_path_points, params.path_stride, layer)
    ok = goal_ok & start_ok & complete
    finite = jnp.all(jnp.isfinite(pose)) & jnp.all(jnp.isfinite(goal))
    return Plan(
        path=grid.center_of(cells),
        valid=valid & finite,
        ok=ok & finite,
        goal_rc=goal_rc,
    )


def plan(
    params: NavParams,
    grid: CostGrid,
    pose: Float[Array, " 3"],
    goal: Float[Array, " 3"],
) -> Plan:
    """Global path from the robot's cell to the goal's cell on the 8-connected weighted grid."""
    weight = step_weights(grid.cost, params.cost_weight)
    value, goal_rc, goal_ok = _goal_value(params, grid, weight, goal)
    return _descent_plan(params, grid, weight, value, goal_rc, goal_ok, pose, goal)


def goal_table(params: NavParams, grid: CostGrid, goals: Float[Array, "K 3"]) -> GoalTable:
    """The cost-to-go grids of `goals` on `grid` (K relaxations, vmapped)."""
    weight = step_weights(grid.cost, params.cost_weight)
    goals = jnp.asarray(goals, jnp.float32)
    value, goal_rc, goal_ok = jax.vmap(lambda g: _goal_value(params, grid, weight, g))(goals)
    return GoalTable(goals=goals, value=value, weight=weight, goal_rc=goal_rc, goal_ok=goal_ok)


def plan_to(params: NavParams, grid: CostGrid, table: GoalTable, k: Int[Array, ""], pose: Float[Array, " 3"]) -> Plan:
    """`plan(params, grid, pose, table.goals[k])` from the precomputed grid of goal k (same path)."""
    return _descent_plan(
        params, grid, table.weight, table.value, table.goal_rc[k], table.goal_ok[k], pose, table.goals[k], layer=k
    )


def plan_from_start(
    params: NavParams,
    grid: CostGrid,
    weight: Float[Array, "H W"],
    value: Float[Array, "H W"],
    goal_rc: Int[Array, " 2"],
    pose: Float[Array, " 3"],
) -> Plan:
    """The plan from the robot to the open cell `goal_rc`, read off the cost-to-go *from the robot* `value`
    (rooted at the robot's cell, as exploration computes it to rank frontiers): the descent from the goal
    cell, reversed. It saves the relaxation rooted at the goal that `plan` runs."""
    n = params.n_path_points
    cells, valid, complete = descend(value, weight, goal_rc, n, params.path_stride)
    count = jnp.sum(valid)
    cells = cells[jnp.clip(count - 1 - jnp.arange(n), 0, n - 1)]
    ok = complete & jnp.isfinite(value[goal_rc[0], goal_rc[1]]) & jnp.all(jnp.isfinite(pose))
    return Plan(path=grid.center_of(cells), valid=(jnp.arange(n) < count) & ok, ok=ok, goal_rc=goal_rc)


def init(params: NavParams, pose: Float[Array, " 3"]) -> NavState:
    n = params.n_path_points
    empty = Plan(
        path=jnp.zeros((n, 2), jnp.float32),
        valid=jnp.zeros(n, bool),
        ok=jnp.array(False),
        goal_rc=jnp.zeros(2, jnp.int32),
    )
    return NavState(controller=mppi.init(params.controller, pose), plan=empty)


def replan(params: NavParams, state: NavState, inputs: NavInputs) -> NavState:
    return eqx.tree_at(lambda s: s.plan, state, plan(params, inputs.grid, inputs.pose, inputs.goal))


def step(params: NavParams, state: NavState, inputs: NavInputs) -> tuple[NavState, mppi.MppiOutput]:
    """One control tick along the current plan (without a valid plan, MPPI drives on the goal critics)."""
    p = state.plan
    path = jnp.where(p.ok, p.path, inputs.goal[:2])
    valid = jnp.where(p.ok, p.valid, jnp.zeros_like(p.valid).at[0].set(True))
    ctrl_in = mppi.MppiInputs(
        pose=inputs.pose,
        path=path,
        path_valid=valid,
        goal=inputs.goal,
        grid=inputs.grid,
        key=inputs.key,
    )
    ctrl, out = mppi.step(params.controller, state.controller, ctrl_in)
    return NavState(controller=ctrl, plan=p), out


class NavTrace(eqx.Module):
    pose: Float[Array, "T 3"]  # after each tick
    cmd: Float[Array, "T 3"]
    arrived: Bool[Array, " T"]
    recovering: Bool[Array, " T"]
    plan_ok: Bool[Array, " T"]


def simulate_kinematic(
    params: NavParams,
    grid: CostGrid,
    start: Float[Array, " 3"],
    goal: Float[Array, " 3"],
    key: Key[Array, ""],
    n_plans: int,
) -> NavTrace:
    """Closed loop in the ideal kinematic model (pose known, commands executed exactly).

    n_plans planning periods of replan_ticks control ticks each."""
    dt = params.controller.dt

    def tick(carry, k):
        pose, state = carry
        state, out = step(params, state, NavInputs(pose=pose, goal=goal, grid=grid, key=k))
        pose = mppi.rollout(pose, out.cmd[None], dt)[0]
        return (pose, state), (
            pose,
            out.cmd,
            out.arrived,
            out.recovering,
            state.plan.ok,
        )

    def period(carry, k):
        pose, state = carry
        state = replan(params, state, NavInputs(pose=pose, goal=goal, grid=grid, key=k))
        return jax.lax.scan(tick, (pose, state), jax.random.split(k, params.replan_ticks))

    carry = (jnp.asarray(start, jnp.float32), init(params, start))
    _, trace = jax.lax.scan(period, carry, jax.random.split(key, n_plans))
    return NavTrace(*(x.reshape(-1, *x.shape[2:]) for x in trace))
