"""Covariance of a linear-Gaussian chain's last state after filtering, by a parallel tree reduction.

The chain: x_k = F_k x_(k-1) + w_k, w_k ~ N(0, Q_k), and at each step one scalar measurement y_k = h_k . x_k + v_k
with information `info_k` = 1 / var(v_k) (0: no measurement), from x_0 ~ N(., P0). A Kalman filter run along it
gives the last state's covariance in N sequential steps; here each step becomes an element (A, C, J) of the
associative filtering operator of Saerkkae and Garcia-Fernandez ("Temporal parallelization of Bayesian smoothers",
IEEE TAC 2021; only the parts the covariance needs, since it does not depend on the y_k) and the elements are
combined pairwise in log2(N) levels. On a GPU that is 10 wide steps for a chain of 1024 instead of 1024 narrow
ones. Steps that are not in the chain are identity elements (F = I, Q = 0, no measurement).
"""

from __future__ import annotations

import jax.numpy as jnp
from jaxtyping import Array, Float


def _elements(F, Q, h, info):
    """Per-step elements: A = (I - K h) F, C = (I - K h) Q, J = F^T h^T h F / S, with 1/S written as
    info / (1 + info h Q h^T) so that info = 0 (no measurement) is exact."""
    d = F.shape[-1]
    hQ = jnp.einsum("na,nab->nb", h, Q)
    inv_s = info / (1.0 + info * jnp.einsum("nb,nb->n", hQ, h))
    K = hQ * inv_s[:, None]  # Q h^T / S (Q symmetric)
    IKh = jnp.eye(d) - K[:, :, None] * h[:, None, :]
    hF = jnp.einsum("na,nab->nb", h, F)
    return IKh @ F, IKh @ Q, inv_s[:, None, None] * hF[:, :, None] * hF[:, None, :]


def _combine(first, second):
    """The element of `first` followed by `second` (the filtering operator's composition)."""
    A1, C1, J1 = first
    A2, C2, J2 = second
    d = A1.shape[-1]
    M = jnp.linalg.inv(jnp.eye(d) + C1 @ J2)  # (I + C1 J2)^-1; its transpose is (I + J2 C1)^-1
    A = A2 @ M @ A1
    C = A2 @ M @ C1 @ jnp.swapaxes(A2, -1, -2) + C2
    J = jnp.swapaxes(A1, -1, -2) @ jnp.swapaxes(M, -1, -2) @ J2 @ A1 + J1
    return A, 0.5 * (C + jnp.swapaxes(C, -1, -2)), 0.5 * (J + jnp.swapaxes(J, -1, -2))


def filtered_covariance(
    F: Float[Array, "n d d"],
    Q: Float[Array, "n d d"],
    h: Float[Array, "n d"],
    info: Float[Array, " n"],
    P0: Float[Array, "d d"],
) -> Float[Array, "d d"]:
    """Covariance of x_n given x_0 ~ N(., P0) and the measurements of steps 1..n (row k is step k+1)."""
    n, d = F.shape[0], F.shape[-1]
    size = 1 << max(n - 1, 0).bit_length()  # the next power of two: pad with identity elements
    eye = jnp.broadcast_to(jnp.eye(d, dtype=F.dtype), (size - n, d, d))
    zeros = jnp.zeros((size - n, d, d), F.dtype)
    A, C, J = _elements(F, Q, h, info)
    elems = (jnp.concatenate([A, eye]), jnp.concatenate([C, zeros]), jnp.concatenate([J, zeros]))
    while elems[0].shape[0] > 1:
        elems = _combine(tuple(e[0::2] for e in elems), tuple(e[1::2] for e in elems))
    A, C, J = (e[0] for e in elems)
    # The prior as the first element (A = 0, C = P0, J = 0) followed by the chain.
    M = jnp.linalg.inv(jnp.eye(d) + P0 @ J)
    out = A @ M @ P0 @ A.T + C
    return 0.5 * (out + out.T)
