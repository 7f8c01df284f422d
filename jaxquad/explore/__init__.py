"""Autonomous frontier exploration in the closed loop: online SLAM, frontier goals, the planner and MPPI
driving simulated robots through unknown worlds (`explore`), its summary and pictures (`report`)."""

from jaxquad.explore.config import VARIANTS, ExploreConfig, ExploreResult
from jaxquad.explore.fleet import explore
from jaxquad.explore.loop import (
    OUTCOMES,
    ExploreFunctions,
    ExploreInputs,
    ExploreLoopConfig,
    ExploreLoopParams,
    ExploreLoopState,
    ExploreOutput,
    coverage,
    make_explore_loop,
)

__all__ = [
    "OUTCOMES",
    "VARIANTS",
    "ExploreConfig",
    "ExploreFunctions",
    "ExploreInputs",
    "ExploreLoopConfig",
    "ExploreLoopParams",
    "ExploreLoopState",
    "ExploreOutput",
    "ExploreResult",
    "coverage",
    "explore",
    "make_explore_loop",
]
