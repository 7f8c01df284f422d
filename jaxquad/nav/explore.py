"""Frontier exploration for one robot: which goal to drive to next, with a blacklist of hopeless goals.

`update` runs once per planning period (explore_lite re-plans every few seconds): it measures the
progress towards the current goal, blacklists the goal (a disk of `blacklist_radius`) after
`blacklist_timeout` seconds without the distance to it shrinking by `progress_margin`, or once the robot
has come within `reach_radius` of it (a frontier the camera could resolve is gone by then: what is left
lies in a blind spot, inside furniture seen edge-on or behind a wall), computes the robot's cost-to-go
over known free space, and picks a reachable frontier cluster (`kernels.frontiers`): the current goal's
own cluster while it lasts (commitment: `keep`, the disk of `blacklist_radius` around the goal), else the
nearest. The goal's yaw faces from the robot towards it. `done` is set when no reachable, large enough,
non-blacklisted frontier is left. Navigation to the goal is `jaxquad.nav`.
"""

from __future__ import annotations

import equinox as eqx
import jax.numpy as jnp
from jaxtyping import Array, Bool, Float, Int

from jaxquad.kernels.costmap import CostGrid
from jaxquad.kernels.frontiers import FrontierChoice, FrontierParams, choose_frontier
from jaxquad.kernels.planner import cost_to_go, nearest_open_cell, step_weights


class ExploreParams(eqx.Module):
    frontier: FrontierParams
    cost_weight: Float[Array, ""]  # planner step weight = 1 + cost_weight * cost / 252
    blacklist_timeout: Float[Array, ""]  # s without progress before the goal is blacklisted
    progress_margin: Float[Array, ""]  # m the distance to the goal must shrink by to count as progress
    blacklist_radius: Float[Array, ""]  # m around a blacklisted goal (and around the goal kept)
    reach_radius: Float[Array, ""]  # m: a goal this close is done with (blacklisted if its frontier is left)
    start_tolerance: Float[Array, ""]  # m: a robot on a blocked cell plans from the nearest open cell

    @classmethod
    def default(cls, **frontier_overrides: float) -> ExploreParams:
        f32 = lambda v: jnp.asarray(v, jnp.float32)
        return cls(
            frontier=FrontierParams.default(**frontier_overrides),
            cost_weight=f32(3.0),
            blacklist_timeout=f32(30.0),
            progress_margin=f32(0.1),
            blacklist_radius=f32(0.5),
            # The camera's blind distance: 0.29 m from the base to the lens plus its 0.2 m minimum range.
            reach_radius=f32(0.5),
            start_tolerance=f32(0.5),
        )


class ExploreState(eqx.Module):
    blacklist: Bool[Array, "H W"]
    goal: Float[Array, " 3"]  # world x, y (m), yaw (rad)
    has_goal: Bool[Array, ""]
    best_distance: Float[Array, ""]  # m, smallest distance to the goal so far
    since_progress: Float[Array, ""]  # s
    done: Bool[Array, ""]


def init(shape: tuple[int, int]) -> ExploreState:
    return ExploreState(
        blacklist=jnp.zeros(shape, bool),
        goal=jnp.zeros(3, jnp.float32),
        has_goal=jnp.array(False),
        best_distance=jnp.asarray(jnp.inf, jnp.float32),
        since_progress=jnp.zeros((), jnp.float32),
        done=jnp.array(False),
    )


def robot_value(
    params: ExploreParams, grid: CostGrid, pose: Float[Array, " 3"]
) -> tuple[Float[Array, "H W"], Float[Array, "H W"]]:
    """(planner step weights, cost-to-go from the robot's cell) on `grid` (a robot on a blocked cell
    starts from the nearest open cell within `start_tolerance`)."""
    h, w = grid.cost.shape
    weight = step_weights(grid.cost, params.cost_weight)
    start, _ = nearest_open_cell(weight, grid.cell_of(pose[:2]), params.start_tolerance / grid.resolution)
    return weight, cost_to_go(weight, jnp.zeros((h, w), bool).at[start[0], start[1]].set(True))


def update(
    params: ExploreParams,
    state: ExploreState,
    occupancy: Int[Array, "H W"],
    grid: CostGrid,
    pose: Float[Array, " 3"],
    elapsed: float | Float[Array, ""],
    value: Float[Array, "H W"] | None = None,
) -> tuple[ExploreState, FrontierChoice]:
    """One planning period: progress check, blacklist, new frontier goal. `grid` is `occupancy`'s costmap;
    `value` the robot's cost-to-go on it when already computed (`robot_value`)."""
    h, w = occupancy.shape
    distance = jnp.linalg.norm(pose[:2] - state.goal[:2])
    progressed = distance < state.best_distance - params.progress_margin
    since = jnp.where(progressed, 0.0, state.since_progress + elapsed)
    best = jnp.where(progressed, distance, state.best_distance)
    drop = state.has_goal & ((since > params.blacklist_timeout) | (distance < params.reach_radius))
    rr, cc = jnp.meshgrid(jnp.arange(h), jnp.arange(w), indexing="ij")
    g = grid.cell_of(state.goal[:2])
    disk = ((rr - g[0]) ** 2 + (cc - g[1]) ** 2).astype(jnp.float32) <= (params.blacklist_radius / grid.resolution) ** 2
    blacklist = state.blacklist | (drop & disk)

    if value is None:
        _, value = robot_value(params, grid, pose)
    keep = disk & state.has_goal & ~drop
    # A goal already within reach of the robot is one it stands at without seeing (it would also turn there).
    r = grid.cell_of(pose[:2])
    here = ((rr - r[0]) ** 2 + (cc - r[1]) ** 2).astype(jnp.float32) <= (params.reach_radius / grid.resolution) ** 2
    choice = choose_frontier(occupancy, grid.resolution, value, blacklist | here, params.frontier, keep)

    xy = grid.center_of(choice.goal_rc)
    goal = jnp.append(xy, jnp.arctan2(xy[1] - pose[1], xy[0] - pose[0]))
    # A goal that moved by more than the blacklist radius is a new goal: the progress clock restarts.
    same = state.has_goal & ~drop & (jnp.linalg.norm(xy - state.goal[:2]) <= params.blacklist_radius)
    new_distance = jnp.linalg.norm(xy - pose[:2])
    state = ExploreState(
        blacklist=blacklist,
        goal=goal,
        has_goal=choice.found,
        best_distance=jnp.where(same, best, new_distance),
        since_progress=jnp.where(same, since, 0.0),
        done=~choice.found,
    )
    return state, choice
