"""JSON output that stays valid JSON: NaN and infinities become null, NumPy values plain Python."""

from __future__ import annotations

import json
import math
import os
from pathlib import Path

import numpy as np

from jaxquad.io.atomic import atomic_write_text

__all__ = ["json_ready", "to_json", "write_json"]


def json_ready(obj):
    """`obj` with NumPy scalars/arrays as Python values and non-finite floats as None (null)."""
    if isinstance(obj, dict):
        return {str(k): json_ready(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [json_ready(v) for v in obj]
    if isinstance(obj, np.ndarray):
        return json_ready(obj.tolist())
    if isinstance(obj, np.generic):
        return json_ready(obj.item())
    if isinstance(obj, float) and not math.isfinite(obj):
        return None
    return obj


def to_json(obj, indent: int | None = 2) -> str:
    return json.dumps(json_ready(obj), indent=indent, allow_nan=False)


def write_json(path: str | os.PathLike, obj) -> Path:
    """Write `obj` as pretty JSON (NaN as null), atomically."""
    return atomic_write_text(path, to_json(obj) + "\n")
