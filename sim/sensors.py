"""Noise models turning simulated ground truth into what a low-cost quadruped's sensors report.

One robot per call; every noise level is a traced leaf of `SensorNoise`, so a fleet draws
per-robot levels under `vmap` without recompiling. Rates are set by the caller (the fleet
runner samples the IMU, encoders and torques at the log rate and the camera on its frames).

- IMU: gyro = true body rate + bias (random walk) + white noise; accelerometer = true specific
  force in the IMU frame (reads +g upward at rest) + bias (random walk) + white noise;
  orientation as an onboard attitude filter reports it: the true orientation with small
  roll/pitch noise and a yaw that drifts as a random walk about the world z axis.
- Encoders: joint angles and velocities with white noise, quantized to the encoder steps.
- Torques: actuator force (from motor current on a real robot) with relative and absolute noise.
- Depth camera: z-depth with noise of standard deviation `depth_k * z^2` (about 2% at 2 m for
  k = 0.01 /m), 0 (invalid) outside [min_range, max_range] and where the surface is seen at a
  grazing angle (incidence from the surface normal estimated from neighbouring pixels), as a
  stereo depth camera fails on slanted surfaces and depth edges.
"""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float, PRNGKeyArray

from jaxquad.kernels.lie import SO3


def _f32(x) -> Array:
    return jnp.asarray(x, jnp.float32)


class SensorNoise(eqx.Module):
    """Per-robot noise levels (traced). White-noise entries are standard deviations per sample."""

    gyro_white: Float[Array, ""]  # rad/s
    gyro_bias_walk: Float[Array, ""]  # rad/s per sqrt(s)
    gyro_bias_init: Float[Array, ""]  # rad/s, std of the turn-on bias
    acc_white: Float[Array, ""]  # m/s^2
    acc_bias_walk: Float[Array, ""]  # m/s^2 per sqrt(s)
    acc_bias_init: Float[Array, ""]  # m/s^2
    tilt_white: Float[Array, ""]  # rad, roll/pitch error of the reported orientation
    yaw_walk: Float[Array, ""]  # rad per sqrt(s), yaw drift of the reported orientation
    q_white: Float[Array, ""]  # rad
    q_step: Float[Array, ""]  # rad, encoder quantization step
    qd_white: Float[Array, ""]  # rad/s
    qd_step: Float[Array, ""]  # rad/s
    tau_rel: Float[Array, ""]  # relative torque error (std)
    tau_white: Float[Array, ""]  # N m
    depth_k: Float[Array, ""]  # 1/m: depth std = depth_k * z^2

    @classmethod
    def default(cls, **overrides) -> "SensorNoise":
        values = dict(
            gyro_white=2e-3,  # ~0.01 deg/s/sqrt(Hz) at 250 Hz, rounded up for a low-cost part
            gyro_bias_walk=2e-4,
            gyro_bias_init=5e-3,
            acc_white=2e-2,
            acc_bias_walk=2e-3,
            acc_bias_init=5e-2,
            tilt_white=float(np.deg2rad(0.3)),
            yaw_walk=float(np.deg2rad(0.2)),
            q_white=5e-4,
            q_step=2 * np.pi / 2**14,
            qd_white=2e-2,
            qd_step=1e-3,
            tau_rel=0.05,
            tau_white=0.1,
            depth_k=0.01,
        )
        values.update(overrides)
        return cls(**{k: _f32(v) for k, v in values.items()})

    @classmethod
    def noiseless(cls) -> "SensorNoise":
        return cls(**{f: _f32(0.0) for f in cls.__dataclass_fields__})

    def scaled(self, s: Float[Array, ""]) -> "SensorNoise":
        """Every noise level times s (quantization steps kept)."""
        keep = {"q_step", "qd_step"}
        return SensorNoise(
            **{f: getattr(self, f) if f in keep else getattr(self, f) * s for f in self.__dataclass_fields__}
        )


class ImuState(eqx.Module):
    gyro_bias: Float[Array, " 3"]  # rad/s
    acc_bias: Float[Array, " 3"]  # m/s^2
    yaw_drift: Float[Array, ""]  # rad


def imu_init(noise: SensorNoise, key: PRNGKeyArray) -> ImuState:
    kg, ka = jax.random.split(key)
    return ImuState(
        gyro_bias=noise.gyro_bias_init * jax.random.normal(kg, (3,)),
        acc_bias=noise.acc_bias_init * jax.random.normal(ka, (3,)),
        yaw_drift=jnp.zeros(()),
    )


def imu_step(
    noise: SensorNoise,
    state: ImuState,
    key: PRNGKeyArray,
    gyro_true: Float[Array, " 3"],
    acc_true: Float[Array, " 3"],
    quat_world_base: Float[Array, " 4"],
    dt: Float[Array, ""] | float,
) -> tuple[ImuState, tuple[Float[Array, " 3"], Float[Array, " 3"], Float[Array, " 4"]]]:
    """One IMU sample `dt` seconds after the previous: (state, (gyro rad/s, acc m/s^2, quat wxyz))."""
    k = jax.random.split(key, 6)
    sq = jnp.sqrt(dt)
    state = ImuState(
        gyro_bias=state.gyro_bias + noise.gyro_bias_walk * sq * jax.random.normal(k[0], (3,)),
        acc_bias=state.acc_bias + noise.acc_bias_walk * sq * jax.random.normal(k[1], (3,)),
        yaw_drift=state.yaw_drift + noise.yaw_walk * sq * jax.random.normal(k[2], ()),
    )
    gyro = gyro_true + state.gyro_bias + noise.gyro_white * jax.random.normal(k[3], (3,))
    acc = acc_true + state.acc_bias + noise.acc_white * jax.random.normal(k[4], (3,))
    tilt = noise.tilt_white * jax.random.normal(k[5], (3,)) * jnp.array([1.0, 1.0, 0.0])
    quat = (SO3.from_z_radians(state.yaw_drift) @ SO3(quat_world_base) @ SO3.exp(tilt)).wxyz
    quat = quat / jnp.linalg.norm(quat)
    return state, (gyro, acc, quat * jnp.sign(quat[0] + 1e-12))


def _quantize(x: Array, step: Array) -> Array:
    return jnp.where(step > 0, jnp.round(x / jnp.where(step > 0, step, 1.0)) * step, x)


def encoders(
    noise: SensorNoise, key: PRNGKeyArray, q: Float[Array, " nj"], qd: Float[Array, " nj"]
) -> tuple[Float[Array, " nj"], Float[Array, " nj"]]:
    """Measured joint angles (rad) and velocities (rad/s)."""
    kq, kd = jax.random.split(key)
    q_meas = _quantize(q + noise.q_white * jax.random.normal(kq, q.shape), noise.q_step)
    qd_meas = _quantize(qd + noise.qd_white * jax.random.normal(kd, qd.shape), noise.qd_step)
    return q_meas, qd_meas


def joint_torque(noise: SensorNoise, key: PRNGKeyArray, tau: Float[Array, " nj"]) -> Float[Array, " nj"]:
    """Measured joint torques (N m) from the actuator force."""
    kr, kw = jax.random.split(key)
    return tau * (1.0 + noise.tau_rel * jax.random.normal(kr, tau.shape)) + noise.tau_white * jax.random.normal(
        kw, tau.shape
    )


def intrinsics(width: int, height: int, hfov_deg: float = 85.2) -> np.ndarray:
    """D435-like pinhole K (px) for an image `width` x `height`: square pixels, centred.

    fx follows the horizontal field of view (348 px at 640 wide for 85.2 deg); the vertical field
    follows from the aspect ratio.
    """
    f = (width / 2) / np.tan(np.deg2rad(hfov_deg) / 2)
    return np.array([[f, 0.0, (width - 1) / 2], [0.0, f, (height - 1) / 2], [0.0, 0.0, 1.0]])


def incidence_cos(depth: Float[Array, "H W"], rays_cam: Float[Array, "H W 3"]) -> Float[Array, "H W"]:
    """|cos| of the angle between each pixel's ray and the surface normal estimated from the
    3-D points of neighbouring pixels (central differences; one-sided at the border)."""
    z = jnp.where(jnp.isfinite(depth), depth, 0.0)
    p = z[..., None] * rays_cam

    def diff(a, axis):
        n = a.shape[axis]
        fwd = jnp.take(a, jnp.minimum(jnp.arange(n) + 1, n - 1), axis=axis)
        bwd = jnp.take(a, jnp.maximum(jnp.arange(n) - 1, 0), axis=axis)
        return fwd - bwd

    n = jnp.cross(diff(p, 1), diff(p, 0))
    num = jnp.abs(jnp.sum(n * rays_cam, -1))
    den = jnp.sqrt(jnp.sum(n**2, -1) * jnp.sum(rays_cam**2, -1))
    return jnp.where(den > 0, num / jnp.where(den > 0, den, 1.0), 0.0)


def depth_camera(
    noise: SensorNoise,
    key: PRNGKeyArray,
    depth_true: Float[Array, "H W"],
    rays_cam: Float[Array, "H W 3"],
    min_range: float = 0.2,
    max_range: float = 8.0,
    max_incidence_deg: float = 80.0,
) -> Float[Array, "H W"]:
    """Measured z-depth image (m); invalid pixels read 0."""
    valid = (depth_true >= min_range) & (depth_true <= max_range)
    valid &= incidence_cos(depth_true, rays_cam) >= np.cos(np.deg2rad(max_incidence_deg))
    z = jnp.where(valid, depth_true, 0.0)
    z_noisy = z + noise.depth_k * z**2 * jax.random.normal(key, z.shape)
    return jnp.where(valid, jnp.maximum(z_noisy, 0.0), 0.0)
