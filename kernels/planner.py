"""Global path planning on an 8-connected grid with static shapes: cost-to-go by wavefront relaxation.

The graph is the grid's 8-neighbourhood; the edge between neighbouring cells a and b costs
|step| * (w_a + w_b) / 2 (|step| = 1 or sqrt 2 cells), with per-cell weights w >= 1 and w = inf for
blocked cells. `cost_to_go` relaxes V(c) = min(V(c), V(n) + edge(c, n)) over all cells at once
(Bellman-Ford in Jacobi form) in a `lax.while_loop` until nothing changes: the fixed point is the
Dijkstra distance, and the number of sweeps is the largest number of steps on a shortest path.
Paths are read off by steepest descent (the neighbour n minimising V(n) + edge(c, n), which is the
shortest-path tree) into a fixed-length array with a validity mask. One robot per call; `vmap` over robots.
"""

from __future__ import annotations

import math

import jax
import jax.numpy as jnp
from jaxtyping import Array, Bool, Float, Int, Shaped

from jaxquad.kernels.costmap import INSCRIBED, UNKNOWN

# (drow, dcol) of the 8 neighbours and their step lengths (cells).
OFFSETS = ((-1, -1), (-1, 0), (-1, 1), (0, -1), (0, 1), (1, -1), (1, 0), (1, 1))
_STEP = tuple(math.hypot(dr, dc) for dr, dc in OFFSETS)
# Relaxation sweeps between two convergence checks (fewer while-loop round trips).
_SWEEPS_PER_CHECK = 4


def neighbour(x: Shaped[Array, "H W"], dr: int, dc: int, fill: bool | int | float) -> Shaped[Array, "H W"]:
    """y[r, c] = x[r + dr, c + dc], `fill` outside the grid."""
    padded = jnp.pad(x, 1, constant_values=fill)
    h, w = x.shape
    return jax.lax.slice(padded, (1 + dr, 1 + dc), (1 + dr + h, 1 + dc + w))


def step_weights(
    cost: Float[Array, "H W"],
    cost_weight: float | Float[Array, ""],
    allow_unknown: bool | Bool[Array, ""] = False,
) -> Float[Array, "H W"]:
    """Per-cell weights from a costmap: 1 + cost_weight * cost / 252; inf at inscribed/lethal (and unknown)."""
    w = 1.0 + cost_weight * jnp.minimum(cost, INSCRIBED - 1) / (INSCRIBED - 1)
    blocked = (cost >= INSCRIBED) & (cost != UNKNOWN)
    blocked = blocked | ((cost == UNKNOWN) & ~jnp.asarray(allow_unknown))
    return jnp.where(blocked, jnp.inf, jnp.where(cost == UNKNOWN, 1.0, w))


def edge_costs(weight: Float[Array, "H W"]) -> Float[Array, "8 H W"]:
    """Cost of the edge from each cell to each of its 8 neighbours (inf off the grid or when blocked)."""
    return jnp.stack([s * 0.5 * (weight + neighbour(weight, dr, dc, jnp.inf)) for (dr, dc), s in zip(OFFSETS, _STEP)])


def cost_to_go(
    weight: Float[Array, "H W"],
    source: Bool[Array, "H W"],
    max_sweeps: int | Int[Array, ""] | None = None,
) -> Float[Array, "H W"]:
    """Shortest-path cost (cells x weight) from every cell to the nearest source cell; inf if unreachable.

    Sources on blocked cells are ignored. `max_sweeps` (default H * W, always enough) bounds the loop.
    """
    h, w = weight.shape
    edges = edge_costs(weight)
    v0 = jnp.where(source & jnp.isfinite(weight), 0.0, jnp.inf)
    limit = h * w if max_sweeps is None else max_sweeps

    def sweep(v):
        cand = [neighbour(v, dr, dc, jnp.inf) + edges[k] for k, (dr, dc) in enumerate(OFFSETS)]
        return jnp.minimum(v, jnp.min(jnp.stack(cand), axis=0))

    def body(carry):
        v, _, n = carry
        new = jax.lax.fori_loop(0, _SWEEPS_PER_CHECK, lambda _, x: sweep(x), v)
        return new, jnp.any(new < v), n + _SWEEPS_PER_CHECK

    def cond(carry):
        _, changed, n = carry
        return changed & (n < limit)

    v, _, _ = jax.lax.while_loop(cond, body, (v0, jnp.array(True), jnp.array(0, jnp.int32)))
    return v


def descend(
    value: Float[Array, "*L H W"],
    weight: Float[Array, "H W"],
    start_rc: Int[Array, " 2"],
    n_points: int,
    stride: int = 1,
    layer: Int[Array, ""] | None = None,
) -> tuple[Int[Array, "n_points 2"], Bool[Array, " n_points"], Bool[Array, ""]]:
    """Cells of the path from `start_rc` down the cost-to-go `value` to a source, every `stride`-th cell.

    Returns (cells (row, col), valid mask, complete): point i is the cell after i * stride steps, or the
    source once reached; the points after the first one on the source are not valid. `complete` is
    False when the start is unreachable or the source is more than (n_points - 1) * stride steps away.
    With `layer`, `value` is a stack of cost-to-go grids (L, H, W) and layer `layer` is descended: only
    the visited cells are read, so one stack serves many robots under `vmap` without a copy per robot.
    Edge costs are formed at the visited cells only (as `edge_costs` would give them).
    """
    h, w = weight.shape
    off = jnp.asarray(OFFSETS, jnp.int32)
    step_len = jnp.asarray(_STEP, weight.dtype)
    at = (lambda r, c: value[r, c]) if layer is None else (lambda r, c: value[layer, r, c])  # noqa: E731

    def step(rc, _):
        here = at(rc[0], rc[1])
        raw = rc + off
        inside = jnp.all((raw >= 0) & (raw < jnp.array([h, w])), axis=-1)
        nb = jnp.clip(raw, 0, jnp.array([h - 1, w - 1]))
        w_nb = jnp.where(inside, weight[nb[:, 0], nb[:, 1]], jnp.inf)
        total = at(nb[:, 0], nb[:, 1]) + step_len * 0.5 * (weight[rc[0], rc[1]] + w_nb)
        k = jnp.argmin(total)
        move = (here > 0.0) & jnp.isfinite(total[k])
        return jnp.where(move, nb[k], rc), (rc, here > 0.0)

    steps = (n_points - 1) * stride + 1
    start_rc = jnp.asarray(start_rc, jnp.int32)
    _, (cells, away) = jax.lax.scan(step, start_rc, None, length=steps)
    n_away = jnp.sum(away)  # steps taken before the source was reached
    idx = jnp.arange(n_points) * stride
    v_start = at(start_rc[0], start_rc[1])
    complete = (v_start < jnp.inf) & (n_away < steps)
    valid = (idx < n_away + stride) & jnp.isfinite(v_start)
    return cells[idx], valid, complete


def nearest_open_cell(
    weight: Float[Array, "H W"],
    rc: Int[Array, " 2"],
    max_distance: float | Float[Array, ""],
) -> tuple[Int[Array, " 2"], Bool[Array, ""]]:
    """The traversable cell nearest to `rc` (Euclidean, cells) within `max_distance` cells, and whether one exists."""
    h, w = weight.shape
    r, c = jnp.meshgrid(jnp.arange(h), jnp.arange(w), indexing="ij")
    d2 = jnp.where(jnp.isfinite(weight), ((r - rc[0]) ** 2 + (c - rc[1]) ** 2).astype(jnp.float32), jnp.inf)
    k = jnp.argmin(d2)
    return jnp.stack([k // w, k % w]).astype(jnp.int32), d2.reshape(-1)[k] <= max_distance**2
