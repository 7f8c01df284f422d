"""The loop-closure consistency test of the online SLAM: how far a loop candidate's measured pose of node j in
node i's frame may lie from the graph's, given the graph's own uncertainty along its chain from i to j.

`chain_covariance` compounds the chain's links (each node's match and leg-odometry information). With wall-heading
priors (`SlamSpec.wall_heading`) the heading does not wander freely along the chain: each prior pins a node's
heading in the map frame. `chain_covariance_with_priors` (the priors applied when `SlamParams.loop_chain_priors`)
runs the chain as a Kalman filter whose state is the pose of node k in node i's frame plus node i's heading error in the
map frame (variance the heading filter's P at node i); every used prior is a measurement of their sum, with its
own variance R. Without it the chain's heading spread was far wider than its error (on replayed warehouse walks
the chain claimed a median heading std of 3.7 deg where its error had a median of 0.56 deg), and its position
spread with it through the lever arm of every link, so a wrong closure a metre off could pass. The price: a heading
that has run away on wrong priors (P small, the error large) now also refuses the closures that would bring it
back, where the wide chain let them through (the README's Exploration section measures both).

A chain leaves out the loop closures that already tie node i to node j, and so grants a closure as much room as
the links compounded over the whole walk between the two visits. With `SlamParams.loop_graph_covariance` (slam.yaml's
`loop_consistency_graph`) the graph's uncertainty is instead the covariance of node j in node i's frame from the
whole graph's information (`kernels.posegraph.relative_covariance`: its links, leg-odometry edges, heading priors and
closures), which is no wider than the chain's.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
from jaxtyping import Array, Bool, Float, Int

from jaxquad.kernels.chain_filter import filtered_covariance
from jaxquad.kernels.lie import se2, xy_theta
from jaxquad.kernels.posegraph import relative_covariance
from jaxquad.slam.state import SlamParams, SlamSpec, SlamState


def chain_covariance(state: SlamState, i: Int[Array, ""], j: Int[Array, ""]) -> Float[Array, "3 3"]:
    """Covariance of node j's pose in node i's frame (right perturbation) along the chain of links from i
    to j: each node k's link covariance moved into node j's frame by Ad(T_k_j^-1) and summed."""
    poses = state.graph.poses
    k = jnp.arange(poses.shape[0])
    on = (k > i) & (k <= j) & state.graph.node_mask
    A = jax.vmap(lambda p: (se2(poses[j]).inverse() @ se2(p)).adjoint())(poses)
    return jnp.einsum("k,kab,kbc,kdc->ad", on.astype(poses.dtype), A, state.node_cov, A)


def chain_covariance_with_priors(
    state: SlamState, i: Int[Array, ""], j: Int[Array, ""], priors: Bool[Array, ""] = True
) -> Float[Array, "3 3"]:
    """The same covariance, filtered by the wall-heading priors of nodes i+1..j (`kernels.chain_filter`); with
    `priors` false none is applied and the filter compounds the links as `chain_covariance` does.

    State (phi, xi): phi node i's heading error in the map frame (variance `node_heading_var[i]`), xi the right
    perturbation of node k's pose in node i's frame; a step k is xi <- Ad(D_k^-1) xi + w_k (D_k node k in node
    k-1's frame, w_k ~ N(0, node_cov[k])); node k's prior measures phi + xi_theta with information
    `node_heading_info[k]` (0 where none was used)."""
    poses = state.graph.poses
    n = poses.shape[0]
    k = jnp.arange(n)
    on = (k > i) & (k <= j) & state.graph.node_mask
    prev = jnp.concatenate([poses[:1], poses[:-1]])
    Ad = jax.vmap(lambda a, b: (se2(b).inverse() @ se2(a)).adjoint())(prev, poses)  # Ad(D_k^-1)
    F = jnp.zeros((n, 4, 4)).at[:, 0, 0].set(1.0).at[:, 1:, 1:].set(Ad)
    F = jnp.where(on[:, None, None], F, jnp.eye(4))
    Q = jnp.zeros((n, 4, 4)).at[:, 1:, 1:].set(jnp.where(on[:, None, None], state.node_cov, 0.0))
    h = jnp.broadcast_to(jnp.array([1.0, 0.0, 0.0, 1.0]), (n, 4))
    info = jnp.where(on & priors, state.node_heading_info, 0.0)
    P0 = jnp.zeros((4, 4)).at[0, 0].set(state.node_heading_var[i])
    return filtered_covariance(F, Q, h, info, P0)[1:, 1:]


def loop_chi2(
    spec: SlamSpec,
    params: SlamParams,
    state: SlamState,
    i,
    j,
    z: Float[Array, "3"],
    cov_z: Float[Array, "3 3"],
    candidate: Bool[Array, ""] = True,
) -> Float[Array, ""]:
    """Chi-square of a loop constraint z (node j in node i's frame) against the graph's estimate of it. With
    `params.loop_graph_covariance` the graph's uncertainty is its whole information's (`kernels.posegraph.
    relative_covariance`, solved only for a `candidate`), else the chain's."""
    x = state.graph.poses
    r = xy_theta(se2(z).inverse() @ se2(x[i]).inverse() @ se2(x[j]))
    if spec.wall_heading:  # one chain computed, the priors applied or not
        chain = chain_covariance_with_priors(state, i, j, params.loop_chain_priors)
    else:
        chain = chain_covariance(state, i, j)
    use_graph = jnp.asarray(params.loop_graph_covariance)
    whole = relative_covariance(state.graph, i, j, params.solver, use_graph & candidate)
    S = jnp.where(use_graph, whole, chain) + cov_z
    return r @ jnp.linalg.solve(0.5 * (S + S.T) + 1e-9 * jnp.eye(3), r)
