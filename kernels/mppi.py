"""MPPI local controller for a holonomic planar robot (x, y, theta; commands vx, vy, yaw rate).

Each step samples `n_samples` command sequences of `horizon` steps around the nominal sequence
(Gaussian noise, clipped to the limits; sample 0 is the nominal itself, sample 1 standing still), rolls
them through the kinematic model, scores them with the critics of `kernels.critics`, and replaces the
nominal by their softmax-weighted mean (weights exp(-(cost - min cost) / temperature)). The first
command is sent and the nominal shifted by one step. `dt` is both the model step and the control period.

Goal: inside `goal_xy_tol` the robot turns to the goal yaw while a proportional step (`k_xy`, scaled to the
speed limits) keeps closing the position error (as Nav2's MPPI keeps its goal critic on until the goal checker
is satisfied, rather than stopping at the tolerance's edge), where a turn in place keeps the footprint off known
obstacles (`critics.turn_is_clear`); elsewhere the sampled commands, scored by the goal critics, go on; it has
arrived when the yaw error is also inside `goal_yaw_tol` (0.25 m / 0.25 rad, the paper's tolerances).

Stuck recovery (Nav2's progress checker, then its backup, spin and wait behaviours): when the robot has not
moved `progress_radius` from its last progress point for `progress_timeout`, for `recovery_time` it backs up at
`backup_speed` if its footprint's disks stay below inscribed cost all along that backup and 0.1 m more, else
turns in place at `recovery_yaw_rate` if the turn keeps them off known obstacles (`critics.turn_is_clear`), else
stands still (in a gap barely wider than the body neither is safe); then the nominal sequence restarts from
zero.

Standing (arrived, or a recovery that may neither back up nor turn) holds the pose where it began (`hold`): a
trotting gait told to stand still drifts by centimetres a second, enough to walk a robot pressed against an
obstacle's padding into it.
"""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
from jaxtyping import Array, Bool, Float, Key

from jaxquad.kernels import critics
from jaxquad.kernels.costmap import INSCRIBED, CostGrid
from jaxquad.kernels.lie import R2, wrap_angle

_BACKUP_MARGIN = 0.1  # m of free room asked for beyond the backup's own length
_BACKUP_CHECKS = 8  # poses checked along it


class MppiParams(eqx.Module):
    """Controller numbers: traced leaves (units in comments), sample count and horizon static."""

    dt: Float[Array, ""]  # s, model step = control period
    v_max: Float[Array, " 3"]  # vx, vy (m/s), yaw rate (rad/s) upper limits
    v_min: Float[Array, " 3"]  # lower limits
    noise_std: Float[Array, " 3"]  # sampling std of vx, vy, yaw rate
    temperature: Float[Array, ""]  # softmax temperature, in cost units
    weights: Float[Array, " 7"]  # obstacle, goal distance, goal heading, path follow, path align, path heading, smooth
    collision_cost: Float[Array, ""]  # added to the obstacle critic for a trajectory entering a >= 253 cell
    footprint_disks: Float[Array, "K 2"]  # m, base-frame centres of the disks the obstacle critic checks
    footprint_outline: Float[Array, "C 2"]  # m, base-frame outline points kept off lethal and unknown cells (C >= 0)
    near_goal_radius: Float[Array, ""]  # m: goal critics replace path critics inside this (straight and along the path)
    lookahead: Float[Array, ""]  # m along the path from the robot's nearest path point to the carrot
    goal_xy_tol: Float[Array, ""]  # m
    goal_yaw_tol: Float[Array, ""]  # rad
    k_yaw: Float[Array, ""]  # 1/s, yaw rate per rad of error when turning at the goal
    k_xy: Float[Array, ""]  # 1/s, velocity per m of position error when turning at the goal
    progress_radius: Float[Array, ""]  # m
    progress_timeout: Float[Array, ""]  # s
    recovery_time: Float[Array, ""]  # s
    backup_speed: Float[Array, ""]  # m/s
    recovery_yaw_rate: Float[Array, ""]  # rad/s
    hold_gain: Float[Array, ""]  # 1/s: velocity per m (and yaw rate per rad) back to the pose where standing began
    hold_radius: Float[Array, ""]  # m: a hold point farther than this (the pose jumped) is given up for the pose
    n_samples: int = eqx.field(static=True)
    horizon: int = eqx.field(static=True)
    path_window: int = eqx.field(static=True)  # path points scored by the path-align critic

    @classmethod
    def default(
        cls,
        n_samples: int = 1000,
        horizon: int = 40,
        path_window: int = 16,
        **overrides,
    ) -> MppiParams:
        """`footprint_disks` defaults to one disk at the base origin (a round robot of the costmap's inscribed
        radius) and `footprint_outline` to none; `kernels.footprint.footprint_disks` and `footprint_outline` give a
        rectangular robot's."""
        # Speed limits: the paper's DWB limits (0.26 m/s, 0.8 rad/s), sideways and backwards slower.
        values = {
            "dt": 0.1,
            "v_max": (0.26, 0.15, 0.8),
            "v_min": (-0.15, -0.15, -0.8),
            "noise_std": (0.15, 0.1, 0.4),
            "temperature": 0.1,
            "weights": (1.0, 8.0, 3.0, 5.0, 2.0, 1.0, 1.0),
            "collision_cost": 1000.0,
            "footprint_disks": ((0.0, 0.0),),
            "footprint_outline": jnp.zeros((0, 2)),
            "near_goal_radius": 0.8,
            "lookahead": 1.0,
            "goal_xy_tol": 0.25,
            "goal_yaw_tol": 0.25,
            "k_yaw": 1.5,
            "k_xy": 0.8,
            "progress_radius": 0.5,
            "progress_timeout": 10.0,
            "recovery_time": 2.0,
            "backup_speed": 0.1,
            "recovery_yaw_rate": 0.5,
            "hold_gain": 2.0,
            "hold_radius": 0.15,
        }
        values.update(overrides)
        leaves = {k: jnp.asarray(v, jnp.float32) for k, v in values.items()}
        return cls(**leaves, n_samples=n_samples, horizon=horizon, path_window=path_window)


class MppiState(eqx.Module):
    nominal: Float[Array, "T 3"]  # body-frame command sequence vx, vy, yaw rate
    last_cmd: Float[Array, " 3"]
    anchor: Float[Array, " 2"]  # world position of the last progress
    since_progress: Float[Array, ""]  # s
    recovery_left: Float[Array, ""]  # s of recovery behaviour still to run
    recovery_cmd: Float[Array, " 3"]
    held_at: Float[Array, " 3"]  # the pose where standing began
    holding: Bool[Array, ""]  # the last tick stood


class MppiInputs(eqx.Module):
    pose: Float[Array, " 3"]  # estimated x, y (m), yaw (rad), world frame
    path: Float[Array, "P 2"]  # global path, world x, y (m), from the robot towards the goal
    path_valid: Bool[Array, " P"]
    goal: Float[Array, " 3"]  # x, y, yaw
    grid: CostGrid
    key: Key[Array, ""]


class MppiOutput(eqx.Module):
    cmd: Float[Array, " 3"]  # body-frame vx, vy (m/s), yaw rate (rad/s)
    arrived: Bool[Array, ""]
    recovering: Bool[Array, ""]
    goal_turn: Bool[Array, ""]  # inside the goal tolerance, turning in place to the goal's yaw (MPPI bypassed)
    valid: Bool[Array, ""]  # False when the pose, goal or path was not finite (then cmd = 0)
    trajectory: Float[Array, "T 3"]  # the chosen sequence's predicted states
    cost: Float[Array, ""]  # its total cost


def init(params: MppiParams, pose: Float[Array, " 3"]) -> MppiState:
    z3 = jnp.zeros(3, jnp.float32)
    return MppiState(
        nominal=jnp.zeros((params.horizon, 3), jnp.float32),
        last_cmd=z3,
        anchor=jnp.asarray(pose[:2], jnp.float32),
        since_progress=jnp.zeros((), jnp.float32),
        recovery_left=jnp.zeros((), jnp.float32),
        recovery_cmd=z3,
        held_at=jnp.asarray(pose, jnp.float32),
        holding=jnp.array(False),
    )


def rollout(pose: Float[Array, " 3"], u: Float[Array, "*S T 3"], dt: Float[Array, ""]) -> Float[Array, "*S T 3"]:
    """States after each step of the holonomic model (each step uses the heading at its start)."""
    theta = pose[2] + jnp.cumsum(u[..., 2] * dt, axis=-1)
    theta0 = jnp.concatenate([jnp.broadcast_to(pose[2], theta[..., :1].shape), theta[..., :-1]], axis=-1)
    c, s = jnp.cos(theta0), jnp.sin(theta0)
    dx = (c * u[..., 0] - s * u[..., 1]) * dt
    dy = (s * u[..., 0] + c * u[..., 1]) * dt
    return jnp.stack([pose[0] + jnp.cumsum(dx, -1), pose[1] + jnp.cumsum(dy, -1), theta], axis=-1)


def _path_targets(
    params: MppiParams, pose, path, path_valid
) -> tuple[Float[Array, " 2"], Float[Array, "K 2"], Float[Array, ""]]:
    """The carrot (lookahead along the path from the robot's nearest point), the local path window, and
    the length (m) left to the path's end from the robot."""
    last = jnp.maximum(jnp.sum(path_valid) - 1, 0)
    path = jnp.where(path_valid[:, None], path, path[last])  # invalid tail = the path's end
    d2 = jnp.where(path_valid, jnp.sum((path - pose[:2]) ** 2, axis=-1), jnp.inf)
    near = jnp.argmin(d2)
    seg = jnp.linalg.norm(jnp.diff(path, axis=0), axis=-1)
    arc = jnp.concatenate([jnp.zeros(1), jnp.cumsum(seg)])
    ahead = (arc - arc[near] >= params.lookahead) | (jnp.arange(path.shape[0]) >= last)
    k_carrot = jnp.argmax(ahead & (jnp.arange(path.shape[0]) >= near))
    # Window: path_window points evenly between the nearest point and the carrot.
    idx = near + jnp.round(jnp.linspace(0.0, 1.0, params.path_window) * (k_carrot - near).astype(jnp.float32)).astype(
        jnp.int32
    )
    remaining = jnp.sqrt(d2[near]) + arc[last] - arc[near]
    return path[k_carrot], path[idx], remaining


def _sample(params: MppiParams, nominal, key) -> Float[Array, "S T 3"]:
    eps = jax.random.normal(key, (params.n_samples, params.horizon, 3)) * params.noise_std
    eps = eps.at[0].set(0.0)
    u = jnp.clip(nominal + eps, params.v_min, params.v_max)
    return u.at[1].set(0.0)


def _total_cost(params: MppiParams, traj, u, last_cmd, inputs: MppiInputs, near_goal, carrot, window):
    w = params.weights
    terms = (
        critics.obstacle(traj, inputs.grid, params.collision_cost, params.footprint_disks, params.footprint_outline),
        critics.goal_distance(traj, inputs.goal, near_goal),
        critics.goal_heading(traj, inputs.goal, near_goal),
        critics.path_follow(traj, carrot, near_goal),
        critics.path_align(traj, window, near_goal),
        critics.path_heading(traj, carrot, near_goal),
        critics.smoothness(u, last_cmd),
    )
    return sum(w[i] * t for i, t in enumerate(terms))


def toward_pose(
    params: MppiParams,
    pose: Float[Array, " 3"],
    target: Float[Array, " 3"],
    k_xy: Float[Array, ""],
    k_yaw: Float[Array, ""],
) -> Float[Array, " 3"]:
    """Proportional step to a nearby pose: body-frame velocity `k_xy` (1/s) x the position error, scaled down as
    a whole (direction kept) into the speed limits, and yaw rate `k_yaw` (1/s) x the yaw error, clipped."""
    v_xy = k_xy * (R2(pose[2]).T @ (target[:2] - pose[:2]))
    lim = jnp.where(v_xy >= 0, params.v_max[:2], -params.v_min[:2])
    v_xy = v_xy * jnp.minimum(1.0, jnp.min(lim / jnp.maximum(jnp.abs(v_xy), 1e-9)))
    yaw_rate = jnp.clip(k_yaw * wrap_angle(target[2] - pose[2]), params.v_min[2], params.v_max[2])
    return jnp.append(v_xy, yaw_rate)


def hold(
    params: MppiParams, pose: Float[Array, " 3"], held_at: Float[Array, " 3"], holding: Bool[Array, ""]
) -> tuple[Float[Array, " 3"], Float[Array, " 3"]]:
    """(command, pose held) of a robot told to stand: a proportional step (`hold_gain`) back to the pose where
    standing began (`pose` on its first tick, `held_at` while `holding`), since a trotting gait told to stand
    still drifts. A hold point more than `hold_radius` away (the pose jumped, as at a loop closure; the drift is
    centimetres) is given up for the pose itself rather than walked back to unchecked; a non-finite pose stands
    still."""
    far = jnp.linalg.norm(pose[:2] - held_at[:2]) > params.hold_radius
    held_at = jnp.where(holding & ~far, held_at, pose)
    cmd = toward_pose(params, pose, held_at, params.hold_gain, params.hold_gain)
    return jnp.where(jnp.all(jnp.isfinite(pose)), cmd, 0.0), held_at


def _recovery_command(params: MppiParams, pose, grid: CostGrid) -> Float[Array, " 3"]:
    # Back up only if the footprint's disks stay clear along the whole backup (and a margin beyond it).
    back = params.backup_speed * params.recovery_time + _BACKUP_MARGIN
    along = jnp.linspace(0.0, 1.0, _BACKUP_CHECKS)[:, None] * back * jnp.array([jnp.cos(pose[2]), jnp.sin(pose[2])])
    path = jnp.concatenate([pose[:2] - along, jnp.full((_BACKUP_CHECKS, 1), pose[2])], axis=1)
    can_back = jnp.all(critics.footprint_cost(path[None], grid, params.footprint_disks) < INSCRIBED)
    can_turn = critics.turn_is_clear(pose, grid, params.footprint_disks)
    backup_cmd = jnp.array([-1.0, 0.0, 0.0]) * params.backup_speed
    turn_cmd = jnp.array([0.0, 0.0, 1.0]) * params.recovery_yaw_rate
    return jnp.where(can_back, backup_cmd, jnp.where(can_turn, turn_cmd, 0.0))


def step(params: MppiParams, state: MppiState, inputs: MppiInputs) -> tuple[MppiState, MppiOutput]:
    """One control tick: sample, score, reweight, shift; goal checking and stuck recovery."""
    pose, goal = inputs.pose, inputs.goal
    valid = jnp.all(jnp.isfinite(pose)) & jnp.all(jnp.isfinite(goal))
    valid = valid & jnp.all(jnp.where(inputs.path_valid[:, None], jnp.isfinite(inputs.path), True))
    pose = jnp.where(valid, pose, 0.0)
    goal = jnp.where(valid, goal, 0.0)
    inputs = eqx.tree_at(lambda x: (x.pose, x.goal), inputs, (pose, goal))

    goal_dist = jnp.linalg.norm(goal[:2] - pose[:2])
    yaw_err = wrap_angle(goal[2] - pose[2])
    at_xy = goal_dist < params.goal_xy_tol
    arrived = at_xy & (jnp.abs(yaw_err) < params.goal_yaw_tol)
    carrot, window, remaining = _path_targets(
        params,
        pose,
        jnp.where(inputs.path_valid[:, None], inputs.path, 0.0),
        inputs.path_valid,
    )
    # Near the goal along the path, not only in a straight line (a goal just behind a wall is far).
    near_goal = jnp.maximum(goal_dist, remaining) < params.near_goal_radius
    u = _sample(params, state.nominal, inputs.key)
    traj = rollout(pose, u, params.dt)
    cost = _total_cost(params, traj, u, state.last_cmd, inputs, near_goal, carrot, window)
    weights = jax.nn.softmax(-(cost - jnp.min(cost)) / params.temperature)
    nominal = jnp.einsum("s,stc->tc", weights, u)
    mppi_cmd = nominal[0]

    turn = toward_pose(params, pose, goal, params.k_xy, params.k_yaw)
    turning = at_xy & critics.turn_is_clear(pose, inputs.grid, params.footprint_disks)
    cmd = jnp.where(turning, turn, mppi_cmd)  # arrived: the hold below

    # Progress checker and recovery.
    moved = jnp.linalg.norm(pose[:2] - state.anchor) > params.progress_radius
    since = jnp.where(moved | at_xy, 0.0, state.since_progress + params.dt)
    anchor = jnp.where(moved | at_xy, pose[:2], state.anchor)
    # Timers count in float32 ticks of dt: half a tick absorbs their rounding.
    start_recovery = (since > params.progress_timeout) & (state.recovery_left < 0.5 * params.dt)
    recovery_cmd = jnp.where(start_recovery, _recovery_command(params, pose, inputs.grid), state.recovery_cmd)
    recovery_left = jnp.where(start_recovery, params.recovery_time, state.recovery_left)
    recovering = recovery_left > 0.5 * params.dt
    cmd = jnp.where(recovering, recovery_cmd, cmd)
    standing = jnp.where(recovering, jnp.all(recovery_cmd == 0.0), arrived) & valid
    hold_cmd, held_at = hold(params, pose, state.held_at, state.holding)
    cmd = jnp.where(standing, hold_cmd, cmd)
    ended = recovering & (recovery_left < 1.5 * params.dt)
    since = jnp.where(recovering, 0.0, since)
    anchor = jnp.where(recovering, pose[:2], anchor)

    cmd = jnp.where(valid, cmd, 0.0)
    keep = valid & ~recovering & ~turning & ~arrived
    shifted = jnp.concatenate([nominal[1:], nominal[-1:]], axis=0)
    new_state = MppiState(
        nominal=jnp.where(keep & ~ended, shifted, 0.0),
        last_cmd=cmd,
        anchor=anchor,
        since_progress=since,
        recovery_left=jnp.maximum(recovery_left - params.dt, 0.0),
        recovery_cmd=recovery_cmd,
        held_at=held_at,
        holding=standing,
    )
    best = rollout(pose, nominal, params.dt)
    out = MppiOutput(
        cmd=cmd,
        arrived=arrived & valid,
        recovering=recovering,
        goal_turn=turning & valid & ~recovering & ~arrived,
        valid=valid,
        trajectory=best,
        cost=jnp.sum(weights * cost),
    )
    return new_state, out
