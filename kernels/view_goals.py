"""View goals: a reachable place from which to look at a frontier the robot cannot walk up to.

A frontier that `kernels.frontiers` cannot use (a cluster shorter than its `min_size`, no reachable free cell next
to it, or its goal blacklisted after the robot stood there and still saw nothing) may still be seen from farther
away: a slot between a box and a wall, too narrow to enter, is seen only from its mouth, looking in. Targets are
frontier cells of clusters at least `min_size` long, not in `excluded`: the `n_scored` of them nearest the robot
(straight-line distance). Cells, not clusters: one cluster may run from a slot's visible mouth along a box's face
whose unknown inside no place sees, and a single cell standing for it (its centroid's, say) may lie on the hidden part.
From a target, `n_rays` rays (evenly spread over the full turn) are marched in steps of a quarter cell through known
free cells; each ray's free length is the distance of its last sample before a cell that is not free (the target's
own cell excepted) or leaves the grid. A cell is in view of the target when its centre lies within the free lengths
of the two rays around its bearing, so the straight line from it to the target crosses free cells only (up to the
rays' spacing, under a cell at `max_range` with the default 360 rays). Candidates are the reachable cells (finite
cost-to-go from the robot) in view of a target at a distance within [min_range, max_range]; each costs its
cost-to-go plus `range_weight` times its distance to the target (cells), and the goal is the cheapest candidate over
the targets scored. The robot stands there facing the target. Every candidate in view costs about the robot's path to
the target, the last stretch seen instead of walked; a `range_weight` above 1 takes the robot as near as it can see
from (a slot is then looked into from its mouth, along it, not glimpsed from afar at a slant), where the depth noise
is least.

`excluded` is where the caller has already looked, and the targets scored that no candidate sees (`hopeless`, the
unknown inside a box behind its mapped faces, say), which the caller excludes in turn (each cell alone: its
neighbours may be seen) so that the next call scores the next ones; `n_left` counts the frontier cells still to score.
"""

from __future__ import annotations

import math

import equinox as eqx
import jax
import jax.numpy as jnp
from jaxtyping import Array, Bool, Float, Int

from jaxquad.kernels.frontiers import Clusters, free_cells, frontier_clusters

_STEP = 0.25  # cells between two samples of a ray


class ViewParams(eqx.Module):
    n_rays: int = eqx.field(static=True)  # rays cast from each target over the full turn
    n_scored: int = eqx.field(static=True)  # target cells scored per call (those nearest the robot)
    reach_cells: int = eqx.field(static=True)  # cells the cast reaches (sizes it): max_range beyond is cut there
    min_size: Float[Array, ""]  # m: shorter clusters are not looked at
    min_range: Float[Array, ""]  # m: nearest a goal may stand from its target
    max_range: Float[Array, ""]  # m: farthest a goal may stand from its target
    range_weight: Float[Array, ""]  # cost per cell of the goal's distance to its target, beside the path's

    @classmethod
    def default(cls, **overrides) -> ViewParams:
        # 0.6 m: the camera's blind distance (0.29 m from the base to the lens plus its 0.2 m minimum range) and a
        # margin; 2.5 m: the depth noise (1 % of z^2) is 6 cm there, about a cell; 50 cells: 2.5 m at 0.05 m.
        values = {
            "n_rays": 360,
            "n_scored": 16,
            "reach_cells": 50,
            "min_size": 0.2,
            "min_range": 0.6,
            "max_range": 2.5,
            "range_weight": 2.0,
        }
        values.update(overrides)
        static = {k: int(values.pop(k)) for k in ("n_rays", "n_scored", "reach_cells")}
        return cls(**static, **{k: jnp.asarray(v, jnp.float32) for k, v in values.items()})


class ViewChoice(eqx.Module):
    found: Bool[Array, ""]  # False: none of the targets scored is in view of a reachable cell
    goal_rc: Int[Array, " 2"]  # the reachable cell to look from
    target_rc: Int[Array, " 2"]  # the frontier cell to look at
    cost: Float[Array, ""]  # the goal's cost (inf when not found)
    n_targets: Int[Array, ""]  # frontier cells of clusters long enough, not excluded
    scored_rc: Int[Array, "K 2"]  # the targets scored: the n_scored nearest the robot, then the kept one
    hopeless: Bool[Array, "H W"]  # the targets scored that no reachable cell within the ranges has in view
    n_left: Int[Array, ""]  # targets (as n_targets counts them) not hopeless


def free_lengths(
    free: Bool[Array, "H W"], target_rc: Int[Array, " 2"], n_rays: int, max_cells: float
) -> Float[Array, " n_rays"]:
    """Per ray from the centre of `target_rc` (bearing 2 pi k / n_rays from the +col axis towards +row): the
    distance (cells) of its last sample before a cell that is not `free` (the target's own cell excepted) or
    leaves the grid, at most `max_cells`."""
    h, w = free.shape
    s = _STEP * jnp.arange(1, math.ceil(max_cells / _STEP) + 1, dtype=jnp.float32)
    a = 2 * jnp.pi * jnp.arange(n_rays, dtype=jnp.float32) / n_rays
    centre = target_rc.astype(jnp.float32) + 0.5
    rows = jnp.floor(centre[0] + jnp.sin(a)[:, None] * s).astype(jnp.int32)
    cols = jnp.floor(centre[1] + jnp.cos(a)[:, None] * s).astype(jnp.int32)
    inside = (rows >= 0) & (rows < h) & (cols >= 0) & (cols < w)
    own = (rows == target_rc[0]) & (cols == target_rc[1])
    ok = own | (inside & free[jnp.clip(rows, 0, h - 1), jnp.clip(cols, 0, w - 1)])
    open_ = jnp.cumprod(ok, axis=1).astype(bool)  # every sample so far passed
    return jnp.max(jnp.where(open_, s, 0.0), axis=1)


def in_view(
    free: Bool[Array, "H W"], target_rc: Int[Array, " 2"], n_rays: int, reach_cells: int
) -> tuple[Bool[Array, "M M"], Float[Array, "M M"]]:
    """(in view, distance in cells) of the window of M = 2 reach_cells + 1 cells centred on `target_rc`: a cell is in
    view when its centre lies within the free lengths (`free_lengths`) of the two rays around its bearing."""
    lengths = free_lengths(free, target_rc, n_rays, reach_cells)
    d = jnp.arange(-reach_cells, reach_cells + 1, dtype=jnp.float32)
    dr, dc = jnp.meshgrid(d, d, indexing="ij")
    dist = jnp.hypot(dr, dc)
    k = jnp.floor(jnp.mod(jnp.arctan2(dr, dc), 2 * jnp.pi) * (n_rays / (2 * jnp.pi))).astype(jnp.int32) % n_rays
    return dist <= jnp.minimum(lengths[k], lengths[(k + 1) % n_rays]), dist


def _best_view(
    free: Bool[Array, "H W"],
    value: Float[Array, "H W"],
    target_rc: Int[Array, " 2"],
    resolution: float | Float[Array, ""],
    params: ViewParams,
) -> tuple[Float[Array, ""], Int[Array, " 2"]]:
    """(cost, cell) of the cheapest reachable cell in view of `target_rc` within the ranges; inf if none."""
    m = params.reach_cells
    seen, dist = in_view(free, target_rc, params.n_rays, m)
    near = (dist * resolution >= params.min_range) & (dist * resolution <= params.max_range)
    window = jax.lax.dynamic_slice(jnp.pad(value, m, constant_values=jnp.inf), (target_rc[0], target_rc[1]), seen.shape)
    cost = jnp.where(seen & near, window + params.range_weight * dist, jnp.inf).reshape(-1)
    i = jnp.argmin(cost)
    return cost[i], target_rc + jnp.stack([i // seen.shape[1], i % seen.shape[1]]).astype(jnp.int32) - m


def choose_view(
    grid: Int[Array, "H W"],
    resolution: float | Float[Array, ""],
    value: Float[Array, "H W"],
    robot_rc: Int[Array, " 2"],
    excluded: Bool[Array, "H W"],
    free_thresh: float | Float[Array, ""],
    params: ViewParams,
    clusters: Clusters | None = None,
    keep_rc: Int[Array, " 2"] | None = None,
) -> ViewChoice:
    """The cheapest view of a frontier cell (see the module doc) given the robot's cost-to-go `value` (inf:
    unreachable) and its cell `robot_rc`. `clusters`: `grid`'s, when already found. `keep_rc`: a target kept (the
    caller's current one, or a cell off the grid for none), scored too and chosen first while it is eligible and in
    view: the targets nearest the robot change as it walks, and without it the goal could switch to and fro."""
    h, w = grid.shape
    if clusters is None:
        clusters = frontier_clusters(grid, free_thresh)
    long_enough = clusters.size.astype(jnp.float32) * resolution >= params.min_size
    eligible = (clusters.mask & long_enough[clusters.labels] & ~excluded).reshape(-1)
    rr, cc = jnp.meshgrid(jnp.arange(h), jnp.arange(w), indexing="ij")
    d2 = ((rr - robot_rc[0]) ** 2 + (cc - robot_rc[1]) ** 2).astype(jnp.float32).reshape(-1)
    _, idx = jax.lax.top_k(jnp.where(eligible, -d2, -jnp.inf), params.n_scored)
    ok = eligible[idx]
    t_rc = jnp.stack([idx // w, idx % w], -1).astype(jnp.int32)
    if keep_rc is not None:
        inside = (keep_rc[0] >= 0) & (keep_rc[0] < h) & (keep_rc[1] >= 0) & (keep_rc[1] < w)
        kept = jnp.clip(keep_rc, 0, jnp.array([h - 1, w - 1])).astype(jnp.int32)
        ok = jnp.append(ok, inside & eligible[kept[0] * w + kept[1]])
        t_rc = jnp.concatenate([t_rc, kept[None]])
    free = free_cells(grid, free_thresh)
    costs, goals = jax.vmap(lambda rc: _best_view(free, value, rc, resolution, params))(t_rc)
    costs = jnp.where(ok, costs, jnp.inf)
    best = jnp.argmin(costs)
    if keep_rc is not None:
        best = jnp.where(jnp.isfinite(costs[-1]), costs.shape[0] - 1, best)
    hopeless = jnp.zeros(h * w, bool).at[t_rc[:, 0] * w + t_rc[:, 1]].max(ok & ~jnp.isfinite(costs))
    return ViewChoice(
        found=jnp.isfinite(costs[best]),
        goal_rc=goals[best].astype(jnp.int32),
        target_rc=t_rc[best],
        cost=costs[best],
        n_targets=jnp.sum(eligible),
        scored_rc=t_rc,
        hopeless=hopeless.reshape(h, w),
        n_left=jnp.sum(eligible & ~hopeless),
    )
