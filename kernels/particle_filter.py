"""Monte Carlo localization of one robot on a known map, as AMCL does it, in pure JAX.

Particles (x, y, theta) live in a fixed-capacity array with a mask (inactive slots carry weight 0
and are never resampled), so a filter is a fixed-shape pytree that `vmap`s over robots. Per scan:

1. Nothing happens until the odometry has moved `update_min_d` (m) or turned `update_min_a` (rad)
   since the last update (the first scan always updates), as AMCL.
2. Motion: the omnidirectional odometry model (Nav2's `OmniMotionModel`): the odometry change since
   the last update is split into a translation `t` along its bearing, a strafe across it and a
   rotation `r`, each perturbed by zero-mean Gaussian noise with standard deviations
   sqrt(a3 t^2 + a4 r^2), sqrt(a4 r^2 + a5 t^2) and sqrt(a1 r^2 + a2 t^2); the bearing is taken
   relative to each particle's own heading.
3. Measurement: the likelihood-field weight (kernels.likelihood_field) of `n_beams` beams.
4. Recovery averages (Thrun et al., Probabilistic Robotics, Augmented MCL; AMCL's rule):
   w_slow += alpha_slow (w_avg - w_slow), w_fast += alpha_fast (w_avg - w_fast), with w_avg the
   weighted mean likelihood of the scan; a resampled particle is replaced by a random pose on the
   map's free cells with probability max(0, 1 - w_fast / w_slow), and the averages restart after
   such an injection. Kept in the log domain so that any likelihood scale is safe.
5. Resampling: low-variance (systematic) when the effective sample size 1 / sum w^2 falls below
   `resample_ratio` times the active count, or when random particles are due.
"""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Bool, Float, Key, UInt32

from jaxquad.kernels.lie import SE2, wrap_angle
from jaxquad.kernels.likelihood_field import LikelihoodField, sample_free_poses, scan_likelihood

__all__ = [
    "AmclInputs",
    "AmclOutput",
    "AmclParams",
    "AmclState",
    "amcl_init",
    "amcl_step",
    "effective_sample_size",
    "measurement_update",
    "omni_motion",
    "pose_estimate",
    "systematic_resample",
]


class AmclParams(eqx.Module):
    """Tunable numbers (traced leaves; SI units) and the beam count (static)."""

    alpha: Float[Array, "5"]  # motion noise a1..a5 (rot<-rot, rot<-trans, trans<-trans, trans<-rot, strafe<-trans)
    z_hit: Float[Array, ""]  # weight of the Gaussian hit term
    z_rand: Float[Array, ""]  # weight of the uniform term (divided by range_max)
    sigma_hit: Float[Array, ""]  # m, std of the hit term
    range_min: Float[Array, ""]  # m, shorter readings are skipped
    range_max: Float[Array, ""]  # m, readings at or beyond are skipped
    update_min_d: Float[Array, ""]  # m of odometry travel before an update
    update_min_a: Float[Array, ""]  # rad of odometry rotation before an update
    alpha_slow: Float[Array, ""]  # rate of the long-term likelihood average
    alpha_fast: Float[Array, ""]  # rate of the short-term likelihood average
    resample_ratio: Float[Array, ""]  # resample when n_eff < ratio * active particles
    init_std: Float[Array, "3"]  # std (m, m, rad) of the particles around a given initial pose
    T_base_laser: Float[Array, "3"]  # laser (x, y, yaw) in the base frame (m, m, rad)
    n_beams: int = eqx.field(static=True, default=60)  # beams used per scan (evenly subsampled)

    @classmethod
    def paper(cls, n_beams: int = 60, **overrides) -> AmclParams:
        """The paper's AMCL numbers (alpha1-5 0.2, sigma_hit 0.2, z_hit 0.5, z_rand 0.5, 0.25 m / 0.2 rad),
        AMCL's recovery rates (0.001 / 0.1) and Nav2's initial spread (0.5 m, pi/12 rad)."""
        values = dict(
            alpha=[0.2] * 5,
            z_hit=0.5,
            z_rand=0.5,
            sigma_hit=0.2,
            range_min=0.2,
            range_max=8.0,
            update_min_d=0.25,
            update_min_a=0.2,
            alpha_slow=0.001,
            alpha_fast=0.1,
            resample_ratio=0.5,
            init_std=[0.5, 0.5, np.pi / 12],
            T_base_laser=[0.0, 0.0, 0.0],
        )
        unknown = set(overrides) - set(values)
        if unknown:
            raise ValueError(f"unknown AMCL parameter(s) {sorted(unknown)}")
        values |= overrides
        return cls(**{k: jnp.asarray(v, jnp.float32) for k, v in values.items()}, n_beams=n_beams)


class AmclState(eqx.Module):
    poses: Float[Array, "P 3"]  # world x, y (m), theta (rad)
    log_w: Float[Array, "P"]  # normalized log weights; -inf on inactive slots
    mask: Bool[Array, "P"]  # active slots
    odom_ref: Float[Array, "3"]  # odometry pose at the last update
    started: Bool[Array, ""]  # a scan has been used
    log_w_slow: Float[Array, ""]  # log of the long-term likelihood average (-inf = not set)
    log_w_fast: Float[Array, ""]
    mean: Float[Array, "3"]  # estimate of the weighted set at the last update, before resampling
    cov: Float[Array, "3 3"]


class AmclInputs(eqx.Module):
    """One scan's inputs; leading axes B (robots, scans) when stacked for vmap or scan."""

    odom: Float[Array, "*B 3"]  # odometry pose x, y (m), theta (rad) at the scan
    ranges: Float[Array, "*B W"]  # m; inf / nan / out of range = no reading
    bearings: Float[Array, "*B W"]  # rad, counter-clockwise from the laser's x axis
    key: Key[Array, "*B"] | UInt32[Array, "*B 2"]  # a typed or a legacy (uint32) key


class AmclOutput(eqx.Module):
    pose: Float[Array, "3"]  # weighted mean x, y, circular-mean theta, moved by the odometry since the update
    cov: Float[Array, "3 3"]  # weighted covariance (theta deviations wrapped)
    n_eff: Float[Array, ""]  # effective sample size after the step
    updated: Bool[Array, ""]  # the filter ran on this scan
    resampled: Bool[Array, ""]
    p_random: Float[Array, ""]  # probability of a random particle at this update


def omni_motion(
    key: Array,
    poses: Float[Array, "P 3"],
    odom_old: Float[Array, "3"],
    odom_new: Float[Array, "3"],
    alpha: Float[Array, "5"],
) -> Float[Array, "P 3"]:
    """Sample the omnidirectional odometry motion model for every particle."""
    d = odom_new - odom_old
    trans = jnp.hypot(d[0], d[1])
    rot = wrap_angle(d[2])
    sd_trans = jnp.sqrt(alpha[2] * trans**2 + alpha[3] * rot**2)
    sd_rot = jnp.sqrt(alpha[0] * rot**2 + alpha[1] * trans**2)
    sd_strafe = jnp.sqrt(alpha[3] * rot**2 + alpha[4] * trans**2)
    n = jax.random.normal(key, poses.shape, poses.dtype)
    # Direction of travel relative to the odometry heading, carried into each particle's heading.
    bearing = wrap_angle(jnp.arctan2(d[1], d[0]) - odom_old[2]) + poses[:, 2]
    t_hat = trans + sd_trans * n[:, 0]
    s_hat = sd_strafe * n[:, 1]
    r_hat = rot + sd_rot * n[:, 2]
    c, s = jnp.cos(bearing), jnp.sin(bearing)
    return jnp.stack(
        [poses[:, 0] + t_hat * c + s_hat * s, poses[:, 1] + t_hat * s - s_hat * c, wrap_angle(poses[:, 2] + r_hat)], -1
    )


def effective_sample_size(log_w: Float[Array, "P"]) -> Float[Array, ""]:
    """1 / sum w^2 of normalized log weights (-inf slots count as 0)."""
    return jnp.exp(-jax.nn.logsumexp(2.0 * log_w))


def systematic_resample(log_w: Float[Array, "P"], mask: Bool[Array, "P"], u: Float[Array, ""]) -> Array:
    """Low-variance resampling: the k-th active slot draws the particle whose cumulative weight
    first exceeds (u + k) / n, u in [0, 1), n = active count. Returns (P,) source indices (inactive
    slots keep their own index). Zero-weight particles are never drawn."""
    w = jnp.where(mask, jnp.exp(log_w), 0.0)
    cdf = jnp.cumsum(w)
    cdf = cdf / cdf[-1]
    n = jnp.sum(mask)
    rank = jnp.cumsum(mask) - 1
    pos = jnp.minimum((u + rank.astype(u.dtype)) / n.astype(u.dtype), jnp.nextafter(jnp.float32(1.0), jnp.float32(0.0)))
    idx = jnp.searchsorted(cdf, pos, side="right")
    return jnp.where(mask, idx, jnp.arange(mask.shape[0]))


def measurement_update(
    params: AmclParams, state: AmclState, log_lik: Float[Array, "P"], random_poses: Float[Array, "P 3"], key: Array
) -> tuple[AmclState, tuple[Array, Array, Array]]:
    """Reweight by log_lik, update the recovery averages, resample if due (with random particles).

    Returns the new state and (n_eff, resampled, p_random)."""
    m = state.mask
    lw = jnp.where(m, state.log_w + log_lik, -jnp.inf)
    log_avg = jax.nn.logsumexp(lw)  # log of the weighted mean likelihood
    lw = lw - log_avg
    # The estimate is taken from the weighted set: resampling adds noise and random particles.
    mean, cov = pose_estimate(state.poses, lw, m)

    def blend(old, rate):
        mixed = jnp.logaddexp(jnp.log1p(-rate) + old, jnp.log(rate) + log_avg)
        return jnp.where(jnp.isfinite(old), mixed, log_avg)

    ws, wf = blend(state.log_w_slow, params.alpha_slow), blend(state.log_w_fast, params.alpha_fast)
    p_random = jnp.clip(1.0 - jnp.exp(wf - ws), 0.0, 1.0)
    n_eff = effective_sample_size(lw)
    n = jnp.sum(m)
    resample = (n_eff < params.resample_ratio * n.astype(lw.dtype)) | (p_random > 0.0)

    k_u, k_pick = jax.random.split(key)
    idx = systematic_resample(lw, m, jax.random.uniform(k_u))
    pick = m & (jax.random.uniform(k_pick, m.shape) < p_random)
    resampled_poses = jnp.where(pick[:, None], random_poses, state.poses[idx])
    uniform = jnp.where(m, -jnp.log(n.astype(lw.dtype)), -jnp.inf)
    injected = resample & (p_random > 0.0)
    new = eqx.tree_at(
        lambda s: (s.poses, s.log_w, s.log_w_slow, s.log_w_fast, s.mean, s.cov),
        state,
        (
            jnp.where(resample, resampled_poses, state.poses),
            jnp.where(resample, uniform, lw),
            jnp.where(injected, -jnp.inf, ws),  # restart the averages after an injection, as AMCL
            jnp.where(injected, -jnp.inf, wf),
            mean,
            cov,
        ),
    )
    return new, (jnp.where(resample, n.astype(lw.dtype), n_eff), resample, p_random)


def pose_estimate(
    poses: Float[Array, "P 3"], log_w: Float[Array, "P"], mask: Bool[Array, "P"]
) -> tuple[Float[Array, "3"], Float[Array, "3 3"]]:
    """Weighted mean pose (circular mean of theta) and covariance of a particle set."""
    w = jnp.where(mask, jnp.exp(log_w), 0.0)
    p = poses
    theta = jnp.arctan2(w @ jnp.sin(p[:, 2]), w @ jnp.cos(p[:, 2]))
    mean = jnp.stack([w @ p[:, 0], w @ p[:, 1], theta])
    dev = jnp.stack([p[:, 0] - mean[0], p[:, 1] - mean[1], wrap_angle(p[:, 2] - theta)], -1)
    return mean, (dev * w[:, None]).T @ dev


def amcl_init(
    params: AmclParams,
    field: LikelihoodField,
    pose: Float[Array, "3"] | None,
    key: Array,
    capacity: int,
    n_active: int | Array | None = None,
) -> AmclState:
    """Particles around `pose` (Gaussian, std params.init_std) or, with pose None, uniform over the
    map's free cells (global localization). `capacity` slots, the first `n_active` (default all) used."""
    if pose is None:
        poses = sample_free_poses(field, key, capacity)
    else:
        pose = jnp.asarray(pose, jnp.float32)
        poses = pose + params.init_std * jax.random.normal(key, (capacity, 3))
        poses = poses.at[:, 2].set(wrap_angle(poses[:, 2]))
    mask = jnp.arange(capacity) < (capacity if n_active is None else n_active)
    log_w = jnp.where(mask, -jnp.log(jnp.sum(mask).astype(jnp.float32)), -jnp.inf)
    mean, cov = pose_estimate(poses, log_w, mask)
    return AmclState(
        poses=poses,
        log_w=log_w,
        mask=mask,
        odom_ref=jnp.zeros(3),
        started=jnp.asarray(False),
        log_w_slow=jnp.asarray(-jnp.inf),
        log_w_fast=jnp.asarray(-jnp.inf),
        mean=mean,
        cov=cov,
    )


def _beams(n_beams: int, width: int) -> np.ndarray:
    """Evenly spread beam indices (static), AMCL's stride (W - 1) / (n_beams - 1)."""
    if n_beams >= width:
        return np.arange(width)
    return np.floor(np.arange(n_beams) * ((width - 1) / max(n_beams - 1, 1))).astype(np.int32)


def amcl_step(
    params: AmclParams, field: LikelihoodField, state: AmclState, inputs: AmclInputs
) -> tuple[AmclState, AmclOutput]:
    """One scan: update (motion, measurement, resampling) if the odometry moved enough, then estimate.

    A scan with non-finite odometry is skipped (the filter keeps its state)."""
    d = inputs.odom - state.odom_ref
    moved = (jnp.hypot(d[0], d[1]) >= params.update_min_d) | (jnp.abs(wrap_angle(d[2])) >= params.update_min_a)
    update = (moved | ~state.started) & jnp.all(jnp.isfinite(inputs.odom))
    beams = _beams(params.n_beams, inputs.ranges.shape[-1])

    def run(state):
        k_motion, k_rand, k_res = jax.random.split(inputs.key, 3)
        odom_old = jnp.where(state.started, state.odom_ref, inputs.odom)
        poses = omni_motion(k_motion, state.poses, odom_old, inputs.odom, params.alpha)
        poses = jnp.where(state.mask[:, None], poses, state.poses)  # inactive slots stay as they are
        lik = scan_likelihood(
            field,
            poses,
            params.T_base_laser,
            inputs.ranges[beams],
            inputs.bearings[beams],
            params.z_hit,
            params.z_rand,
            params.sigma_hit,
            params.range_min,
            params.range_max,
        )
        moved_state = eqx.tree_at(
            lambda s: (s.poses, s.odom_ref, s.started), state, (poses, inputs.odom, jnp.asarray(True))
        )
        random_poses = sample_free_poses(field, k_rand, poses.shape[0])
        return measurement_update(params, moved_state, jnp.log(lik), random_poses, k_res)

    def skip(state):
        return state, (effective_sample_size(state.log_w), jnp.asarray(False), jnp.asarray(0.0, jnp.float32))

    state, (n_eff, resampled, p_random) = jax.lax.cond(update, run, skip, state)
    pose, cov = state.mean, state.cov
    # Between updates the pose follows the odometry from the last update, as AMCL's map->odom transform.
    since = SE2.from_xy_theta(*state.odom_ref).inverse() @ SE2.from_xy_theta(*inputs.odom)
    now = SE2.from_xy_theta(*pose) @ since
    follow = state.started & jnp.all(jnp.isfinite(inputs.odom))
    pose = jnp.where(follow, jnp.concatenate([now.translation(), now.rotation().as_radians()[None]]), pose)
    return state, AmclOutput(pose=pose, cov=cov, n_eff=n_eff, updated=update, resampled=resampled, p_random=p_random)
