"""Block-tridiagonal (odometry-chain) preconditioner for pose-graph normal equations.

Pose graphs are long chains of odometry edges (node k-1 -> k) plus loop closures; block Jacobi
leaves CG with a condition number growing with the chain's length. This preconditioner keeps every
3x3 diagonal block of H + lam I (loop closures' included) and the off-diagonal blocks of the
odometry edges: a block-tridiagonal matrix T, factored exactly as T = (I + L) S (I + L^T)-style
block LDL^T. The Schur complements S_k = D_k - U_k^T S_{k-1}^-1 U_k are a sequential `lax.scan`
once per linearization, its 3x3 inverses and products written out elementwise: `jnp.linalg.inv`
made a batched LU and triangular solves per step, library calls whose launches were the scan's
whole cost on a GPU (108.6 -> 8.4 ms for 100 robots x 1202 nodes on an H200). Each application
of T^-1 is two first-order linear recurrences run as associative scans of affine maps (log depth:
parallel on a GPU, and vmappable).
"""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
from jaxtyping import Array, Float

from jaxquad.kernels._small_linalg import spd_inverse


class Tridiagonal(eqx.Module):
    """Factored T: `U[k]` = block (k-1, k) (zero where node k has no odometry edge to k-1), `S_inv[k]`."""

    U: Float[Array, "n 3 3"]
    S_inv: Float[Array, "n 3 3"]


def _compose(a, b):
    """Affine maps x -> M x + v: `a` applied first, then `b`."""
    Ma, va = a
    Mb, vb = b
    return Mb @ Ma, (Mb @ va[..., None])[..., 0] + vb


def _matmul(a: Float[Array, "3 3"], b: Float[Array, "3 3"]) -> Float[Array, "3 3"]:
    """a @ b as a broadcast product and sum (fuses with its neighbours; a tiny dot may not)."""
    return jnp.sum(a[:, :, None] * b[None, :, :], axis=1)


def factor(D: Float[Array, "n 3 3"], U: Float[Array, "n 3 3"]) -> Tridiagonal:
    """Block LDL^T of the symmetric positive definite block-tridiagonal matrix with diagonal `D` and blocks
    (k-1, k) = `U[k]`. Each Schur complement's lower triangle is read (it is symmetric in exact arithmetic)."""

    def step(S_prev_inv, blocks):
        D_k, U_k = blocks
        S_inv = spd_inverse(D_k - _matmul(U_k.T, _matmul(S_prev_inv, U_k)))
        return S_inv, S_inv

    # Not unrolled: 8 steps per loop trip made the factor 1.9x faster on an H200 (8.4 -> 4.4 ms, 100 robots), but
    # XLA's CPU code then rounded differently for different robot counts, and a fleet split over processes no
    # longer drew the same maps as on one device (tests/test_parallel.py).
    _, S_inv = jax.lax.scan(step, jnp.zeros_like(D[0]), (D, U))
    return Tridiagonal(U, S_inv)


def solve(T: Tridiagonal, r: Float[Array, "n 3"]) -> Float[Array, "n 3"]:
    """T^-1 r."""
    # Forward: y_k = r_k - U_k^T S_{k-1}^-1 y_{k-1}.
    S_prev_inv = jnp.concatenate([jnp.zeros_like(T.S_inv[:1]), T.S_inv[:-1]])
    M = -jnp.swapaxes(T.U, 1, 2) @ S_prev_inv
    _, y = jax.lax.associative_scan(_compose, (M, r))
    # Backward: z_k = S_k^-1 (y_k - U_{k+1} z_{k+1}).
    U_next = jnp.concatenate([T.U[1:], jnp.zeros_like(T.U[:1])])
    N = -T.S_inv @ U_next
    w = (T.S_inv @ y[..., None])[..., 0]
    _, z = jax.lax.associative_scan(_compose, (N[::-1], w[::-1]))
    return z[::-1]
