"""Active loop closing for exploration: after a while without a loop closure, go back to a place mapped long ago.

A frontier explorer keeps walking into new space. Its SLAM then only chains scans to scans, and the heading
drifts with the leg odometry's (the IMU's reported yaw, a random walk) until a loop closure ties the graph to
an old node again. In the warehouse the runs that closed no loop were the ones lost (README, Exploration).
Active loop closing (Stachniss, Haehnel and Burgard, IROS 2004) sends the robot back to known places when its
uncertainty grows; here the time since the last accepted closure stands in for that uncertainty, since the
drift it lets through grows with that time.

`update` runs once per planning period. A revisit starts once `after` s have passed since the last closure
(or the last revisit) and a stored SLAM node at least `min_age` s old, not tried before, lies on a cell the
robot reaches within `max_path` m of path (its cost-to-go): the nearest such node becomes the goal, with its
heading (the camera must face what it saw then), and every node within `spacing` m of it is marked tried.
The revisit ends when a loop closes, after `dwell` s within `reach` m of the goal (the turn to its heading
included), or after `timeout` s; then the clock starts again. `after` = inf never starts one.
"""

from __future__ import annotations

import equinox as eqx
import jax.numpy as jnp
from jaxtyping import Array, Bool, Float, Int

from jaxquad.kernels.costmap import CostGrid


class RevisitParams(eqx.Module):
    after: Float[Array, ""]  # s without a loop closure (or revisit) before one starts; inf: never
    min_age: Float[Array, ""]  # s: a node younger than this is no revisit (its drift is the robot's own)
    max_path: Float[Array, ""]  # m of path to the node at most
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


def update(
    params: RevisitParams,
    state: RevisitState,
    node_pose: Float[Array, "n 3"],
    node_t: Float[Array, " n"],
    node_mask: Bool[Array, " n"],
    loops: Int[Array, ""],
    t: Float[Array, ""],
    pose: Float[Array, " 3"],
    grid: CostGrid,
    value: Float[Array, "H W"],
    elapsed: float | Float[Array, ""],
) -> RevisitState:
    """One planning period, `elapsed` s after the last: end the current revisit or start one (see the module doc).
    `node_*` are the SLAM's node slots (base poses in the map frame, stamps in s, which are stored), `loops` its
    count of accepted closures, `t` the time now (s), `value` the robot's cost-to-go on `grid` (cells x step
    weight; inf where unreachable)."""
    closed = loops > state.loops
    there = jnp.linalg.norm(pose[:2] - state.goal[:2]) < params.reach
    near_for = jnp.where(state.active & there, state.near_for + elapsed, 0.0)
    spent = jnp.where(state.active, state.elapsed + elapsed, 0.0)
    ended = state.active & (closed | (near_for >= params.dwell) | (spent >= params.timeout))
    since = jnp.where(closed | ended, 0.0, state.since + elapsed)
    going = state.active & ~ended

    h, w = value.shape
    rc = grid.cell_of(node_pose[:, :2])
    inside = (rc[:, 0] >= 0) & (rc[:, 0] < h) & (rc[:, 1] >= 0) & (rc[:, 1] < w)
    path = jnp.where(inside, value[jnp.clip(rc[:, 0], 0, h - 1), jnp.clip(rc[:, 1], 0, w - 1)], jnp.inf)
    path = path * grid.resolution
    away = jnp.linalg.norm(node_pose[:, :2] - pose[:2], axis=1) >= params.reach
    candidate = node_mask & (t - node_t >= params.min_age) & ~state.tried & (path <= params.max_path) & away
    start = ~going & (since >= params.after) & jnp.any(candidate)
    k = jnp.argmin(jnp.where(candidate, path, jnp.inf))
    near_k = node_mask & (jnp.linalg.norm(node_pose[:, :2] - node_pose[k, :2], axis=1) <= params.spacing)
    return RevisitState(
        active=going | start,
        goal=jnp.where(start, node_pose[k], state.goal),
        since=since,
        loops=loops.astype(state.loops.dtype),
        near_for=jnp.where(start, 0.0, near_for),
        elapsed=jnp.where(start, 0.0, spent),
        tried=state.tried | (start & near_k),
        started=state.started + start.astype(state.started.dtype),
        closed=state.closed + (state.active & closed).astype(state.closed.dtype),
    )
