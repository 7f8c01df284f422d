"""jaxquad: state estimation, mapping and navigation for low-cost quadruped robots, in JAX."""

__version__ = "0.1.0"
