"""Gait clock, swing-foot trajectories and the Raibert foothold rule."""

from __future__ import annotations

import jax.numpy as jnp
from jaxtyping import Array, Bool, Float

# Trot: diagonal pairs (FL, RR) and (FR, RL) half a cycle apart; legs in FL FR RL RR order.
TROT_OFFSETS = (0.0, 0.5, 0.5, 0.0)


def leg_phases(
    phase: Float[Array, ""], offsets: Float[Array, " L"], duty: Float[Array, ""]
) -> tuple[Bool[Array, " L"], Float[Array, " L"]]:
    """Stance flags and progress in [0, 1) through the current stance or swing of each leg.

    `phase` is the gait-cycle phase in cycles (any real number); a leg is in stance for the first
    `duty` of its own cycle (`phase + offset`, mod 1) and swings for the rest.
    """
    leg = jnp.mod(phase + offsets, 1.0)
    stance = leg < duty
    progress = jnp.where(stance, leg / duty, (leg - duty) / (1.0 - duty))
    return stance, progress


def swing_position(
    p_lift: Float[Array, "L 3"],
    p_land: Float[Array, "L 3"],
    s: Float[Array, " L"],
    height: Float[Array, ""],
) -> Float[Array, "L 3"]:
    """Swing-foot position at progress `s` in [0, 1] between lift-off and landing.

    Horizontal motion follows a cubic smoothstep (zero velocity at both ends); the vertical bump
    16 h s^2 (1 - s)^2 peaks at `height` (m) at mid-swing and also starts and ends at rest.
    """
    s = jnp.clip(s, 0.0, 1.0)[..., None]
    blend = s * s * (3.0 - 2.0 * s)
    bump = 16.0 * height * (s * (1.0 - s)) ** 2
    return p_lift + blend * (p_land - p_lift) + bump * jnp.array([0.0, 0.0, 1.0])


def raibert_foothold(
    p_hip: Float[Array, "L 2"],
    v_body: Float[Array, " 2"],
    v_cmd: Float[Array, " 2"],
    yaw_rate_cmd: Float[Array, ""],
    t_stance: Float[Array, ""],
    k_feedback: Float[Array, ""],
) -> Float[Array, "L 2"]:
    """Planar foothold under each hip (m): p_hip + v_hip T_stance / 2 + k (v - v_cmd).

    v_hip is the commanded velocity of the hip point, planar body velocity plus the yaw rate's
    share (w x p_hip), so turning steps land symmetrically about the hip during the next stance.
    """
    v_hip = v_cmd + yaw_rate_cmd * jnp.stack([-p_hip[:, 1], p_hip[:, 0]], -1)
    return p_hip + 0.5 * t_stance * v_hip + k_feedback * (v_body - v_cmd)
