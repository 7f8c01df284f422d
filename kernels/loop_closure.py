"""Loop-closure candidates for 2D graph SLAM (Karto/slam_toolbox style), over fixed-capacity node stores.

For the current node j, the old nodes i considered are those stored (`node_mask`), earlier than j,
reached after at least `min_travel` m of path since them (so the recent chain never closes a loop
with itself) and within `search_radius` m of node j. They must form a chain of at least
`min_chain` consecutive nodes, or (with `min_chain_distance` > 0) of consecutive nodes spanning at least
`min_chain_distance` m of path: a count assumes nodes at the node rule's spacing, and a log that keeps a scan
every metre holds too few of them within the search radius to make the count; the chain holding the nearest
such node is used, at most
`LoopSpec.chain` of its scans around that node, as the reference map. Node j's scan is matched
against it twice, as Karto does: a coarse match over a large window (`LoopSpec.coarse`, +-2 m at
0.05 m by default), which must reach `coarse_response`, then a fine match (`LoopSpec.fine`, the
correlation settings) from the coarse pose, which must reach `fine_response`.

Repeated structure (a corridor of identical doors or pillars) can give a confident but wrong match.
The coarse search is therefore run a second time with the translations within
`ambiguity_distance` of the best one left out; when that second, distinct peak reaches
`ambiguity_ratio` times the best coarse response, the candidate is rejected as ambiguous.

A scan that sees one wall, or two parallel ones, does not say where along them the robot is: its
response is a ridge, and the spot the search picks on it is noise. The fine match's covariance (the
response spread) shows it; a candidate whose largest position standard deviation exceeds
`max_position_std` is rejected as degenerate. (The spread is measured on a lattice of the fine window,
+-0.5 m by default, so it saturates near 0.29 m however long the ridge: the test is on its size, not
a weight to trust.)
"""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
from jaxtyping import Array, Bool, Float, Int

from jaxquad.kernels.control_flow import run_if
from jaxquad.kernels.lie import SE2
from jaxquad.kernels.scan_grid import MatchParams, MatchSpec, likelihood_grid, world_points
from jaxquad.kernels.scan_match import match_scan


class LoopSpec(eqx.Module):
    """Static structure: the two match specs and how many chain scans form the reference."""

    coarse: MatchSpec = eqx.field(static=True, default_factory=MatchSpec.loop)
    fine: MatchSpec = eqx.field(static=True, default_factory=MatchSpec)
    chain: int = eqx.field(static=True, default=10)  # reference scans at most (7-10 in the paper's setups)


class LoopParams(eqx.Module):
    """Tunable numbers (traced leaves); defaults from the paper's SLAM settings."""

    match: MatchParams = eqx.field(default_factory=MatchParams)
    search_radius: Float[Array, ""] = eqx.field(default_factory=lambda: jnp.asarray(3.0))  # m
    min_chain: Int[Array, ""] = eqx.field(default_factory=lambda: jnp.asarray(7))  # consecutive nodes
    min_chain_distance: Float[Array, ""] = eqx.field(default_factory=lambda: jnp.asarray(0.0))  # m of path; 0: off
    min_travel: Float[Array, ""] = eqx.field(default_factory=lambda: jnp.asarray(6.0))  # m of path since node i
    coarse_response: Float[Array, ""] = eqx.field(default_factory=lambda: jnp.asarray(0.35))
    fine_response: Float[Array, ""] = eqx.field(default_factory=lambda: jnp.asarray(0.45))
    ambiguity_distance: Float[Array, ""] = eqx.field(default_factory=lambda: jnp.asarray(0.5))  # m
    ambiguity_ratio: Float[Array, ""] = eqx.field(default_factory=lambda: jnp.asarray(0.9))
    max_position_std: Float[Array, ""] = eqx.field(default_factory=lambda: jnp.asarray(0.15))  # m


class LoopCandidate(eqx.Module):
    i: Int[Array, ""]  # old node the constraint attaches to (the chain node nearest to node j)
    j: Int[Array, ""]  # current node
    T_i_j: Float[Array, "3"]  # pose of node j in node i's frame: x, y (m), theta (rad)
    covariance: Float[Array, "3 3"]  # of T_i_j's right perturbation (translation in node j's frame), m^2, rad^2
    accept: Bool[Array, ""]
    chain_length: Int[Array, ""]  # consecutive nearby old nodes in the chosen chain (0: none)
    coarse_response: Float[Array, ""]
    fine_response: Float[Array, ""]
    second_response: Float[Array, ""]  # best coarse response away from the best peak
    pose_j: Float[Array, "3"]  # matched world pose of node j


def _chains(
    eligible: Bool[Array, " n"], travel: Float[Array, " n"]
) -> tuple[Int[Array, " n"], Int[Array, " n"], Float[Array, " n"]]:
    """Label (1, 2, ...; 0 if not eligible) of each node's run of consecutive eligible nodes, its length, and
    the path it spans (`travel`, the path length up to each node, at its last node less at its first; m)."""
    n = eligible.shape[0]
    start = eligible & ~jnp.concatenate([jnp.zeros(1, bool), eligible[:-1]])
    label = jnp.where(eligible, jnp.cumsum(start), 0)
    length = jnp.zeros(n + 1, jnp.int32).at[label].add(1)
    first = jnp.full(n + 1, jnp.inf).at[label].min(travel)
    last = jnp.full(n + 1, -jnp.inf).at[label].max(travel)
    return label, jnp.where(eligible, length[label], 0), jnp.where(eligible, last[label] - first[label], 0.0)


def find_loop_closure(
    spec: LoopSpec,
    params: LoopParams,
    poses: Float[Array, "n 3"],
    ranges: Float[Array, "n b"],
    valid: Bool[Array, "n b"],
    bearings: Float[Array, " b"],
    node_mask: Bool[Array, " n"],
    j: Int[Array, ""],
) -> LoopCandidate:
    """The loop-closure candidate of node j against the older stored nodes (sensor poses, world frame)."""
    n = poses.shape[0]
    idx = jnp.arange(n)
    step = jnp.where(node_mask[1:] & node_mask[:-1], jnp.linalg.norm(jnp.diff(poses[:, :2], axis=0), axis=1), 0.0)
    travel = jnp.concatenate([jnp.zeros(1), jnp.cumsum(step)])
    dist = jnp.linalg.norm(poses[:, :2] - poses[j, :2], axis=1)
    eligible = node_mask & (idx < j) & (travel[j] - travel >= params.min_travel) & (dist < params.search_radius)
    label, length, span = _chains(eligible, travel)
    usable = (length >= params.min_chain) | ((params.min_chain_distance > 0) & (span >= params.min_chain_distance))
    nearest = jnp.argmin(jnp.where(usable, dist, jnp.inf))
    found = usable[nearest]

    # Reference: up to `chain` scans of the chosen run around its nearest node.
    C = spec.chain
    raw = nearest - C // 2 + jnp.arange(C)
    ref = jnp.clip(raw, 0, n - 1)
    in_chain = found & (raw >= 0) & (raw < n) & (label[ref] == label[nearest])
    pts, mask = world_points(params.match, poses[ref], ranges[ref], bearings, valid[ref] & in_chain[:, None])

    def matches(operand):
        pts, mask, _ = operand
        prior = poses[j]
        coarse_grid = likelihood_grid(spec.coarse, params.match, prior[:2], pts, mask)
        coarse = match_scan(spec.coarse, params.match, coarse_grid, prior, ranges[j], bearings, valid[j])
        second = match_scan(
            spec.coarse,
            params.match,
            coarse_grid,
            prior,
            ranges[j],
            bearings,
            valid[j],
            coarse.pose[:2],
            params.ambiguity_distance,
        )
        fine_grid = likelihood_grid(spec.fine, params.match, coarse.pose[:2], pts, mask)
        fine = match_scan(spec.fine, params.match, fine_grid, coarse.pose, ranges[j], bearings, valid[j])
        return pts, mask, (coarse, second, fine)

    # Without a chain there is nothing to match: the three matches (and their grids, the costly part)
    # are skipped, and the candidate reports zero responses.
    nothing = jax.tree.map(lambda a: jnp.zeros(a.shape, a.dtype), jax.eval_shape(matches, (pts, mask, None))[2])
    _, _, (coarse, second, fine) = run_if(found, matches, (pts, mask, nothing))

    unambiguous = second.coarse_response < params.ambiguity_ratio * coarse.coarse_response
    # Largest eigenvalue of the 2x2 position covariance, in closed form.
    c = fine.covariance
    half_trace, det = 0.5 * (c[0, 0] + c[1, 1]), c[0, 0] * c[1, 1] - c[0, 1] ** 2
    largest_var = half_trace + jnp.sqrt(jnp.maximum(half_trace**2 - det, 0.0))
    constrained = largest_var <= params.max_position_std**2
    accept = (
        found
        & (coarse.coarse_response >= params.coarse_response)
        & (fine.response >= params.fine_response)
        & unambiguous
        & constrained
    )
    with jax.default_matmul_precision("highest"):  # GPUs would round float32 matmuls to TF32
        T_world_i = SE2.from_xy_theta(poses[nearest, 0], poses[nearest, 1], poses[nearest, 2])
        T_world_j = SE2.from_xy_theta(fine.pose[0], fine.pose[1], fine.pose[2])
        T_i_j = T_world_i.inverse() @ T_world_j
        # The match's covariance is of j's world position; g2o's SE2 edge error (Z^-1 T_i^-1 T_j) has its
        # translation in node j's frame, so the constraint's covariance is rotated into that frame.
        R = T_world_j.rotation().as_matrix()
        R3 = jnp.zeros((3, 3)).at[:2, :2].set(R).at[2, 2].set(1.0)
        cov = R3.T @ fine.covariance @ R3
    return LoopCandidate(
        i=nearest.astype(jnp.int32),
        j=jnp.asarray(j, jnp.int32),
        T_i_j=jnp.concatenate([T_i_j.translation(), T_i_j.rotation().as_radians()[None]]),
        covariance=cov,
        accept=accept,
        chain_length=jnp.where(found, length[nearest], 0),
        coarse_response=coarse.coarse_response,
        fine_response=fine.response,
        second_response=second.coarse_response,
        pose_j=fine.pose,
    )
