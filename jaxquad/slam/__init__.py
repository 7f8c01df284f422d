"""2D SLAM back end: pose-graph optimization of g2o graphs and occupancy-grid mapping, per robot and
batched over fleets."""

from jaxquad.kernels.posegraph import PoseGraph, SolveInfo, SolverParams, chi2, edge_error, optimize
from jaxquad.slam.graph import build_graph, stack_graphs
from jaxquad.slam.solve import g2o_pose_graph, optimize_g2o
from jaxquad.slam.synthetic import SyntheticGraph, manhattan_graph

__all__ = [
    "PoseGraph", "SolveInfo", "SolverParams", "SyntheticGraph", "build_graph", "chi2", "edge_error", "g2o_pose_graph",
    "manhattan_graph", "optimize", "optimize_g2o", "stack_graphs",
]  # fmt: skip
