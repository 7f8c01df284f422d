"""MuJoCo MJX, imported once with its optional-backend notices ("Failed to import warp", printed
when the optional GPU backends are absent) silenced, so no command prints them. Import mjx from here."""

import contextlib
import os

with open(os.devnull, "w") as _null, contextlib.redirect_stdout(_null), contextlib.redirect_stderr(_null):
    from mujoco import mjx  # noqa: F401
