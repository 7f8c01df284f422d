"""Navigation and exploration for one robot (vmap over a fleet): costmap, global plan, MPPI, frontiers."""

from jaxquad.nav import explore
from jaxquad.nav.explore import ExploreParams, ExploreState
from jaxquad.nav.navigate import (
    NavInputs,
    NavParams,
    NavState,
    NavTrace,
    Plan,
    cost_grid,
    init,
    plan,
    replan,
    simulate_kinematic,
    step,
)

__all__ = [
    "ExploreParams",
    "ExploreState",
    "NavInputs",
    "NavParams",
    "NavState",
    "NavTrace",
    "Plan",
    "cost_grid",
    "explore",
    "init",
    "plan",
    "replan",
    "simulate_kinematic",
    "step",
]
