"""Trajectory evaluation with the definitions of evo (association, Umeyama alignment, APE, RPE) and
occupancy-map scores against a ground-truth map."""

from jaxquad.metrics._align import ALIGN_MODES, Alignment, align, umeyama
from jaxquad.metrics._ape import PoseErrors, ape, pose_errors
from jaxquad.metrics._associate import associate
from jaxquad.metrics._evaluate import (
    DELTA_UNITS,
    AlignedTrack,
    Evaluation,
    evaluate,
    evaluate_batch,
    evaluate_poses,
)
from jaxquad.metrics._maps import MapScores, map_scores, resample_map
from jaxquad.metrics._result import EvalResult
from jaxquad.metrics._rpe import Pairs, pairs_by_frames, pairs_by_path, pairs_by_path_all, pairs_for, rpe
from jaxquad.metrics._se3 import rotation_angle, rotation_from_quat_xyzw
from jaxquad.metrics._stats import Stats, statistics

__all__ = [
    "ALIGN_MODES", "DELTA_UNITS", "AlignedTrack", "Alignment", "EvalResult", "Evaluation", "MapScores", "Pairs",
    "PoseErrors", "Stats", "align", "ape", "associate", "evaluate", "evaluate_batch", "evaluate_poses", "map_scores",
    "pairs_by_frames", "pairs_by_path", "pairs_by_path_all", "pairs_for", "pose_errors", "rotation_angle",
    "resample_map", "rotation_from_quat_xyzw", "rpe", "statistics", "umeyama",
]
