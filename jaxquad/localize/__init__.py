"""Localization on a saved map (AMCL): the particle filter of jaxquad.kernels over a log's scans and
odometry, for one robot or a fleet."""

from jaxquad.localize.params import DEFAULTS_FILE, LocalizeParams, load_params
from jaxquad.localize.run import CONVERGED_M, field_of_map, localize_log, localize_scans, run_localize

__all__ = [
    "CONVERGED_M",
    "DEFAULTS_FILE",
    "LocalizeParams",
    "field_of_map",
    "load_params",
    "localize_log",
    "localize_scans",
    "run_localize",
]
