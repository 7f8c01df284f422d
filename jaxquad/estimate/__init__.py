"""Contact estimation and leg-inertial odometry over robot logs, scoring and tuning."""

from jaxquad.estimate.attitude import AttitudeParams, AttitudeState, attitude_from_acc, estimate_attitude
from jaxquad.estimate.differentiate import DifferentiatorParams, DifferentiatorState, joint_velocities
from jaxquad.estimate.inputs import CONTACT_SOURCES, RobotInputs, check_log, full_state, robot_inputs
from jaxquad.estimate.odometry import Pose, integrate_twist, odometry_step, se3_exp
from jaxquad.estimate.pipeline import estimate_fleet, estimate_robot, inputs_from_log, pipeline_init, pipeline_step
from jaxquad.estimate.pipeline_types import (
    Estimate,
    Flags,
    PipelineConfig,
    PipelineParams,
    PipelineSample,
    PipelineState,
)
from jaxquad.estimate.run import estimate_log, load_params, run_estimate
from jaxquad.estimate.scores import (
    aggregate_delays,
    contact_scores,
    detection_delays,
    fleet_mean,
    force_rmse,
    odometry_drift,
    odometry_scores,
    path_ratio,
    z_error,
)
from jaxquad.estimate.tune import (
    ContactTruth,
    GridSpec,
    ObserverInputs,
    Unconstrained,
    fleet_scores,
    gradient_tune,
    grid_search,
    observer_inputs,
    save_params,
    surrogate_loss,
    tune_fleet,
)

__all__ = [
    "CONTACT_SOURCES",
    "AttitudeParams",
    "AttitudeState",
    "DifferentiatorParams",
    "DifferentiatorState",
    "Estimate",
    "Flags",
    "PipelineConfig",
    "PipelineParams",
    "Pose",
    "RobotInputs",
    "attitude_from_acc",
    "check_log",
    "contact_scores",
    "detection_delays",
    "estimate_attitude",
    "estimate_fleet",
    "estimate_log",
    "estimate_robot",
    "force_rmse",
    "inputs_from_log",
    "integrate_twist",
    "load_params",
    "joint_velocities",
    "odometry_drift",
    "odometry_step",
    "run_estimate",
    "se3_exp",
    "full_state",
    "robot_inputs",
]
__all__ += ["aggregate_delays", "fleet_mean", "odometry_scores", "path_ratio", "z_error"]
__all__ += ["PipelineSample", "PipelineState", "pipeline_init", "pipeline_step"]
__all__ += [
    "ContactTruth",
    "GridSpec",
    "ObserverInputs",
    "Unconstrained",
    "fleet_scores",
    "grid_search",
    "gradient_tune",
    "observer_inputs",
    "save_params",
    "surrogate_loss",
    "tune_fleet",
]
