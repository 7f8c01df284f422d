"""Navigation and exploration for one robot (vmap over a fleet): costmap, global plan, MPPI, frontiers."""

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
    "NavInputs",
    "NavParams",
    "NavState",
    "NavTrace",
    "Plan",
    "cost_grid",
    "init",
    "plan",
    "replan",
    "simulate_kinematic",
    "step",
]
