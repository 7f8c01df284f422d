"""Active loop closing for exploration: after a while without a loop closure, go back to a place mapped long ago.

A frontier explorer keeps walking into new space. Its SLAM then only chains scans to scans, and the heading
drifts with the leg odometry's (the IMU's reported yaw, a random walk) until a loop closure ties the graph to
an old node again. In the warehouse the runs that closed no loop were the ones lost (README, Exploration).
Active loop closing (Stachniss, Haehnel and Burgard, IROS 2004) sends the robot back to known places when its
uncertainty grows; here the time since the last accepted closure stands in for that uncertainty, since the
drift it lets through grows with that time.

`update` runs once per planning period. A revisit starts once `after` s have passed since the last closure
(or the last revisit) and a stored SLAM node at least `min_age` s old, not tried before, lies on a cell the
robot reaches at a path cost of at most `max_path` (the planner's cost-to-go: metres in the open, more near
obstacles, whose cells weigh up to 4 times): the cheapest such node becomes the goal, with its heading (the camera
must face what it saw then). It ends when a loop closes, after `dwell` s within `reach` m of the goal (where the
navigation turns the robot to the goal's heading), or after `timeout` s; the nodes within `spacing` m of its goal,
where it began and where it ended (the nodes added there meanwhile), are then tried, and the clock starts
again. `after` = inf never starts one; nor does a robot whose run has ended.
"""

from __future__ import annotations

import equinox as eqx
import jax.numpy as jnp
from jaxtyping import Array, Bool, Float, Int

from jaxquad.kernels.costmap import CostGrid


class RevisitParams(eqx.Module):
    after: Float[Array, ""]  # s without a loop closure (or revisit) before one starts; inf: never
    min_age: Float[Array, ""]  # s: a node younger than this is no revisit (its drift is the robot's own)
    max_path: Float[Array, ""]  # path cost to the node at most (m in the open; cells near obstacles weigh more)
    spacing: Float[Array, ""]  # m: nodes this close to a revisited one are not tried again
    reach: Float[Array, ""]  # m from the goal that counts as there
    dwell: Float[Array, ""]  # s there (turning to the node's heading) before the revisit ends
    timeout: Float[Array, ""]  # s a revisit may last

    @classmethod
    def default(cls, **overrides: float) -> RevisitParams:
        values = dict(after=jnp.inf, min_age=60.0, max_path=6.0, spacing=1.5, reach=0.5, dwell=4.0, timeout=40.0)
        values.update(overrides)
        return cls(**{k: jnp.asarray(v, jnp.float32) for k, v in values.items()})


class RevisitState(eqx.Module):
    active: Bool[Array, ""]
    goal: Float[Array, " 3"]  # the node's base pose: world x, y (m), yaw (rad)
    since: Float[Array, ""]  # s since the last loop closure or the end of the last revisit
    loops: Int[Array, ""]  # the SLAM's count of accepted closures at the last update
    near_for: Float[Array, ""]  # s within `reach` of the goal
    elapsed: Float[Array, ""]  # s since this revisit began
    tried: Bool[Array, " n"]  # node slots revisited (or near one that was)
    started: Int[Array, ""]  # revisits begun
    closed: Int[Array, ""]  # revisits ended by a loop closure


def init(n_nodes: int) -> RevisitState:
    zero_f, zero_i = jnp.zeros((), jnp.float32), jnp.zeros((), jnp.int32)
    return RevisitState(
        active=jnp.array(False),
        goal=jnp.zeros(3, jnp.float32),
        since=zero_f,
        loops=zero_i,
        near_for=zero_f,
        elapsed=zero_f,
        tried=jnp.zeros(n_nodes, bool),
        started=zero_i,
        closed=zero_i,
    )


class Nodes(eqx.Module):
    """The SLAM's node slots (`jaxquad.slam.SlamState`: graph poses, stamps, which are stored)."""

    pose: Float[Array, "n 3"]  # base pose in the map frame: x, y (m), yaw (rad)
    t: Float[Array, " n"]  # s
    mask: Bool[Array, " n"]


def _near(nodes: Nodes, xy: Float[Array, " 2"], radius: Float[Array, ""]) -> Bool[Array, " n"]:
    return nodes.mask & (jnp.linalg.norm(nodes.pose[:, :2] - xy, axis=1) <= radius)


def _cheapest(
    params: RevisitParams,
    tried: Bool[Array, " n"],
    nodes: Nodes,
    t: Float[Array, ""],
    pose: Float[Array, " 3"],
    grid: CostGrid,
    value: Float[Array, "H W"],
) -> tuple[Bool[Array, ""], Int[Array, ""]]:
    """(whether a node qualifies, the cheapest one's slot): old enough, untried, within `max_path`, not here."""
    path = grid.lookup(value, nodes.pose[:, :2], jnp.inf) * grid.resolution
    here = _near(nodes, pose[:2], params.reach)
    ok = nodes.mask & (t - nodes.t >= params.min_age) & ~tried & (path <= params.max_path) & ~here
    return jnp.any(ok), jnp.argmin(jnp.where(ok, path, jnp.inf))


def update(
    params: RevisitParams,
    state: RevisitState,
    nodes: Nodes,
    loops: Int[Array, ""],
    t: Float[Array, ""],
    pose: Float[Array, " 3"],
    grid: CostGrid,
    value: Float[Array, "H W"],
    elapsed: float | Float[Array, ""],
    running: Bool[Array, ""] | bool = True,
) -> RevisitState:
    """One planning period, `elapsed` s after the last: end the current revisit or start one (see the module doc).
    `loops` is the SLAM's count of accepted closures, `t` the time now (s), `value` the robot's cost-to-go on
    `grid` (cells x step weight; inf where unreachable); `running`: the robot's run has not ended."""
    running = jnp.asarray(running, bool)
    closed = loops > state.loops
    there = jnp.linalg.norm(pose[:2] - state.goal[:2]) < params.reach
    near_for = jnp.where(state.active & there, state.near_for + elapsed, 0.0)
    spent = jnp.where(state.active, state.elapsed + elapsed, 0.0)
    ended = state.active & (closed | (near_for >= params.dwell) | (spent >= params.timeout) | ~running)
    since = jnp.where(closed | ended, 0.0, state.since + elapsed)
    going = state.active & ~ended
    tried = state.tried | (ended & _near(nodes, state.goal[:2], params.spacing))

    found, k = _cheapest(params, tried, nodes, t, pose, grid, value)
    start = running & ~going & (since >= params.after) & found
    return RevisitState(
        active=going | start,
        goal=jnp.where(start, nodes.pose[k], state.goal),
        since=since,
        loops=loops.astype(state.loops.dtype),
        near_for=jnp.where(start, 0.0, near_for),
        elapsed=jnp.where(start, 0.0, spent),
        tried=tried | (start & _near(nodes, nodes.pose[k, :2], params.spacing)),
        started=state.started + start.astype(state.started.dtype),
        closed=state.closed + (state.active & closed).astype(state.closed.dtype),
    )
