"""The leg odometry's velocity bias, estimated online from the scan matches and taken out of the leg edges.

A legged robot's leg odometry can err by a few mm/s in one direction of its base frame for minutes (a gait
whose two halves are not mirror images, feet that slip the same way each stride). Each preintegrated leg
edge then carries that bias times its interval, and where the scan matches are weak the graph follows it.
`kernels.bias_filter` tracks the position and the bias together: the leg displacement from node to node
predicts, the node's scan match (against the running buffer, in the map frame) measures. Its bias estimate
is subtracted from every later leg edge (H b, H = the integral of the base frame's rotation since the last
node), whose covariance gains H P_b H^T. `SlamParams.lo_bias_mean` and `lo_bias_std` are the bias's prior mean
and std per axis of the base frame (forward, sideways); an axis of std 0 is not estimated (its bias stays at its
mean), and both at 0 with zero means leave the edges exactly the uncorrected ones. Only the `preintegrated`
constraints use it.
"""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
from jaxtyping import Array, Bool, Float

from jaxquad.kernels.bias_filter import BiasFilter, bias_predict, bias_update
from jaxquad.kernels.lie import R2, wrap_angle
from jaxquad.slam.state import SlamInputs, SlamParams, SlamState

# m^2: the filter's position variance after a stretch without leg odometry (its next match re-anchors it).
_LOST_POSITION_VAR = 1.0


def accumulate(state: SlamState, inp: SlamInputs, dt: Float[Array, ""], ok: Bool[Array, ""]) -> Float[Array, "2 2"]:
    """H after this scan's interval of dt s: H + R(psi) dt, psi the base heading at the interval's middle
    relative to the last node's (leg-odometry headings)."""
    last = jnp.maximum(state.n_nodes - 1, 0)
    mid = state.lo_prev[2] + 0.5 * wrap_angle(inp.lo_pose[2] - state.lo_prev[2])
    H = state.lo_bias_jac + R2(wrap_angle(mid - state.node_lo[last, 2])) * dt
    return jnp.where(ok, H, state.lo_bias_jac)


def correct_edge(
    state: SlamState, z: Float[Array, "3"], cov: Float[Array, "3 3"]
) -> tuple[Float[Array, "3"], Float[Array, "3 3"]]:
    """The leg edge (measurement, covariance) since the last node with the estimated bias taken out. The bias term
    H b lies in the last node's frame; the edge's covariance is the new node's right perturbation (R(dtheta)^T)."""
    H, f = state.lo_bias_jac, state.lo_bias
    Rz = R2(z[2])
    HPH = H @ f.P[2:, 2:] @ H.T
    return z.at[:2].add(-H @ f.bias), cov.at[:2, :2].add(Rz.T @ HPH @ Rz)


def node_update(
    params: SlamParams,
    state: SlamState,
    x_last: Float[Array, "3"],
    pose: Float[Array, "3"],
    z_leg: Float[Array, "3"],
    leg_ok: Bool[Array, ""],
    matched: Float[Array, "3"],
    cov_match: Float[Array, "3 3"],
    good: Bool[Array, ""],
    dt: Float[Array, ""],
    first: Bool[Array, ""],
) -> BiasFilter:
    """The filter at a new node placed at `pose`: predicted by the leg edge `z_leg` from `x_last` over dt s (the bias
    taken out by `correct_edge`), updated by the scan match `matched` (base pose, covariance `cov_match` in its own
    frame) when `good`. Without a leg edge its position restarts at the node; at the first node it starts there."""
    f, H = state.lo_bias, state.lo_bias_jac
    R = R2(x_last[2])
    on = params.lo_bias_std > 0
    walk = jnp.where(on, params.lo_bias_walk**2 * jnp.clip(dt, 0.0), 0.0)  # per axis: none where not estimated
    raw = z_leg[:2] + H @ f.bias
    R_new = R2(x_last[2] + z_leg[2])  # lo_cov: the new node's right perturbation
    moved = bias_predict(f, R @ raw, R @ H, R_new @ state.lo_cov[:2, :2] @ R_new.T, walk)
    restart_var = jnp.where(first, 0.0, _LOST_POSITION_VAR)
    P_restart = jnp.zeros((4, 4)).at[2:, 2:].set(f.P[2:, 2:]).at[:2, :2].set(restart_var * jnp.eye(2))
    restarted = BiasFilter(x=jnp.concatenate([pose[:2], f.bias]), P=P_restart)
    keep = leg_ok & ~first
    f = jax.tree.map(lambda a, b: jnp.where(keep, a, b), moved, restarted)
    Rm = R2(matched[2])
    f, _, _ = bias_update(f, matched[:2], Rm @ cov_match[:2, :2] @ Rm.T, params.lo_bias_gate, good & keep & jnp.any(on))
    return f


def reanchor(state: SlamState, j, accept: Bool[Array, ""]) -> SlamState:
    """After a loop closure moved the map: the filter's position is the new node's optimized one."""
    f = state.lo_bias
    x = jnp.where(accept, f.x.at[:2].set(state.graph.poses[j, :2]), f.x)
    return eqx.tree_at(lambda s: s.lo_bias, state, BiasFilter(x=x, P=f.P))
