"""The end-to-end demo: simulate, estimate, score, draw (`jaxquad demo`)."""

from jaxquad.demo.run import contact_sources, run_demo
from jaxquad.demo.scans import camera_pose_2d, frame_samples, score_scans, stack_scans
from jaxquad.demo.summary import format_table, mean_scores

__all__ = [
    "contact_sources",
    "camera_pose_2d",
    "format_table",
    "frame_samples",
    "mean_scores",
    "run_demo",
    "score_scans",
    "stack_scans",
]
