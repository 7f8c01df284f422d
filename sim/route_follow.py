"""Looping route follower: waypoints and the planar pose -> body velocity command (pure pursuit)."""

from __future__ import annotations

import equinox as eqx
import jax.numpy as jnp
from jaxtyping import Array, Bool, Float, Int

from jaxquad.kernels.lie import wrap_angle


class RouteParams(eqx.Module):
    """Per-robot follower numbers (traced leaves, so a fleet can randomize them under vmap)."""

    v_max: Float[Array, ""]  # forward speed on straight segments (m/s)
    yaw_rate_max: Float[Array, ""]  # rad/s
    k_yaw: Float[Array, ""]  # yaw rate per rad of heading error (1/s)
    k_lateral: Float[Array, ""]  # lateral speed per unit sin(heading error), as a share of v_max
    lookahead: Float[Array, ""]  # distance of the pursued point ahead of the projection (m)
    switch_radius: Float[Array, ""]  # a waypoint counts as reached inside this radius (m)

    @classmethod
    def default(cls, v_max: float = 0.4, **overrides: float) -> "RouteParams":
        values = dict(v_max=v_max, yaw_rate_max=1.0, k_yaw=1.5, k_lateral=0.3, lookahead=0.5, switch_radius=0.3)
        values.update(overrides)
        return cls(**{k: jnp.asarray(v, jnp.float32) for k, v in values.items()})


class RouteState(eqx.Module):
    target: Int[Array, ""]  # index of the waypoint being approached
    laps: Int[Array, ""]  # times waypoint 0 has been reached (starting on it counts once)


def route_init(waypoints: Float[Array, "K 2"], p_world_base: Float[Array, " 2"]) -> RouteState:
    """Start by approaching the waypoint nearest to the robot."""
    nearest = jnp.argmin(jnp.sum((waypoints - p_world_base) ** 2, -1))
    return RouteState(target=nearest.astype(jnp.int32), laps=jnp.zeros((), jnp.int32))


def _segment(waypoints: Float[Array, "K 2"], i: Int[Array, ""]) -> tuple[Array, Array]:
    k = waypoints.shape[0]
    return waypoints[(i - 1) % k], waypoints[i % k]


def _project(p: Array, a: Array, b: Array) -> Float[Array, ""]:
    ab = b - a
    return jnp.clip(jnp.dot(p - a, ab) / jnp.maximum(jnp.dot(ab, ab), 1e-12), 0.0, 1.0)


def route_step(
    params: RouteParams,
    state: RouteState,
    waypoints: Float[Array, "K 2"],
    pose_world_base: Float[Array, " 3"],
) -> tuple[RouteState, tuple[Float[Array, " 3"], Bool[Array, ""]]]:
    """Velocity command (vx, vy in m/s, yaw rate in rad/s; body frame) following the closed loop.

    `pose_world_base` is (x, y, yaw). The pursued point lies `lookahead` metres along the route
    past the projection on the current segment, spilling onto the next one. Returns the new state
    and (command, validity flag); a non-finite pose gives a zero command and keeps the state.
    """
    k = waypoints.shape[0]
    p, yaw = pose_world_base[:2], pose_world_base[2]
    valid = jnp.all(jnp.isfinite(pose_world_base))

    a, b = _segment(waypoints, state.target)
    reached = (jnp.linalg.norm(p - b) < params.switch_radius) | (_project(p, a, b) >= 1.0)
    target = jnp.where(reached, (state.target + 1) % k, state.target)
    laps = state.laps + (reached & (target == 1 % k)).astype(jnp.int32)

    a, b = _segment(waypoints, target)
    c = waypoints[(target + 1) % k]
    ab_len = jnp.maximum(jnp.linalg.norm(b - a), 1e-9)
    along = _project(p, a, b) * ab_len + params.lookahead
    spill = jnp.maximum(along - ab_len, 0.0)
    bc = c - b
    bc_dir = bc / jnp.maximum(jnp.linalg.norm(bc), 1e-9)
    goal = jnp.where(
        along <= ab_len, a + (b - a) * (along / ab_len), b + bc_dir * jnp.minimum(spill, jnp.linalg.norm(bc))
    )

    d = goal - p
    err = wrap_angle(jnp.arctan2(d[1], d[0]) - yaw)
    forward = params.v_max * jnp.clip(jnp.cos(err), 0.0, 1.0) ** 2
    lateral = params.k_lateral * params.v_max * jnp.sin(err)
    yaw_rate = jnp.clip(params.k_yaw * err, -params.yaw_rate_max, params.yaw_rate_max)
    cmd = jnp.stack([forward, lateral, yaw_rate])

    cmd = jnp.where(valid, cmd, 0.0)
    new_state = RouteState(
        target=jnp.where(valid, target, state.target).astype(jnp.int32),
        laps=jnp.where(valid, laps, state.laps).astype(jnp.int32),
    )
    return new_state, (cmd, valid)
