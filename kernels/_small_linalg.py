"""Solves and inverses of tiny symmetric positive definite systems as unrolled elementwise arithmetic.

`jnp.linalg.solve` on a 3x3 or 4x4 matrix lowers to a batched LU factorization plus triangular
solves (LAPACK on the CPU, cuSolver/cuBLAS on the GPU: several library calls, each a kernel launch
of its own, and a pivot loop). For a static size of a few rows the same arithmetic written out
entry by entry is a few dozen multiply-adds that XLA fuses with the surrounding elementwise code,
and under `vmap` it stays one fused loop over the batch.
"""

from __future__ import annotations

import jax.numpy as jnp
from jaxtyping import Array, Float


def spd_solve(A: Float[Array, "n n"], b: Float[Array, "n *k"]) -> Float[Array, "n *k"]:
    """x = A^-1 b for a symmetric positive definite A of small static size n, by an unrolled
    LDL^T factorization (Cholesky without square roots) and two triangular substitutions; b is a
    vector or a matrix of k right-hand sides (its columns).

    Only the lower triangle of A is read. No pivoting is needed: for an SPD matrix every pivot d_j is
    a Schur complement's diagonal entry, bounded below by A's smallest eigenvalue, and the
    factorization is backward stable in that order (as Cholesky is). A singular leading block gives a
    zero pivot and a non-finite solution; callers pass matrices that are SPD by construction.
    Differentiable (plain arithmetic, no square root); gradients are finite wherever A is SPD.
    """
    n = A.shape[-1]
    if A.shape != (n, n) or b.ndim not in (1, 2) or b.shape[0] != n:
        raise ValueError(f"spd_solve expects A (n, n) and b (n,) or (n, k), got {A.shape} and {b.shape}")
    # A = L D L^T with unit lower-triangular L; L[i][j] for j < i, d[j] the pivots, inv_d their
    # reciprocals (one division per pivot).
    L = [[None] * n for _ in range(n)]
    d, inv_d = [], []
    for j in range(n):
        d.append(A[j, j] - sum((L[j][k] * L[j][k] * d[k] for k in range(j)), 0.0))
        inv_d.append(1.0 / d[j])
        for i in range(j + 1, n):
            L[i][j] = (A[i, j] - sum((L[i][k] * L[j][k] * d[k] for k in range(j)), 0.0)) * inv_d[j]
    # L y = b, then L^T x = y / d.
    y = []
    for i in range(n):
        y.append(b[i] - sum((L[i][k] * y[k] for k in range(i)), 0.0))
    x = [None] * n
    for i in reversed(range(n)):
        x[i] = y[i] * inv_d[i] - sum((L[k][i] * x[k] for k in range(i + 1, n)), 0.0)
    return jnp.stack(x)


def spd_inverse(A: Float[Array, "n n"]) -> Float[Array, "n n"]:
    """A^-1 for a small symmetric positive definite A (`spd_solve` on the identity). Only the lower
    triangle of A is read. The columns' rounding differs, so the result is made exactly symmetric: an
    information matrix must be, and so must a preconditioner for conjugate gradients."""
    X = spd_solve(A, jnp.eye(A.shape[-1], dtype=A.dtype))
    return 0.5 * (X + X.T)
