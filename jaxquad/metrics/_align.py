"""Umeyama alignment of an estimated trajectory to a reference (positions only), as evo does it."""

from __future__ import annotations

import equinox as eqx
import jax.numpy as jnp
from jaxtyping import Array, Bool, Float

ALIGN_MODES = ("se3", "sim3", "scale", "origin", "none")


class Alignment(eqx.Module):
    """x_ref ~ scale * R_ref_est @ x_est + t_ref_est; `ok` is False when the mode needed a
    non-degenerate point set and did not get one (then R = I, t = 0, scale = 1)."""

    R_ref_est: Float[Array, "3 3"]
    t_ref_est: Float[Array, "3"]
    scale: Float[Array, ""]
    ok: Bool[Array, ""]


def umeyama(p_est: Float[Array, "N 3"], p_ref: Float[Array, "N 3"], with_scale: bool) -> Alignment:
    """Least-squares similarity (Umeyama 1991, eqs. 34-43) mapping p_est onto p_ref.

    Degenerate when fewer than 2 singular values of the cross-covariance exceed eps (evo's rank
    test; eps scaled by max(1, largest singular value) so float32 batches flag near-collinear sets).
    """
    n = p_est.shape[0]
    mu_est = jnp.mean(p_est, axis=0)
    mu_ref = jnp.mean(p_ref, axis=0)
    d_est = p_est - mu_est
    d_ref = p_ref - mu_ref
    var_est = jnp.sum(d_est * d_est) / n  # eq. 36
    cov = d_ref.T @ d_est / n  # eq. 38, Sigma_xy = mean (y - mu_y)(x - mu_x)^T
    U, D, Vt = jnp.linalg.svd(cov)
    eps = jnp.finfo(cov.dtype).eps * jnp.maximum(1.0, D[0])
    ok = (jnp.sum(eps < D) >= 2) & (n >= 3) & (var_est > 0)
    # eq. 43: reflect the last axis when U V^T would be a reflection.
    sign = jnp.where(jnp.linalg.det(U) * jnp.linalg.det(Vt) < 0, -1.0, 1.0)
    S = jnp.array([1.0, 1.0, sign], dtype=cov.dtype)
    R = (U * S) @ Vt  # eq. 40
    scale = jnp.sum(D * S) / jnp.where(var_est > 0, var_est, 1.0) if with_scale else jnp.ones((), cov.dtype)
    t = mu_ref - scale * R @ mu_est  # eq. 41
    eye = jnp.eye(3, dtype=cov.dtype)
    return Alignment(
        R_ref_est=jnp.where(ok, R, eye),
        t_ref_est=jnp.where(ok, t, 0.0),
        scale=jnp.where(ok, scale, 1.0),
        ok=ok,
    )


def align(
    p_ref: Float[Array, "N 3"],
    R_ref: Float[Array, "N 3 3"],
    p_est: Float[Array, "N 3"],
    R_est: Float[Array, "N 3 3"],
    mode: str,
) -> tuple[Float[Array, "N 3"], Float[Array, "N 3 3"], Alignment]:
    """Aligned estimate (positions, rotations) and the alignment applied.

    se3: rigid Umeyama; sim3: the estimate is scaled by c, then moved rigidly; scale: only scaled by
    the Umeyama c; origin: left-multiplied by ref_0 est_0^-1; none: unchanged.
    """
    dtype = p_est.dtype
    eye, zero, one = jnp.eye(3, dtype=dtype), jnp.zeros(3, dtype), jnp.ones((), dtype)
    if mode in ("se3", "sim3", "scale"):
        a = umeyama(p_est, p_ref, with_scale=mode != "se3")
        if mode == "scale":
            a = Alignment(eye, zero, a.scale, a.ok)
    elif mode == "origin":
        R = R_ref[0] @ R_est[0].T
        a = Alignment(R, p_ref[0] - R @ p_est[0], one, jnp.array(True))
    elif mode == "none":
        a = Alignment(eye, zero, one, jnp.array(True))
    else:
        raise ValueError(f"unknown alignment {mode!r}; expected one of {', '.join(ALIGN_MODES)}")
    p_aligned = (a.scale * p_est) @ a.R_ref_est.T + a.t_ref_est
    R_aligned = a.R_ref_est @ R_est
    return p_aligned, R_aligned, a
