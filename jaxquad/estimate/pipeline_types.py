"""The estimation pipeline's pytrees: tunable numbers (`PipelineParams`), static choices
(`PipelineConfig`), one sample's inputs (`PipelineSample`), the state carried between samples
(`PipelineState`) and the per-sample outputs (`Estimate`, with its `Flags`).
`jaxquad.estimate.pipeline` steps them."""

from __future__ import annotations

import dataclasses
from typing import Literal

import equinox as eqx
import jax.numpy as jnp
from jaxtyping import Array, Bool, Float

from jaxquad.estimate import attitude as att
from jaxquad.estimate import differentiate as dif
from jaxquad.estimate.inputs import CONTACT_SOURCES, OBSERVER_ROWS
from jaxquad.estimate.odometry import Pose
from jaxquad.kernels import ObserverParams
from jaxquad.kernels import floor as flr


class PipelineParams(eqx.Module):
    """Every tunable number of the pipeline (traced leaves)."""

    observer: ObserverParams
    attitude: att.AttitudeParams  # the attitude filter on the accelerometer (logs without an attitude)
    attitude_report: att.AttitudeParams  # the same filter toward the log's attitude (`attitude.step_toward`)
    differentiator: dif.DifferentiatorParams
    imu_weight: Float[Array, ""]  # weight of the gyro rows in the twist least squares
    min_stance: Float[Array, ""]  # effective stance count needed for the linear velocity
    max_gap_s: Float[Array, ""]  # longer time steps are not integrated
    fall_tilt_rad: Float[Array, ""]  # base tilt beyond which the robot counts as fallen
    torque_saturation: Float[Array, ""]  # fraction of the torque limit that counts as saturated
    robust_scale: Float[Array, ""]  # m/s: scale of the twist's robust loss (kernels.robust_twist)
    sigma_prior: Float[Array, ""]  # m/s: prior foot-velocity noise of the twist covariance
    prior_dof: Float[Array, ""]  # its weight in degrees of freedom
    settle_s: Float[Array, ""]  # s: a foot's twist weight ramps from 0 to 1 over its first settle_s of stance
    held_accel_std: Float[Array, ""]  # m/s^2: a held twist's std grows by this times the time it has been held
    floor: flr.FloorParams  # height filter (kernels.floor)

    @classmethod
    def default(cls, n_feet: int = 4, mode: Literal["plain", "mixed"] = "mixed") -> "PipelineParams":
        """The paper's observer defaults (facts.md Sec. 3) and this library's filter settings."""
        return cls(
            observer=ObserverParams.paper(n_feet, mode),
            attitude=att.AttitudeParams.default(),
            attitude_report=att.AttitudeParams.toward_report(),
            differentiator=dif.DifferentiatorParams.default(),
            imu_weight=jnp.asarray(1.0),
            min_stance=jnp.asarray(1.5),
            max_gap_s=jnp.asarray(0.05),
            fall_tilt_rad=jnp.asarray(1.2),
            torque_saturation=jnp.asarray(0.99),
            robust_scale=jnp.asarray(0.1),
            sigma_prior=jnp.asarray(0.039),
            prior_dof=jnp.asarray(3.0),
            settle_s=jnp.asarray(0.032),
            held_accel_std=jnp.asarray(2.0),
            floor=flr.FloorParams.default(),
        )


@dataclasses.dataclass(frozen=True)
class PipelineConfig:
    """Static choices: they select code, so each combination compiles once."""

    contacts: str = "truth"  # one of CONTACT_SOURCES
    has_qd: bool = True  # use RobotInputs.qd, else differentiate q
    has_attitude: bool = True  # use RobotInputs.quat_wxyz, else run the attitude filter
    soft_contacts: bool = False  # observer: weight feet by contact_soft instead of 0/1
    # observer rows (`inputs.observer_rows`): "full" = every generalized coordinate, floating base
    # included (the paper); "joints" = the actuated joints, insensitive to errors in the estimated
    # base velocity (the previous leg-odometry twist, whose errors the full rows read as foot forces
    # of tens of newtons); "legs" = the legs' own joints, which also leaves out a spine's row (it
    # couples to the base velocity 4-5 times more than a leg row).
    observer_rows: str = "legs"
    # observer force axes: "xyz" = full foot forces, z components thresholded (a z-only observer
    # reads the stance feet's tangential friction forces as z forces, on every foot); "z" = z only.
    observer_axes: str = "xyz"
    # observer tau_bar with the model's joint damping and friction (`dynamics.passive_forces`).
    observer_passive: bool = True
    # leg odometry: contact points of round feet rolling on the floor (radius from the model);
    # robust loss over stance feet ("none", "huber", "cauchy") with `robust_iters` reweightings,
    # against the previous sample's twist too (`robust_prior`: feet sliding at touchdown or lift-off);
    # base height from the floor under the stance feet (flat ground); each foot's weight ramped up over
    # its first `PipelineParams.settle_s` of stance (`settle`: a foot that has just touched down still slides).
    rolling: bool = True
    robust: str = "huber"
    robust_iters: int = 3
    robust_prior: bool = True
    floor: bool = True
    settle: bool = True

    def __post_init__(self):
        if self.contacts not in CONTACT_SOURCES:
            raise ValueError(f"contacts must be one of {CONTACT_SOURCES}, got {self.contacts!r}")
        if self.observer_rows not in OBSERVER_ROWS:
            raise ValueError(f"observer_rows must be one of {OBSERVER_ROWS}, got {self.observer_rows!r}")
        if self.robust not in ("none", "huber", "cauchy"):
            raise ValueError(f"robust must be 'none', 'huber' or 'cauchy', got {self.robust!r}")
        if self.observer_axes not in ("z", "xyz"):
            raise ValueError(f"observer_axes must be 'z' or 'xyz', got {self.observer_axes!r}")


class Flags(eqx.Module):
    """Per-sample flags of what was detected and handled (leading axes B: time T, robots N)."""

    bad_joints: Bool[Array, "*B"]  # some q (or qd) not finite: last value held
    bad_imu: Bool[Array, "*B"]  # gyro, acc or reported attitude not usable: the last gyro / the gyro alone carries on
    bad_torque: Bool[Array, "*B"]  # torque not finite or saturated: observer step skipped
    gap: Bool[Array, "*B"]  # dt > max_gap_s (or dt <= 0): not integrated
    no_stance: Bool[Array, "*B"]  # twist not observed: last good twist held
    fallen: Bool[Array, "*B"]  # tilted past fall_tilt_rad or marked invalid: pose held from here on


class Estimate(eqx.Module):
    """Per-sample outputs of one robot (leading axes B: time T once scanned, robots N once vmapped)."""

    p_world_base: Float[Array, "*B 3"]
    q_world_base: Float[Array, "*B 4"]  # w x y z
    v_base: Float[Array, "*B 3"]  # m/s, base frame
    omega_base: Float[Array, "*B 3"]  # rad/s, base frame
    contact: Bool[Array, "*B F"]
    contact_soft: Float[Array, "*B F"]  # observer's soft contact; the input weight otherwise
    force_z: Float[Array, "*B F"]  # observer force (N), 0 for truth/sensor contacts
    force_z_filtered: Float[Array, "*B F"]
    qd: Float[Array, "*B nu"]  # joint velocities used
    cov_v_base: Float[Array, "*B 3 3"]  # (m/s)^2: covariance of v_base (that sample's solve, or the held one's)
    twist_weight: Float[Array, "*B F"]  # each foot's weight in the twist: the contact weight, ramped over settle_s
    slip: Bool[Array, "*B F"]  # stance feet the robust twist flagged as slipping
    flags: Flags


class PipelineState(eqx.Module):
    """What the pipeline carries from one sample to the next (one robot)."""

    diff: dif.DifferentiatorState
    att: att.AttitudeState
    obs: object  # ObserverState, or None without the observer
    pose: Pose
    q_last: Float[Array, "nu"]
    qd_last: Float[Array, "nu"]
    gyro_last: Float[Array, "3"]
    weight_last: Float[Array, "F"]
    stance_s: Float[Array, "F"]  # s each foot has been in contact (0 in swing)
    v_last: Float[Array, "3"]
    omega_last: Float[Array, "3"]
    cov_last: Float[Array, "3 3"]  # (m/s)^2: covariance of the last observed v_base
    held_s: Float[Array, ""]  # s since v_base was last observed
    fallen: Bool[Array, ""]
    floor: flr.FloorState


class PipelineSample(eqx.Module):
    """One sample of a robot's inputs (the rows of `RobotInputs` at one time)."""

    dt: Float[Array, ""]  # s since the previous sample; 0 at the first
    q: Float[Array, "nu"]
    qd: Float[Array, "nu"]
    tau: Float[Array, "nu"]
    gyro: Float[Array, "3"]
    acc: Float[Array, "3"]
    quat_wxyz: Float[Array, "4"]
    contact_weight: Float[Array, "F"]
    valid: Bool[Array, ""]
