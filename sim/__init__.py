"""MJX fleet simulator: robots walking through generated worlds, with the sensors the estimators use."""

from jaxquad.sim.gait import TROT_OFFSETS, leg_phases, raibert_foothold, swing_position
from jaxquad.sim.leg_ik import LegGeometry, leg_fk, leg_ik
from jaxquad.sim.locomotion import Gait, GaitParams, GaitState, base_to_leg_trunk, gait_init, gait_step
from jaxquad.sim.route_follow import RouteParams, RouteState, route_init, route_step
