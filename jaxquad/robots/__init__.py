"""Robot descriptions (MJCF) and their loader."""

from jaxquad.robots._robot import BUILTIN_ROBOTS, LEGS, Robot, load

__all__ = ["BUILTIN_ROBOTS", "LEGS", "Robot", "load"]
