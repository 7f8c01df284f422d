"""JSON output that stays valid JSON: NaN and infinities become null, NumPy and JAX values plain Python,
dataclasses (parameter pytrees such as `eqx.Module`s) objects of their fields."""

from __future__ import annotations

import dataclasses
import json
import math
import os
from pathlib import Path

import numpy as np

from jaxquad.io.atomic import atomic_write_text

__all__ = ["json_ready", "to_json", "write_json"]


def json_ready(obj):
    """`obj` with NumPy/JAX scalars and arrays as Python values, dataclass instances as {field: value}
    and non-finite floats as None (null)."""
    if isinstance(obj, dict):
        return {str(k): json_ready(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [json_ready(v) for v in obj]
    if isinstance(obj, np.ndarray):
        if obj.dtype.kind == "f" and obj.dtype.itemsize < 8:
            # float32 as its shortest decimal (0.2, not 0.20000000298023224): the same float32 when read.
            return json_ready(np.array([float(str(v)) for v in obj.ravel()]).reshape(obj.shape).tolist())
        return json_ready(obj.tolist())
    if isinstance(obj, np.generic):
        return json_ready(np.asarray(obj))
    if dataclasses.is_dataclass(obj) and not isinstance(obj, type):
        return {f.name: json_ready(getattr(obj, f.name)) for f in dataclasses.fields(obj)}
    if hasattr(obj, "__array__") and not isinstance(obj, (str, bytes)):  # a JAX array
        return json_ready(np.asarray(obj))
    if isinstance(obj, float) and not math.isfinite(obj):
        return None
    return obj


def to_json(obj, indent: int | None = 2) -> str:
    return json.dumps(json_ready(obj), indent=indent, allow_nan=False)


def write_json(path: str | os.PathLike, obj) -> Path:
    """Write `obj` as pretty JSON (NaN as null), atomically."""
    return atomic_write_text(path, to_json(obj) + "\n")
