"""MuJoCo MJX, imported with its optional-backend notices sent to stderr: stdout carries JSON output."""

import contextlib
import sys

with contextlib.redirect_stdout(sys.stderr):
    from mujoco import mjx  # noqa: F401
