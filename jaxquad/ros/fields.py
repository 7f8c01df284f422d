"""Values out of deserialized ROS messages by field path (`a.b`, `a[3]`, `a[*].q`)."""

from __future__ import annotations

import re

import numpy as np

_PART = re.compile(r"^([A-Za-z_][A-Za-z0-9_]*)(?:\[(\*|\d+)\])?$")


def _to_array(value) -> np.ndarray:
    """A message value as floats: Quaternion -> w x y z, Vector3/Point -> x y z, sequences as they are."""
    if hasattr(value, "w") and hasattr(value, "x"):
        return np.array([value.w, value.x, value.y, value.z], np.float64)
    if hasattr(value, "x") and hasattr(value, "z"):
        return np.array([value.x, value.y, value.z], np.float64)
    if isinstance(value, (list, tuple)):
        return np.asarray([_to_array(v) for v in value], np.float64)
    return np.asarray(value, np.float64)


def get_field(msg, path: str, where: str):
    """The raw value at `path` in `msg` (a list where a `[*]` step maps over elements)."""
    values, mapped = [msg], False
    for part in path.split("."):
        m = _PART.match(part)
        if m is None:
            raise ValueError(f"{where}: malformed field path {path!r} at {part!r}")
        name, index = m.groups()
        try:
            values = [getattr(v, name) for v in values]
        except AttributeError:
            fields = [f for f in getattr(type(values[0]), "__dataclass_fields__", {}) if not f.startswith("_")]
            raise ValueError(
                f"{where}: field {name!r} of {path!r} not in the message (fields: {', '.join(fields)})"
            ) from None
        if index == "*":
            values, mapped = [x for v in values for x in v], True
        elif index is not None:
            try:
                values = [v[int(index)] for v in values]
            except IndexError:
                raise ValueError(f"{where}: index {index} of {path!r} out of range") from None
    return values if mapped else values[0]


def get_array(msg, path: str, where: str) -> np.ndarray:
    """The value at `path` as a float64 array (see `_to_array`)."""
    return _to_array(get_field(msg, path, where))


def stamp_ns(msg, receive_ns: int, mode: str) -> int:
    """The message's header stamp (ns) in mode 'header' when it has a non-zero one, else the bag time."""
    header = getattr(msg, "header", None)
    if mode == "header" and header is not None:
        ns = int(header.stamp.sec) * 1_000_000_000 + int(header.stamp.nanosec)
        if ns > 0:
            return ns
    return int(receive_ns)
