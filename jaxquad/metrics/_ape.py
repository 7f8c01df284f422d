"""Absolute pose error: per-pose error of E = est^-1 ref (evo's APE)."""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
from jaxtyping import Array, Float

from jaxquad.metrics._se3 import rotation_angle


class PoseErrors(eqx.Module):
    """Per-pose (or per-pair) errors of error transforms E in every pose relation.

    translation_m: |t(E)|; angle_rad: |log R(E)|; rotation_part: ||R(E) - I||_F;
    full: ||E - I_4||_F (dimensionless mix of the two parts, as evo defines it).
    """

    translation_m: Float[Array, "N"]
    angle_rad: Float[Array, "N"]
    rotation_part: Float[Array, "N"]
    full: Float[Array, "N"]


def pose_errors(R_err: Float[Array, "N 3 3"], t_err: Float[Array, "N 3"]) -> PoseErrors:
    """Errors of the transforms [R_err | t_err]."""
    eye = jnp.eye(3, dtype=R_err.dtype)
    rot_sq = jnp.sum((R_err - eye) ** 2, axis=(-2, -1))
    trans_sq = jnp.sum(t_err * t_err, axis=-1)
    return PoseErrors(
        translation_m=jnp.sqrt(trans_sq),
        angle_rad=jax.vmap(rotation_angle)(R_err),
        rotation_part=jnp.sqrt(rot_sq),
        full=jnp.sqrt(rot_sq + trans_sq),
    )


def ape(
    p_ref: Float[Array, "N 3"],
    R_ref: Float[Array, "N 3 3"],
    p_est: Float[Array, "N 3"],
    R_est: Float[Array, "N 3 3"],
) -> PoseErrors:
    """APE of an (already aligned) estimate against the reference, pose by pose: E = est^-1 ref."""
    R_est_T = jnp.swapaxes(R_est, -1, -2)
    R_err = R_est_T @ R_ref
    t_err = jnp.einsum("nij,nj->ni", R_est_T, p_ref - p_est)
    return pose_errors(R_err, t_err)
