"""Pure jitted math for one robot: contact observer, leg twist, scan slicing, Lie groups (`lie`), pose graphs,
occupancy grids, scan matching, AMCL, costmaps, planning, MPPI, frontiers. `vmap` at the call site."""
from jaxquad.kernels.icp import Alignment, DepthLevel, IcpParams, align, depth_frame, gauss_newton_step
from jaxquad.kernels.contact import ContactEstimate, ContactObserver, ObserverParams, ObserverState
from jaxquad.kernels.occupancy import GridSpec, OccupancyGrid, OccupancyParams, init_grid, insert_scan, map_from_scans
from jaxquad.kernels.posegraph import PoseGraph, SolveInfo, SolverParams, edge_error, optimize
from jaxquad.kernels.raycast import Boxes, cast_depth, pinhole_rays, ray_distance
from jaxquad.kernels.scan import CameraIntrinsics, Scan, baseline_scan, level_scan, stabilized_scan
from jaxquad.kernels.costmap import CostGrid, CostmapParams, costmap_from_occupancy, distance_transform, inflation_cost
from jaxquad.kernels.frontiers import FrontierChoice, FrontierParams, choose_frontier, frontier_mask, label_clusters
from jaxquad.kernels.mppi import MppiInputs, MppiOutput, MppiParams, MppiState
from jaxquad.kernels.planner import cost_to_go, descend, nearest_open_cell, step_weights
from jaxquad.kernels.likelihood_field import (
    LikelihoodField, distance_at, likelihood_field, sample_free_poses, scan_likelihood,
)  # fmt: skip
from jaxquad.kernels.particle_filter import (
    AmclInputs, AmclOutput, AmclParams, AmclState, amcl_init, amcl_step, effective_sample_size, measurement_update,
    omni_motion, pose_estimate, systematic_resample,
)  # fmt: skip
from jaxquad.kernels.scan_grid import LikelihoodGrid, MatchParams, MatchSpec, cells_for_range, likelihood_grid, scan_points, world_points
from jaxquad.kernels.scan_match import MatchResult, match_scan, scan_lookup, search_angles
from jaxquad.kernels.loop_closure import LoopCandidate, LoopParams, LoopSpec, find_loop_closure
from jaxquad.kernels.floor import FloorParams, FloorState, floor_init, floor_step, stance_height
from jaxquad.kernels.robust_twist import RobustTwist, robust_body_twist, robust_weight
from jaxquad.kernels.twist import Twist, body_twist, rolling_contact

__all__ = [
    "Alignment",
    "AmclInputs",
    "AmclOutput",
    "AmclParams",
    "AmclState",
    "Boxes",
    "CameraIntrinsics",
    "ContactEstimate",
    "ContactObserver",
    "CostGrid",
    "CostmapParams",
    "DepthLevel",
    "FloorParams",
    "FloorState",
    "FrontierChoice",
    "FrontierParams",
    "GridSpec",
    "IcpParams",
    "LikelihoodField",
    "LikelihoodGrid",
    "LoopCandidate",
    "LoopParams",
    "LoopSpec",
    "MatchParams",
    "MatchResult",
    "MatchSpec",
    "MppiInputs",
    "MppiOutput",
    "MppiParams",
    "MppiState",
    "ObserverParams",
    "ObserverState",
    "OccupancyGrid",
    "OccupancyParams",
    "PoseGraph",
    "RobustTwist",
    "Scan",
    "SolveInfo",
    "SolverParams",
    "Twist",
    "align",
    "amcl_init",
    "amcl_step",
    "baseline_scan",
    "body_twist",
    "cast_depth",
    "cells_for_range",
    "choose_frontier",
    "cost_to_go",
    "costmap_from_occupancy",
    "depth_frame",
    "descend",
    "distance_at",
    "distance_transform",
    "edge_error",
    "effective_sample_size",
    "find_loop_closure",
    "floor_init",
    "floor_step",
    "frontier_mask",
    "gauss_newton_step",
    "inflation_cost",
    "init_grid",
    "insert_scan",
    "label_clusters",
    "level_scan",
    "likelihood_field",
    "likelihood_grid",
    "map_from_scans",
    "match_scan",
    "measurement_update",
    "nearest_open_cell",
    "omni_motion",
    "optimize",
    "pinhole_rays",
    "pose_estimate",
    "ray_distance",
    "robust_body_twist",
    "robust_weight",
    "rolling_contact",
    "sample_free_poses",
    "scan_likelihood",
    "scan_lookup",
    "scan_points",
    "search_angles",
    "stabilized_scan",
    "stance_height",
    "step_weights",
    "systematic_resample",
    "world_points",
]
