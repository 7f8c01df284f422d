"""Frontier exploration for one robot: which goal to drive to next, with a blacklist of hopeless goals.

`update` runs once per planning period (explore_lite re-plans every few seconds): it measures the
progress towards the current goal, blacklists the goal (a disk of `blacklist_radius`) after
`blacklist_timeout` seconds without the distance to it shrinking by `progress_margin`, or once the robot
has come within `reach_radius` of it (a frontier the camera could resolve is gone by then: what is left
lies in a blind spot, inside furniture seen edge-on or behind a wall), computes the robot's cost-to-go
over known free space, and picks a reachable frontier cluster (`kernels.frontiers`): the current goal's
own cluster while it lasts (commitment: `keep`, the disk of `blacklist_radius` around the goal), else the
nearest. The goal's yaw faces from the robot towards it.

When no such frontier is left, a view goal (`kernels.view_goals`) takes its place: a reachable cell from which a
frontier the robot cannot walk up to (too short, behind a gap too narrow for it, or blacklisted) lies in plain view,
the goal's yaw facing it. Once the robot has stood within `view_radius` of it, turned to within `view_yaw_tolerance`,
for `view_dwell` seconds (the SLAM's nodes then hold the view), or after `blacklist_timeout` seconds without
progress (its goal then blacklisted too), the cell looked at and its surroundings (a disk of `view_done_radius`) are
marked `viewed`, and no view goal looks there again; so is every frontier cell scored as a target that no reachable
cell sees (`kernels.view_goals`' `hopeless`), while no reachable frontier is left, so that the next period scores the
next ones. The current target is kept while it is in view (commitment, as for frontiers). A frontier that becomes
reachable goes first. `done` is set when neither kind of goal is left and no frontier cell is left to score.
Navigation to the goal is `jaxquad.nav`.
"""

from __future__ import annotations

import equinox as eqx
import jax.numpy as jnp
from jaxtyping import Array, Bool, Float, Int

from jaxquad.kernels.costmap import CostGrid
from jaxquad.kernels.frontiers import FrontierChoice, FrontierParams, choose_frontier, frontier_clusters
from jaxquad.kernels.lie import wrap_angle
from jaxquad.kernels.planner import cost_to_go, nearest_open_cell, step_weights
from jaxquad.kernels.view_goals import ViewParams, choose_view


class ExploreParams(eqx.Module):
    frontier: FrontierParams
    cost_weight: Float[Array, ""]  # planner step weight = 1 + cost_weight * cost / 252
    blacklist_timeout: Float[Array, ""]  # s without progress before the goal is blacklisted
    progress_margin: Float[Array, ""]  # m the distance to the goal must shrink by to count as progress
    blacklist_radius: Float[Array, ""]  # m around a blacklisted goal (and around the goal kept)
    reach_radius: Float[Array, ""]  # m: a goal this close is done with (blacklisted if its frontier is left)
    start_tolerance: Float[Array, ""]  # m: a robot on a blocked cell plans from the nearest open cell
    view: ViewParams
    view_goals: bool = eqx.field(static=True)  # look at frontiers out of reach once no reachable one is left
    view_radius: Float[Array, ""]  # m: a view goal this close ...
    view_yaw_tolerance: Float[Array, ""]  # rad: ... with the heading this close to its yaw ...
    view_dwell: Float[Array, ""]  # s: ... for this long is done with
    view_done_radius: Float[Array, ""]  # m around a frontier cell looked at: no view goal looks there again

    @classmethod
    def default(cls, view_goals: bool = True, **frontier_overrides: float) -> ExploreParams:
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
            view=ViewParams.default(),
            view_goals=bool(view_goals),
            # The navigation's arrival tolerances (0.25 m, 0.25 rad) and a margin (the gait drifts a standing robot),
            # and three planning periods standing there: the SLAM adds a node on 0.02 rad of rotation or 0.1 m of
            # travel, at most every 0.5 s, and the map needs two scans' misses for a free cell.
            view_radius=f32(0.3),
            view_yaw_tolerance=f32(0.35),
            view_dwell=f32(3.0),
            # Three cells: a view that revealed some of a frontier moves its cells farther than that; one that
            # revealed nothing leaves them, and the neighbours of the cell looked at are looked at no more.
            view_done_radius=f32(0.15),
        )


class ExploreState(eqx.Module):
    blacklist: Bool[Array, "H W"]
    goal: Float[Array, " 3"]  # world x, y (m), yaw (rad)
    has_goal: Bool[Array, ""]
    best_distance: Float[Array, ""]  # m, smallest distance to the goal so far
    since_progress: Float[Array, ""]  # s
    done: Bool[Array, ""]
    viewing: Bool[Array, ""]  # the goal is a view goal
    target: Float[Array, " 2"]  # world x, y (m) of the frontier cell a view goal looks at
    viewed: Bool[Array, "H W"]  # surroundings of the frontiers already looked at
    view_time: Float[Array, ""]  # s the robot has stood at its view goal, turned to it


def init(shape: tuple[int, int]) -> ExploreState:
    return ExploreState(
        blacklist=jnp.zeros(shape, bool),
        goal=jnp.zeros(3, jnp.float32),
        has_goal=jnp.array(False),
        best_distance=jnp.asarray(jnp.inf, jnp.float32),
        since_progress=jnp.zeros((), jnp.float32),
        done=jnp.array(False),
        viewing=jnp.array(False),
        target=jnp.zeros(2, jnp.float32),
        viewed=jnp.zeros(shape, bool),
        view_time=jnp.zeros((), jnp.float32),
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
    """One planning period: progress check, blacklist, new frontier goal, else a view goal. `grid` is
    `occupancy`'s costmap; `value` the robot's cost-to-go on it when already computed (`robot_value`). Returns
    the frontier choice; the goal taken (frontier or view) is the state's."""
    h, w = occupancy.shape
    distance = jnp.linalg.norm(pose[:2] - state.goal[:2])
    progressed = distance < state.best_distance - params.progress_margin
    since = jnp.where(progressed, 0.0, state.since_progress + elapsed)
    best = jnp.where(progressed, distance, state.best_distance)
    stalled = state.has_goal & (since > params.blacklist_timeout)
    drop = ~state.viewing & (stalled | (state.has_goal & (distance < params.reach_radius)))
    turned = jnp.abs(wrap_angle(pose[2] - state.goal[2])) < params.view_yaw_tolerance
    there = state.has_goal & state.viewing & (distance < params.view_radius) & turned
    view_time = jnp.where(there, state.view_time + elapsed, 0.0)
    looked = state.viewing & (stalled | (view_time >= params.view_dwell))
    rr, cc = jnp.meshgrid(jnp.arange(h), jnp.arange(w), indexing="ij")

    def disk(xy, radius):
        g = grid.cell_of(xy)
        d2 = ((rr - g[0]) ** 2 + (cc - g[1]) ** 2).astype(jnp.float32)
        return d2 <= (radius / grid.resolution) ** 2

    around_goal = disk(state.goal[:2], params.blacklist_radius)
    # A goal of either kind the robot made no progress towards is blacklisted: no goal of either kind goes there.
    blacklist = state.blacklist | ((drop | (state.viewing & stalled)) & around_goal)
    viewed = state.viewed | (looked & disk(state.target, params.view_done_radius))

    if value is None:
        _, value = robot_value(params, grid, pose)
    keep = around_goal & state.has_goal & ~state.viewing & ~drop
    # A goal already within reach of the robot is one it stands at without seeing (it would also turn there).
    here = disk(pose[:2], params.reach_radius)
    clusters = frontier_clusters(occupancy, params.frontier.free_thresh)
    choice = choose_frontier(occupancy, grid.resolution, value, blacklist | here, params.frontier, keep, clusters)
    if params.view_goals:
        kept = jnp.where(state.viewing & state.has_goal & ~looked, grid.cell_of(state.target), -1)
        view_value = jnp.where(blacklist, jnp.inf, value)
        args = (view_value, grid.cell_of(pose[:2]), viewed, params.frontier.free_thresh, params.view, clusters, kept)
        view = choose_view(occupancy, grid.resolution, *args)
        viewing = ~choice.found & view.found
        # While views are sought, the targets no reachable cell sees are set aside, so the next ones get scored,
        # and exploration is not done while any are left to score.
        viewed = viewed | (view.hopeless & ~choice.found)
        pending = ~choice.found & (view.n_left > 0)
        view_rc, target_rc = view.goal_rc, view.target_rc
    else:
        viewing = pending = jnp.array(False)
        view_rc = target_rc = choice.goal_rc

    xy = grid.center_of(jnp.where(viewing, view_rc, choice.goal_rc))
    target = jnp.where(viewing, grid.center_of(target_rc), state.target)
    toward = jnp.where(viewing, target, xy)
    origin = jnp.where(viewing, xy, pose[:2])
    goal = jnp.append(xy, jnp.arctan2(toward[1] - origin[1], toward[0] - origin[0]))
    # A goal that moved by more than the blacklist radius, or changed kind, is a new goal: the clocks restart; the
    # time spent looking counts for its own target only.
    kept_goal = state.has_goal & ~drop & ~looked & (viewing == state.viewing)
    same = kept_goal & (jnp.linalg.norm(xy - state.goal[:2]) <= params.blacklist_radius)
    same_target = same & (jnp.linalg.norm(target - state.target) <= params.view_done_radius)
    new_distance = jnp.linalg.norm(xy - pose[:2])
    state = ExploreState(
        blacklist=blacklist,
        goal=goal,
        has_goal=choice.found | viewing,
        best_distance=jnp.where(same, best, new_distance),
        since_progress=jnp.where(same, since, 0.0),
        done=~(choice.found | viewing | pending),
        viewing=viewing,
        target=target,
        viewed=viewed,
        view_time=jnp.where(same_target, view_time, 0.0),
    )
    return state, choice
