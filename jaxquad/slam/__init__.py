"""2D graph SLAM: the online SLAM (`init`/`step`/`finish` with leg-odometry constraints), pose-graph
optimization of g2o graphs and occupancy-grid mapping, per robot and batched over fleets."""

from jaxquad.kernels.occupancy import (
    GridSpec,
    OccupancyGrid,
    OccupancyParams,
    init_grid,
    insert_scan,
    map_from_scans,
    scan_evidence,
)
from jaxquad.kernels.posegraph import PoseGraph, SolveInfo, SolverParams, chi2, edge_error, optimize
from jaxquad.slam.graph import build_graph, stack_graphs
from jaxquad.slam.mapping import (
    fleet_maps,
    grid_spec,
    grid_spec_like,
    refresh_map,
    scan_map,
    scan_poses,
    to_occupancy_map,
)
from jaxquad.slam.online import finish, step
from jaxquad.slam.params import load_params, map_max_range, slam_config
from jaxquad.slam.run import final_poses, laser_log_inputs, map_grid, redraw_maps, run_fleet
from jaxquad.slam.solve import g2o_pose_graph, optimize_g2o
from jaxquad.slam.state import LO_CONSTRAINTS, SlamInputs, SlamOutput, SlamParams, SlamSpec, SlamState, init
from jaxquad.slam.synthetic import SyntheticGraph, manhattan_graph

__all__ = [
    "LO_CONSTRAINTS",
    "SlamInputs",
    "SlamOutput",
    "SlamParams",
    "SlamSpec",
    "SlamState",
    "final_poses",
    "finish",
    "init",
    "laser_log_inputs",
    "load_params",
    "map_max_range",
    "map_grid",
    "redraw_maps",
    "refresh_map",
    "run_fleet",
    "scan_map",
    "scan_poses",
    "slam_config",
    "step",
    "GridSpec",
    "OccupancyGrid",
    "OccupancyParams",
    "PoseGraph",
    "SolveInfo",
    "SolverParams",
    "SyntheticGraph",
    "build_graph",
    "chi2",
    "edge_error",
    "fleet_maps",
    "g2o_pose_graph",
    "grid_spec",
    "grid_spec_like",
    "init_grid",
    "insert_scan",
    "manhattan_graph",
    "map_from_scans",
    "optimize",
    "optimize_g2o",
    "scan_evidence",
    "stack_graphs",
    "to_occupancy_map",
]
