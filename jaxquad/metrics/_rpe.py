"""Relative pose error: pose pairs by path distance (metres) or by index (frames), and their errors.

Pairs live in N - 1 static slots with a mask, so trajectories of equal length share one shape and
vmap works whatever the number of pairs each one gets.
"""

from __future__ import annotations

import equinox as eqx
import jax.numpy as jnp
from jax import lax
from jaxtyping import Array, Bool, Float, Int

from jaxquad.metrics._ape import PoseErrors, pose_errors


class Pairs(eqx.Module):
    """Index pairs (i, j), i < j, in static slots (N - 1 for RPE); slots with mask False hold (0, 0)."""

    i: Int[Array, "M"]
    j: Int[Array, "M"]
    mask: Bool[Array, "M"]


def _step_lengths(p: Float[Array, "N 3"]) -> Float[Array, "N-1"]:
    d = p[1:] - p[:-1]
    return jnp.sqrt(jnp.sum(d * d, axis=-1))


def pairs_by_path(p: Float[Array, "N 3"], delta_m: Float[Array, ""]) -> Pairs:
    """Consecutive pairs by travelled distance (evo's rule): walk the path accumulating step lengths;
    when the sum reaches delta_m the index is appended and the sum restarts from 0 (the excess is
    dropped). Pairs are consecutive appended indices, starting from index 0."""
    steps = _step_lengths(p)
    idx = jnp.arange(1, p.shape[0])

    def walk(carry, x):
        travelled, last = carry
        step, i = x
        travelled = travelled + step
        hit = travelled >= delta_m
        out = (jnp.where(hit, last, 0), jnp.where(hit, i, 0), hit)
        return (jnp.where(hit, 0.0, travelled), jnp.where(hit, i, last)), out

    init = (jnp.zeros((), p.dtype), jnp.zeros((), idx.dtype))
    _, (i, j, mask) = lax.scan(walk, init, (steps, idx))
    return Pairs(i, j, mask)


def pairs_by_path_all(p: Float[Array, "N 3"], delta_m: Float[Array, ""], rel_tol: float = 0.1) -> Pairs:
    """All-pairs mode (evo's rule): for every start i, the first later index j whose travelled
    distance from i is nearest to delta_m, kept if within rel_tol * delta_m."""
    n = p.shape[0]
    dist = jnp.concatenate([jnp.zeros(1, p.dtype), jnp.cumsum(_step_lengths(p))])
    i = jnp.arange(n - 1)
    gap = lambda j: jnp.abs((dist[j] - dist[i]) - delta_m)
    # dist is non-decreasing, so the nearest j is at the crossing of dist[i] + delta_m or one before;
    # within a run of equal distances the first index wins, as in an argmin.
    # searchsorted returns int32, the indices i may be int64 (float64 evaluations).
    k = jnp.clip(jnp.searchsorted(dist, dist[i] + delta_m, side="left").astype(i.dtype), i + 1, n - 1)
    first_equal = lambda j: jnp.maximum(jnp.searchsorted(dist, dist[j], side="left").astype(i.dtype), i + 1)
    before = first_equal(jnp.maximum(k - 1, i + 1))
    at = first_equal(k)
    j = jnp.where(gap(before) <= gap(at), before, at)
    mask = gap(j) <= rel_tol * delta_m
    return Pairs(jnp.where(mask, i, 0), jnp.where(mask, j, 0), mask)


def pairs_by_frames(n: int, delta: Int[Array, ""], all_pairs: bool = False) -> Pairs:
    """Pairs delta indices apart: (0, d), (d, 2d), ... or, with all_pairs, (i, i + d) for every i."""
    m = jnp.arange(n - 1, dtype=delta.dtype)
    i = m if all_pairs else m * delta
    j = i + delta
    mask = (j < n) & (delta >= 1)
    return Pairs(jnp.where(mask, i, 0), jnp.where(mask, j, 0), mask)


def rpe(
    p_ref: Float[Array, "N 3"],
    R_ref: Float[Array, "N 3 3"],
    p_est: Float[Array, "N 3"],
    R_est: Float[Array, "N 3 3"],
    pairs: Pairs,
) -> PoseErrors:
    """RPE per pair slot: E = (Q_i^-1 Q_j)^-1 (P_i^-1 P_j) with Q the reference and P the estimate.
    Masked-out slots compare pose 0 with itself (zero error); weigh them out with `pairs.mask`."""

    def relative(p, R):
        R_i_T = jnp.swapaxes(R[pairs.i], -1, -2)
        return R_i_T @ R[pairs.j], jnp.einsum("mij,mj->mi", R_i_T, p[pairs.j] - p[pairs.i])

    R_q, t_q = relative(p_ref, R_ref)
    R_p, t_p = relative(p_est, R_est)
    R_q_T = jnp.swapaxes(R_q, -1, -2)
    return pose_errors(R_q_T @ R_p, jnp.einsum("mij,mj->mi", R_q_T, t_p - t_q))


def pairs_for(p_est: Float[Array, "N 3"], delta, unit: str, all_pairs: bool, rel_tol: float = 0.1) -> Pairs:
    """Pairs for one delta in `unit` ("m" travelled metres along p_est, or "frames")."""
    if unit == "m":
        return pairs_by_path_all(p_est, delta, rel_tol) if all_pairs else pairs_by_path(p_est, delta)
    if unit == "frames":
        return pairs_by_frames(p_est.shape[0], jnp.asarray(delta).astype(jnp.int32), all_pairs)
    raise ValueError(f"unknown RPE delta unit {unit!r}; expected 'm' or 'frames'")
