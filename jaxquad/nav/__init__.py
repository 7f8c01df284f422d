"""Navigation and exploration for one robot (vmap over a fleet): costmap, global plan, MPPI, frontiers."""

from jaxquad.nav import explore
from jaxquad.nav.explore import ExploreParams, ExploreState
from jaxquad.nav.navigate import (
    GoalTable,
    NavInputs,
    NavParams,
    NavState,
    NavTrace,
    Plan,
    cost_grid,
    goal_table,
    init,
    plan,
    plan_to,
    replan,
    simulate_kinematic,
    step,
)

__all__ = [
    "ExploreParams",
    "ExploreState",
    "GoalTable",
    "NavInputs",
    "NavParams",
    "NavState",
    "NavTrace",
    "Plan",
    "cost_grid",
    "explore",
    "goal_table",
    "init",
    "plan",
    "plan_to",
    "replan",
    "simulate_kinematic",
    "step",
]
