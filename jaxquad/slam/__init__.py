"""2D SLAM back end: pose-graph optimization of g2o graphs and occupancy-grid mapping, per robot and
batched over fleets."""

from jaxquad.kernels.occupancy import (
    GridSpec,
    OccupancyGrid,
    OccupancyParams,
    init_grid,
    insert_scan,
    map_from_scans,
    scan_codes,
)
from jaxquad.kernels.posegraph import PoseGraph, SolveInfo, SolverParams, chi2, edge_error, optimize
from jaxquad.slam.graph import build_graph, stack_graphs
from jaxquad.slam.mapping import fleet_maps, grid_spec, grid_spec_like, to_occupancy_map
from jaxquad.slam.solve import g2o_pose_graph, optimize_g2o
from jaxquad.slam.synthetic import SyntheticGraph, manhattan_graph

__all__ = [
    "GridSpec", "OccupancyGrid", "OccupancyParams", "PoseGraph", "SolveInfo", "SolverParams", "SyntheticGraph",
    "build_graph", "chi2", "edge_error", "fleet_maps", "g2o_pose_graph", "grid_spec", "grid_spec_like", "init_grid",
    "insert_scan", "manhattan_graph", "map_from_scans", "optimize", "optimize_g2o", "scan_codes", "stack_graphs",
    "to_occupancy_map",
]  # fmt: skip
