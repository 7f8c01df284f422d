"""MJX fleet simulator: robots walking through generated worlds, with the sensors the estimators use.

`rollout(FleetConfig(...), seconds) -> FleetLog` runs a fleet in memory; `build_fleet` / `init` /
`run_chunk` drive it chunk by chunk; `Fleet.functions` holds the pure single-robot step functions.
"""

from jaxquad.sim.fleet import Fleet, FleetConfig, build_fleet, init, n_chunks, run_chunk
from jaxquad.sim.gait import TROT_OFFSETS, leg_phases, raibert_foothold, swing_position
from jaxquad.sim.gait_structure import Gait
from jaxquad.sim.leg_ik import LegGeometry, leg_fk, leg_ik
from jaxquad.sim.locomotion import GaitParams, GaitState, base_to_leg_trunk, gait_init, gait_step
from jaxquad.sim.robot_step import FleetFunctions, RobotSetup, RobotState
from jaxquad.sim.rollout import FleetLog, rollout
from jaxquad.sim.route_follow import RouteParams, RouteState, route_init, route_step

__all__ = [
    "TROT_OFFSETS",
    "Fleet",
    "FleetConfig",
    "FleetFunctions",
    "FleetLog",
    "Gait",
    "GaitParams",
    "GaitState",
    "LegGeometry",
    "RobotSetup",
    "RobotState",
    "RouteParams",
    "RouteState",
    "base_to_leg_trunk",
    "build_fleet",
    "gait_init",
    "gait_step",
    "init",
    "leg_fk",
    "leg_ik",
    "leg_phases",
    "n_chunks",
    "raibert_foothold",
    "rollout",
    "route_init",
    "route_step",
    "run_chunk",
    "swing_position",
]
