"""Tuning of the contact observer's numbers over a fleet log: grid search and gradient descent.

`observer_inputs` computes the observer inputs of a log once (MJX, via the pipeline's own log
parsing); each configuration then runs only the observer's `lax.scan` (`observer_scan`), with
configurations on one vmap axis and robots on another. `grid_search` and `gradient_tune` search;
`tune_fleet` runs the whole thing with held-out robots. Parameter files: `jaxquad.io.params`.
"""

from jaxquad.estimate.tune.gradient import GradientResult, LossTerms, Unconstrained, gradient_tune, surrogate_loss
from jaxquad.estimate.tune.grid import GridResult, GridSpec, grid_counts, grid_search, pick_best
from jaxquad.estimate.tune.observer_inputs import ContactTruth, ObserverInputs, observer_inputs, select_robots
from jaxquad.estimate.tune.observer_scan import (
    Counts,
    delay_cost,
    f1_of,
    fleet_scores,
    observer_counts,
    run_observer,
)
from jaxquad.estimate.tune.run import split_robots, tune_fleet
from jaxquad.io.params import read_observer_params, write_observer_params

save_params = write_observer_params

__all__ = [
    "ContactTruth",
    "Counts",
    "GradientResult",
    "GridResult",
    "GridSpec",
    "LossTerms",
    "ObserverInputs",
    "Unconstrained",
    "delay_cost",
    "f1_of",
    "fleet_scores",
    "grid_counts",
    "grid_search",
    "gradient_tune",
    "observer_counts",
    "observer_inputs",
    "pick_best",
    "read_observer_params",
    "run_observer",
    "save_params",
    "select_robots",
    "split_robots",
    "surrogate_loss",
    "tune_fleet",
    "write_observer_params",
]
