"""File formats: TUM trajectories, g2o pose graphs, robot logs (.npz), occupancy maps (PGM + YAML)."""
from jaxquad.io.g2o import G2oGraph, read_g2o, write_g2o
from jaxquad.io.log import load_log, robot_log, save_log, validate_log
from jaxquad.io.maps import OccupancyMap, load_map, save_map
from jaxquad.io.tum import TumTrajectory, read_tum, write_tum
