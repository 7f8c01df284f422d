"""MPPI critics: each a pure function of the sampled trajectories, returning one cost per sample (S,).

As in Nav2's MPPI controller, the total cost is a weighted sum of small independent critics. The
trajectories are the planar states after each model step, `traj` (S, T, 3) = x, y, theta (world
frame), driven by the body-frame commands `u` (S, T, 3) = vx, vy, yaw rate. Near the goal
(`near_goal`) the goal critics take over from the path critics.
"""

from __future__ import annotations

import jax.numpy as jnp
from jaxtyping import Array, Bool, Float

from jaxquad.kernels.costmap import INSCRIBED, LETHAL, UNKNOWN, CostGrid
from jaxquad.kernels.lie import R2, wrap_angle


def footprint_cost(
    traj: Float[Array, "S T 3"], grid: CostGrid, p_base_disk: Float[Array, "K 2"]
) -> Float[Array, "S T"]:
    """Cost of the worst of the footprint's covering disks (centres `p_base_disk` in the base frame, m) at each
    pose: the cell under each disk centre, lethal off the grid."""
    return jnp.max(grid.cost_at(_disk_centres(traj, p_base_disk)), axis=-1)


def _disk_centres(traj: Float[Array, "S T 3"], p_base_disk: Float[Array, "K 2"]) -> Float[Array, "S T K 2"]:
    R_world_base = R2(traj[..., 2])  # (S, T, 2, 2)
    return traj[..., None, :2] + jnp.einsum("stij,kj->stki", R_world_base, p_base_disk)


def turn_is_clear(
    pose: Float[Array, " 3"], grid: CostGrid, p_base_disk: Float[Array, "K 2"], n_headings: int = 32
) -> Bool[Array, ""]:
    """Whether a turn in place at `pose` keeps the footprint's covering disks off every known obstacle: below
    inscribed cost at `n_headings` headings around the full circle (between two the disks move at most
    |disk centre| x 2 pi / n_headings). Unknown cells do not block: turning is how a robot looks at them."""
    yaw = pose[2] + jnp.arange(n_headings, dtype=jnp.float32) * (2.0 * jnp.pi / n_headings)
    cost = grid.cost_at(pose[:2] + jnp.einsum("nij,kj->nki", R2(yaw), p_base_disk))  # (N, K)
    return ~jnp.any((cost >= INSCRIBED) & (cost != UNKNOWN))


def obstacle(
    traj: Float[Array, "S T 3"],
    grid: CostGrid,
    collision_cost: Float[Array, ""],
    p_base_disk: Float[Array, "K 2"],
    p_base_outline: Float[Array, "C 2"] | None = None,
) -> Float[Array, " S"]:
    """Mean inflation cost (0..1 of 252) along the trajectory at the worst of the footprint's covering disks
    (centres `p_base_disk` in the base frame, m; `kernels.footprint.footprint_disks`), plus, if a disk centre
    enters a cell at inscribed cost or above (lethal, inscribed, unknown or off the map), `collision_cost` x
    (1 + the deepest and the mean depth inside the inscribed radius along it, each 0..1; `CostGrid.depth`).
    With the costmap's inscribed radius at the disks' radius that is the footprint touching an obstacle, to
    within the grid's resolution (distances run between cell centres); with a safety padding on the radius it
    is entering the padding. The depth grades what a flat collision cost cannot: a robot that has drifted into
    the padding, where every sample enters it, prefers the samples that leave it soonest and go least deep.
    Unknown cells beyond the inflation have depth 0: a sample entering unknown space alone costs the collision
    cost once. Unknown cells are not inflated, so a footprint's corner can reach into cells no scan has seen (an
    obstacle's face behind the robot) while its disks' centres stay clear: with `p_base_outline` (points of the
    footprint's outline, base frame, m; `kernels.footprint.footprint_outline`) a sample also collides where one of
    them lands on a lethal or unknown cell."""
    centres = _disk_centres(traj, p_base_disk)
    cost = jnp.max(grid.cost_at(centres), axis=-1)  # footprint_cost, from the centres computed once
    hit = jnp.any(cost >= INSCRIBED, axis=-1)
    if p_base_outline is not None and p_base_outline.shape[0]:
        hit = hit | jnp.any(grid.cost_at(_disk_centres(traj, p_base_outline)) >= LETHAL, axis=(-2, -1))
    soft = jnp.mean(jnp.minimum(cost, INSCRIBED - 1) / (INSCRIBED - 1), axis=-1)
    depth = jnp.max(grid.depth_at(centres), axis=-1)  # (S, T)
    graded = 1.0 + jnp.max(depth, axis=-1) + jnp.mean(depth, axis=-1)
    return soft + jnp.where(hit, collision_cost * graded, 0.0)


def goal_distance(
    traj: Float[Array, "S T 3"], goal: Float[Array, " 3"], near_goal: Bool[Array, ""]
) -> Float[Array, " S"]:
    """Mean distance (m) of the trajectory to the goal position, near the goal only."""
    d = jnp.linalg.norm(traj[..., :2] - goal[:2], axis=-1)
    return jnp.where(near_goal, jnp.mean(d, axis=-1), 0.0)


def goal_heading(
    traj: Float[Array, "S T 3"], goal: Float[Array, " 3"], near_goal: Bool[Array, ""]
) -> Float[Array, " S"]:
    """Mean absolute heading error (rad) to the goal's yaw, near the goal only."""
    err = jnp.abs(wrap_angle(traj[..., 2] - goal[2]))
    return jnp.where(near_goal, jnp.mean(err, axis=-1), 0.0)


def path_follow(
    traj: Float[Array, "S T 3"], carrot: Float[Array, " 2"], near_goal: Bool[Array, ""]
) -> Float[Array, " S"]:
    """Distance (m) from the trajectory's end to the path point a lookahead ahead of the robot."""
    d = jnp.linalg.norm(traj[:, -1, :2] - carrot, axis=-1)
    return jnp.where(near_goal, 0.0, d)


def path_align(
    traj: Float[Array, "S T 3"], window: Float[Array, "K 2"], near_goal: Bool[Array, ""]
) -> Float[Array, " S"]:
    """Mean distance (m) from each trajectory point to the nearest point of the local path window."""
    d2 = jnp.sum((traj[:, :, None, :2] - window[None, None]) ** 2, axis=-1)  # (S, T, K)
    return jnp.where(near_goal, 0.0, jnp.mean(jnp.sqrt(jnp.min(d2, axis=-1)), axis=-1))


def path_heading(
    traj: Float[Array, "S T 3"], carrot: Float[Array, " 2"], near_goal: Bool[Array, ""]
) -> Float[Array, " S"]:
    """Mean absolute angle (rad) between the heading and the direction to the carrot: walk forwards."""
    delta = carrot - traj[..., :2]
    far = jnp.sum(delta**2, axis=-1) > 0.01  # the direction is undefined on the carrot itself
    err = jnp.abs(wrap_angle(jnp.arctan2(delta[..., 1], delta[..., 0]) - traj[..., 2]))
    return jnp.where(near_goal, 0.0, jnp.mean(jnp.where(far, err, 0.0), axis=-1))


def smoothness(u: Float[Array, "S T 3"], u_prev: Float[Array, " 3"]) -> Float[Array, " S"]:
    """Mean squared change of the command between steps, the first against the last command sent."""
    du = jnp.diff(jnp.concatenate([jnp.broadcast_to(u_prev, u[:, :1].shape), u], axis=1), axis=1)
    return jnp.mean(jnp.sum(du**2, axis=-1), axis=-1)
