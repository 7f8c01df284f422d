"""Depth-inertial visual odometry guided and restarted by leg odometry (frame-to-keyframe ICP)."""

from jaxquad.vo.odometry import COUPLINGS, VoInputs, VoOutput, VoParams, VoState, init, run, step
from jaxquad.vo.fleet import VoResult, frame_samples, visual_odometry, vo_inputs

__all__ = [
    "COUPLINGS", "VoInputs", "VoOutput", "VoParams", "VoResult", "VoState", "frame_samples", "init", "run", "step",
    "visual_odometry", "vo_inputs",
]  # fmt: skip
