"""Trajectory evaluation with the definitions of evo (association, Umeyama alignment, APE, RPE) and
KITTI's segment drift (t_rel %, r_rel deg/m), and occupancy-map scores against a ground-truth map."""

from jaxquad.metrics._align import ALIGN_MODES, Alignment, align, umeyama
from jaxquad.metrics._ape import PoseErrors, ape, pose_errors
from jaxquad.metrics._associate import associate
from jaxquad.metrics._drift import DRIFT_LENGTHS_M, DRIFT_STEP, Drift, evaluate_drift, segment_drift, segment_pairs
from jaxquad.metrics._evaluate import (
    DELTA_UNITS,
    AlignedTrack,
    Evaluation,
    evaluate,
    evaluate_batch,
    evaluate_poses,
)
from jaxquad.metrics._maps import MapScores, cells_in_view, map_scores, narrow_gaps, resample_map
from jaxquad.metrics._result import EvalResult
from jaxquad.metrics._rpe import Pairs, pairs_by_frames, pairs_by_path, pairs_by_path_all, pairs_for, rpe
from jaxquad.metrics._scan_map import scan_map_hits
from jaxquad.metrics._se3 import rotation_angle, rotation_from_quat_xyzw
from jaxquad.metrics._stats import Stats, statistics

__all__ = [
    "ALIGN_MODES",
    "DELTA_UNITS",
    "DRIFT_LENGTHS_M",
    "DRIFT_STEP",
    "AlignedTrack",
    "Alignment",
    "Drift",
    "EvalResult",
    "Evaluation",
    "Pairs",
    "PoseErrors",
    "Stats",
    "align",
    "ape",
    "associate",
    "evaluate",
    "evaluate_batch",
    "evaluate_drift",
    "evaluate_poses",
    "pairs_by_frames",
    "pairs_by_path",
    "pairs_by_path_all",
    "pairs_for",
    "pose_errors",
    "rotation_angle",
    "rotation_from_quat_xyzw",
    "rpe",
    "scan_map_hits",
    "segment_drift",
    "segment_pairs",
    "statistics",
    "umeyama",
    "MapScores",
    "map_scores",
    "narrow_gaps",
    "cells_in_view",
    "resample_map",
]
