"""Analytic kinematics of 3-dof quadruped legs (abduction about x, thigh and knee about y).

Each leg is described in its trunk frame at zero joint angles: the abduction anchor, the offsets
hip -> thigh anchor -> knee anchor -> foot centre, and the sign of each joint axis (+x/-x, +y/-y).
Arrays carry one row per leg; every function broadcasts over leading leg axes.
"""

from __future__ import annotations

import equinox as eqx
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Bool, Float

from jaxquad.kernels.lie import SO3, wrap_angle

# Keeps the solution off the fully stretched / fully folded singularities (m).
_REACH_MARGIN = 1e-3


class LegGeometry(eqx.Module):
    """Leg kinematics in the trunk frame at zero joint angles (one row per leg, units m; no leg axis under vmap).

    `axis_sign` is +1 where the joint turns about +x (abduction) or +y (thigh, knee), -1 where it
    turns about the negative axis. `knee_bend` picks the knee branch (+1/-1) of the nominal stand.
    """

    p_trunk_hip: Float[Array, "*L 3"]
    d_hip_thigh: Float[Array, "*L 3"]
    d_thigh_knee: Float[Array, "*L 3"]
    d_knee_foot: Float[Array, "*L 3"]
    axis_sign: Float[Array, "*L 3"]
    knee_bend: Float[Array, "*L"]
    q_min: Float[Array, "*L 3"]
    q_max: Float[Array, "*L 3"]


def leg_fk(geom: LegGeometry, q_leg: Float[Array, "*L 3"]) -> Float[Array, "*L 3"]:
    """Foot centres in the trunk frame for joint angles (abduction, thigh, knee) in rad."""
    angle = geom.axis_sign * q_leg
    w = geom.d_thigh_knee + SO3.from_y_radians(angle[..., 2]).apply(geom.d_knee_foot)
    v = geom.d_hip_thigh + SO3.from_y_radians(angle[..., 1]).apply(w)
    return geom.p_trunk_hip + SO3.from_x_radians(angle[..., 0]).apply(v)


def leg_ik(geom: LegGeometry, p_trunk_foot: Float[Array, "*L 3"]) -> tuple[Float[Array, "*L 3"], Bool[Array, "*L"]]:
    """Joint angles (rad) placing each foot centre at `p_trunk_foot` (m, trunk frame).

    Targets out of reach are pulled onto the reachable shell along the same direction and the
    angles are clipped to the joint ranges; the flag says whether the exact target was reachable.
    """
    p = p_trunk_foot - geom.p_trunk_hip
    d1, d2, d3 = geom.d_hip_thigh, geom.d_thigh_knee, geom.d_knee_foot
    # Rotations about y keep the lateral coordinate, so the whole lateral offset is fixed by the
    # chain and the abduction angle alone brings it onto the target's (y, z) direction.
    l_y = d1[..., 1] + d2[..., 1] + d3[..., 1]
    r2_yz = p[..., 1] ** 2 + p[..., 2] ** 2
    inside_abd = r2_yz > l_y**2 + _REACH_MARGIN**2
    v_z = -jnp.sqrt(jnp.maximum(r2_yz - l_y**2, _REACH_MARGIN**2))
    abd = jnp.arctan2(p[..., 2], p[..., 1]) - jnp.arctan2(v_z, l_y)

    # Sagittal plane in complex form c = z + i x, where a y rotation by a multiplies by e^{ia}.
    w_z, w_x = v_z - d1[..., 2], p[..., 0] - d1[..., 0]
    l2 = jnp.hypot(d2[..., 2], d2[..., 0])
    l3 = jnp.hypot(d3[..., 2], d3[..., 0])
    r_min = jnp.abs(l2 - l3) + _REACH_MARGIN
    r_max = l2 + l3 - _REACH_MARGIN
    r = jnp.maximum(jnp.hypot(w_z, w_x), 1e-9)
    r_c = jnp.clip(r, r_min, r_max)
    cos_k = (r_c**2 - l2**2 - l3**2) / (2.0 * l2 * l3)
    phi2 = jnp.arctan2(d2[..., 0], d2[..., 2])
    phi3 = jnp.arctan2(d3[..., 0], d3[..., 2])
    knee = phi2 - phi3 + geom.knee_bend * jnp.arccos(jnp.clip(cos_k, -1.0, 1.0))
    wk_z = d2[..., 2] + jnp.cos(knee) * d3[..., 2] - jnp.sin(knee) * d3[..., 0]
    wk_x = d2[..., 0] + jnp.sin(knee) * d3[..., 2] + jnp.cos(knee) * d3[..., 0]
    thigh = jnp.arctan2(w_x, w_z) - jnp.arctan2(wk_x, wk_z)

    angle = wrap_angle(jnp.stack([abd, thigh, knee], -1))
    q = jnp.clip(geom.axis_sign * angle, geom.q_min, geom.q_max)
    reachable = inside_abd & (r >= r_min) & (r <= r_max)
    return q, reachable


def knee_branch(
    d_thigh_knee: np.ndarray, d_knee_foot: np.ndarray, axis_sign: np.ndarray, q_leg: np.ndarray
) -> np.ndarray:
    """Knee branch (+1/-1) that reproduces the knee angle of a reference pose (e.g. the stand)."""
    phi2 = np.arctan2(d_thigh_knee[..., 0], d_thigh_knee[..., 2])
    phi3 = np.arctan2(d_knee_foot[..., 0], d_knee_foot[..., 2])
    a = axis_sign[..., 2] * q_leg[..., 2] + phi3 - phi2
    return np.where(np.sin(a) >= 0.0, 1.0, -1.0)
