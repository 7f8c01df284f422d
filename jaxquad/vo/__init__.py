"""Depth-inertial visual odometry guided and restarted by leg odometry (frame-to-keyframe ICP)."""

from jaxquad.vo.fleet import (
    VoResult,
    frame_samples,
    run_vo,
    score_vo,
    visual_odometry,
    vo_inputs,
)
from jaxquad.vo.odometry import (
    COUPLINGS,
    VoInputs,
    VoOutput,
    VoParams,
    VoState,
    init,
    run,
    step,
)

__all__ = [
    "COUPLINGS",
    "VoInputs",
    "VoOutput",
    "VoParams",
    "VoResult",
    "VoState",
    "frame_samples",
    "init",
    "run",
    "run_vo",
    "score_vo",
    "step",
    "visual_odometry",
    "vo_inputs",
]
