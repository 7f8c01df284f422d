"""Building `PoseGraph`s from plain arrays (padded to a capacity) and stacking them for `vmap`."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from jaxquad.kernels.posegraph import ROBUST_KINDS, PoseGraph


def build_graph(
    poses: np.ndarray,
    edge_i: np.ndarray,
    edge_j: np.ndarray,
    measurement: np.ndarray,
    information: np.ndarray,
    *,
    fixed: np.ndarray | None = None,
    robust: str | np.ndarray = "none",
    node_capacity: int | None = None,
    edge_capacity: int | None = None,
    dtype=None,
) -> PoseGraph:
    """A `PoseGraph` of N poses (N, 3) and M edges (node indices 0..N-1), padded to the capacities.

    `fixed`: (N,) bool, default node 0 only. `robust`: one kind for every edge ("none", "huber",
    "cauchy") or (M,) kind names. `dtype`: float dtype of the arrays (default: JAX's default float).
    """
    poses = np.asarray(poses, np.float64)
    n, m = len(poses), len(edge_i)
    n_cap, m_cap = node_capacity or n, edge_capacity or m
    if poses.shape != (n, 3) or np.shape(measurement) != (m, 3) or np.shape(information) != (m, 3, 3):
        raise ValueError(
            f"pose graph shapes: poses {poses.shape}, measurement {np.shape(measurement)}, "
            f"information {np.shape(information)} (expected (N, 3), (M, 3), (M, 3, 3))"
        )
    if n_cap < n or m_cap < m:
        raise ValueError(f"capacity ({n_cap} nodes, {m_cap} edges) below the graph's size ({n}, {m})")
    ij = np.stack([np.asarray(edge_i), np.asarray(edge_j)])
    if m and (ij.min() < 0 or ij.max() >= n):
        raise ValueError(f"edge endpoints must index the {n} nodes, got range [{ij.min()}, {ij.max()}]")
    if fixed is None:
        fixed = np.arange(n) == 0
    kinds = np.broadcast_to(np.asarray(robust), (m,))
    unknown = set(kinds.tolist()) - set(ROBUST_KINDS)
    if unknown:
        raise ValueError(f"unknown robust kernel {min(unknown)!r}; choose from {sorted(ROBUST_KINDS)}")

    def pad(a, cap, fill=0):
        a = np.asarray(a)
        out = np.full((cap, *a.shape[1:]), fill, a.dtype)
        out[: len(a)] = a
        return out

    dtype = dtype or jnp.zeros(()).dtype
    f = lambda a: jnp.asarray(a, dtype)
    return PoseGraph(
        poses=f(pad(poses, n_cap)),
        node_mask=jnp.asarray(np.arange(n_cap) < n),
        fixed=jnp.asarray(pad(np.asarray(fixed, bool), n_cap, False)),
        edge_i=jnp.asarray(pad(edge_i, m_cap), jnp.int32),
        edge_j=jnp.asarray(pad(edge_j, m_cap), jnp.int32),
        measurement=f(pad(measurement, m_cap)),
        information=f(pad(information, m_cap)),
        edge_mask=jnp.asarray(np.arange(m_cap) < m),
        robust=jnp.asarray(pad(np.array([ROBUST_KINDS[k] for k in kinds], np.int32), m_cap), jnp.int32),
    )


def stack_graphs(graphs: list[PoseGraph]) -> PoseGraph:
    """Stack graphs of one capacity along a new leading axis (for `vmap`)."""
    return jax.tree.map(lambda *xs: jnp.stack(xs), *graphs)
