"""Frontier exploration: frontier cells, 8-connected clusters, and the goal of the nearest reachable one.

A frontier cell is an unknown cell with a free 4-neighbour. Frontier cells are grouped 8-connected by
min-label propagation with pointer jumping in a `lax.while_loop` (each cluster's label is the smallest
flat index among its cells), so every array keeps a static shape: per-cluster statistics live in arrays
of H * W + 1 slots indexed by label. A cluster is a candidate when its size (cells x resolution, m)
reaches `min_size`, a free cell 4-adjacent to it is reachable (finite cost-to-go from the robot), and
its goal cell is not blacklisted. Its goal is that reachable adjacent free cell nearest to the cluster's
centroid; its cost is potential_scale * (path cost to the cluster, m) - gain_scale * (size, m), so
gain_scale = 0 picks the nearest frontier (the paper) and gain_scale > 0 favours large ones.

Commitment: a cluster whose goal cell lies in the optional `keep` mask (the caller's current goal and its
surroundings) is a candidate at any size and is chosen before every other candidate. Without it the choice
flips between far-apart clusters whenever the nearest one's size wavers around `min_size` under noisy scans,
and a robot walks to and fro without reaching either.
"""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
from jaxtyping import Array, Bool, Float, Int

from jaxquad.kernels.planner import OFFSETS, neighbour

_FOUR = ((-1, 0), (1, 0), (0, -1), (0, 1))


class FrontierParams(eqx.Module):
    min_size: Float[Array, ""]  # m: clusters shorter than this are ignored
    free_thresh: Float[Array, ""]  # occupancy (0..100) below which a known cell is free
    potential_scale: Float[Array, ""]  # weight of the path cost (per m)
    gain_scale: Float[Array, ""]  # weight of the cluster size (per m)

    @classmethod
    def default(cls, **overrides: float) -> FrontierParams:
        # 0.75 m: the paper's 0.5-0.75 m (the authors' public configuration uses 1.2 m).
        values = {
            "min_size": 0.75,
            "free_thresh": 19.6,
            "potential_scale": 1.0,
            "gain_scale": 0.0,
        }
        values.update(overrides)
        return cls(**{k: jnp.asarray(v, jnp.float32) for k, v in values.items()})


class FrontierChoice(eqx.Module):
    found: Bool[Array, ""]  # False: no reachable, large enough, non-blacklisted frontier is left
    goal_rc: Int[Array, " 2"]  # reachable free cell next to the chosen cluster, nearest its centroid
    centroid_rc: Float[Array, " 2"]  # (row, col) mean of the chosen cluster's cells
    size: Int[Array, ""]  # cells in the chosen cluster
    cost: Float[Array, ""]
    n_candidates: Int[Array, ""]  # clusters that qualified


def free_cells(grid: Int[Array, "H W"], free_thresh: float | Float[Array, ""]) -> Bool[Array, "H W"]:
    return (grid >= 0) & (grid.astype(jnp.float32) < free_thresh)


def frontier_mask(grid: Int[Array, "H W"], free_thresh: float | Float[Array, ""]) -> Bool[Array, "H W"]:
    """Unknown cells (-1) with at least one free 4-neighbour."""
    free = free_cells(grid, free_thresh)
    touches = jnp.zeros_like(free)
    for dr, dc in _FOUR:
        touches = touches | neighbour(free, dr, dc, False)
    return (grid < 0) & touches


def label_clusters(mask: Bool[Array, "H W"]) -> Int[Array, "H W"]:
    """8-connected component labels: the smallest flat index of the component's cells; H * W off the mask."""
    h, w = mask.shape
    n = h * w
    lab0 = jnp.where(mask, jnp.arange(n, dtype=jnp.int32).reshape(h, w), n)

    def body(carry):
        lab, _ = carry
        m = lab
        for dr, dc in OFFSETS:
            m = jnp.minimum(m, neighbour(lab, dr, dc, n))
        m = jnp.where(mask, m, n)
        # Pointer jumping: a label is a cell of the same component whose own label is no larger.
        jumped = jnp.append(m.reshape(-1), n)[m.reshape(-1)].reshape(h, w)
        new = jnp.where(mask, jumped, n)
        return new, jnp.any(new != lab)

    lab, _ = jax.lax.while_loop(lambda c: c[1], body, (lab0, jnp.array(True)))
    return lab


def cluster_stats(mask: Bool[Array, "H W"], labels: Int[Array, "H W"]) -> tuple[Int[Array, " N"], Float[Array, "N 2"]]:
    """Per label slot (H * W + 1 of them): cell count and (row, col) centroid (nan for empty slots)."""
    h, w = mask.shape
    n = h * w + 1
    lab = labels.reshape(-1)
    r, c = jnp.meshgrid(
        jnp.arange(h, dtype=jnp.float32),
        jnp.arange(w, dtype=jnp.float32),
        indexing="ij",
    )
    size = jax.ops.segment_sum(mask.reshape(-1).astype(jnp.int32), lab, n)
    sums = jax.ops.segment_sum(
        jnp.where(mask.reshape(-1, 1), jnp.stack([r.reshape(-1), c.reshape(-1)], -1), 0.0), lab, n
    )
    return size, sums / jnp.where(size > 0, size.astype(jnp.float32), jnp.nan)[:, None]


class Clusters(eqx.Module):
    """A map's frontier cells and their 8-connected clusters (per-cluster arrays: one slot per label)."""

    mask: Bool[Array, "H W"]
    labels: Int[Array, "H W"]  # `label_clusters`
    size: Int[Array, " N"]  # N = H * W + 1 label slots
    centroid: Float[Array, "N 2"]  # (row, col); nan for empty slots


def frontier_clusters(grid: Int[Array, "H W"], free_thresh: float | Float[Array, ""]) -> Clusters:
    """`grid`'s frontier cells (`frontier_mask`), their labels (`label_clusters`), sizes and centroids."""
    mask = frontier_mask(grid, free_thresh)
    labels = label_clusters(mask)
    return Clusters(mask, labels, *cluster_stats(mask, labels))


def choose_frontier(
    grid: Int[Array, "H W"],
    resolution: float | Float[Array, ""],
    value: Float[Array, "H W"],
    blacklist: Bool[Array, "H W"],
    params: FrontierParams,
    keep: Bool[Array, "H W"] | None = None,
    clusters: Clusters | None = None,
) -> FrontierChoice:
    """The best frontier cluster given the robot's cost-to-go `value` (cells x weight; inf = unreachable); a
    cluster whose goal cell lies in `keep` first (see the module doc). `clusters`: `grid`'s, when already found."""
    h, w = grid.shape
    n = h * w + 1
    if clusters is None:
        clusters = frontier_clusters(grid, params.free_thresh)
    mask, labels, size, centroid = clusters.mask, clusters.labels, clusters.size, clusters.centroid
    reach = free_cells(grid, params.free_thresh) & jnp.isfinite(value)
    rr, cc = jnp.meshgrid(jnp.arange(h), jnp.arange(w), indexing="ij")
    cen = centroid[labels.reshape(-1)].reshape(h, w, 2)

    # Candidates: (frontier cell, free reachable 4-neighbour) pairs, each scored for its cluster.
    lab_k, d2_k, v_k, idx_k = [], [], [], []
    for dr, dc in _FOUR:
        ok = mask & neighbour(reach, dr, dc, False)
        nr, nc = rr + dr, cc + dc
        lab_k.append(jnp.where(ok, labels, n - 1))
        d2 = (nr.astype(jnp.float32) - cen[..., 0]) ** 2 + (nc.astype(jnp.float32) - cen[..., 1]) ** 2
        d2_k.append(jnp.where(ok, d2, jnp.inf))
        v_k.append(jnp.where(ok, neighbour(value, dr, dc, jnp.inf), jnp.inf))
        idx_k.append(jnp.clip(nr, 0, h - 1) * w + jnp.clip(nc, 0, w - 1))
    lab_k, d2_k, v_k, idx_k = (jnp.stack(x).reshape(-1) for x in (lab_k, d2_k, v_k, idx_k))
    path_cost = jax.ops.segment_min(v_k, lab_k, n)
    best_d2 = jax.ops.segment_min(d2_k, lab_k, n)
    is_best = jnp.isfinite(d2_k) & (d2_k == best_d2[lab_k])
    goal_idx = jax.ops.segment_min(jnp.where(is_best, idx_k, h * w), lab_k, n)

    def at_goal(cells):  # per cluster: its goal cell's entry (False without a goal)
        return jnp.append(cells.reshape(-1), False)[jnp.minimum(goal_idx, h * w)]

    kept = at_goal(keep) if keep is not None else jnp.zeros(n, bool)
    size_m = size.astype(jnp.float32) * resolution
    ok = ((size_m >= params.min_size) | kept) & jnp.isfinite(path_cost) & ~at_goal(blacklist) & (goal_idx < h * w)
    ok = ok.at[n - 1].set(False)
    cost = params.potential_scale * path_cost * resolution - params.gain_scale * size_m
    cost = jnp.where(ok, cost, jnp.inf)
    best_kept = jnp.argmin(jnp.where(kept, cost, jnp.inf))
    best = jnp.where(ok[best_kept] & kept[best_kept], best_kept, jnp.argmin(cost))
    g = jnp.minimum(goal_idx[best], h * w - 1)
    return FrontierChoice(
        found=ok[best],
        goal_rc=jnp.stack([g // w, g % w]).astype(jnp.int32),
        centroid_rc=centroid[best],
        size=size[best],
        cost=cost[best],
        n_candidates=jnp.sum(ok),
    )
