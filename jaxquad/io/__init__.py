"""File formats and file output: TUM trajectories, g2o pose graphs, robot logs (.npz), occupancy maps (PGM + YAML),
observer parameter files, checked .npz reading, and the atomic writes every writer uses."""

from jaxquad.io.atomic import (
    atomic_dir,
    atomic_open,
    atomic_write_bytes,
    atomic_write_text,
    check_output_dir,
    check_output_file,
)
from jaxquad.io.carmen import LaserLog, load_laser_log, read_carmen, read_laser_npz, save_laser_npz
from jaxquad.io.files import read_npz, read_text
from jaxquad.io.g2o import G2oGraph, read_g2o, write_g2o
from jaxquad.io.jsonfile import json_ready, to_json, write_json
from jaxquad.io.log import load_log, robot_log, save_log, validate_log
from jaxquad.io.maps import OccupancyMap, load_map, save_map
from jaxquad.io.params import OBSERVER_KEYS, observer_params_dict, read_observer_params, write_observer_params
from jaxquad.io.tum import TumTrajectory, read_tum, write_tum

__all__ = [
    "OBSERVER_KEYS",
    "OccupancyMap",
    "TumTrajectory",
    "atomic_dir",
    "atomic_open",
    "atomic_write_bytes",
    "atomic_write_text",
    "check_output_dir",
    "check_output_file",
    "load_log",
    "load_map",
    "observer_params_dict",
    "read_observer_params",
    "read_tum",
    "robot_log",
    "save_log",
    "save_map",
    "validate_log",
    "write_observer_params",
    "write_tum",
    "json_ready",
    "to_json",
    "write_json",
    "LaserLog",
    "load_laser_log",
    "read_carmen",
    "read_laser_npz",
    "save_laser_npz",
    "G2oGraph",
    "read_g2o",
    "write_g2o",
    "read_npz",
    "read_text",
]
