"""TUM trajectory files: one pose per line `timestamp tx ty tz qx qy qz qw`, `#` starts a comment line.

Reading validates every line and reports the first problem as one line naming the file and line
number; quaternions are normalized. Writing is atomic (a temporary file renamed over the target)
and keeps full float precision (shortest round-trip representation).
"""

from __future__ import annotations

import dataclasses
import math
import os
from pathlib import Path

import numpy as np

from jaxquad.io.atomic import atomic_write_text
from jaxquad.io.files import read_text


@dataclasses.dataclass(frozen=True)
class TumTrajectory:
    """Timestamped poses of a body in the world frame.

    t_s: (N,) seconds, strictly increasing. p_world_body: (N, 3) metres.
    q_world_body_xyzw: (N, 4) unit quaternions, scalar last (the TUM column order).
    """

    t_s: np.ndarray
    p_world_body: np.ndarray
    q_world_body_xyzw: np.ndarray

    def __post_init__(self):
        t = np.asarray(self.t_s, dtype=np.float64)
        p = np.asarray(self.p_world_body, dtype=np.float64)
        q = np.asarray(self.q_world_body_xyzw, dtype=np.float64)
        n = t.shape[0] if t.ndim == 1 else -1
        if t.ndim != 1 or p.shape != (n, 3) or q.shape != (n, 4):
            raise ValueError(
                f"trajectory arrays must have shapes (N,), (N, 3), (N, 4); got {t.shape}, {p.shape}, {q.shape}"
            )
        object.__setattr__(self, "t_s", t)
        object.__setattr__(self, "p_world_body", p)
        object.__setattr__(self, "q_world_body_xyzw", q)

    def __len__(self) -> int:
        return int(self.t_s.shape[0])

    def subset(self, idx: np.ndarray) -> "TumTrajectory":
        """The poses at integer indices `idx` (repeats allowed)."""
        return TumTrajectory(self.t_s[idx], self.p_world_body[idx], self.q_world_body_xyzw[idx])


def _parse_line(fields: list[str], where: str) -> list[float]:
    if len(fields) != 8:
        raise ValueError(f"{where}: expected 8 fields 'timestamp tx ty tz qx qy qz qw', got {len(fields)}")
    try:
        values = [float(f) for f in fields]
    except ValueError:
        bad = next(f for f in fields if not _is_float(f))
        raise ValueError(f"{where}: not a number: {bad!r}") from None
    if not all(math.isfinite(v) for v in values):
        raise ValueError(f"{where}: NaN or infinite value")
    if not any(values[4:]):
        raise ValueError(f"{where}: zero quaternion")
    return values


def _is_float(s: str) -> bool:
    try:
        float(s)
    except ValueError:
        return False
    return True


def _parse_fast(lines: list[str]) -> np.ndarray | None:
    """All data rows parsed by NumPy's C reader, or None when anything is off (then the line-by-line
    parser finds and names the first bad line)."""
    data = [ln for ln in lines if ln.strip() and not ln.lstrip().startswith("#")]
    if not data:
        return None
    try:
        mat = np.loadtxt(data, dtype=np.float64, comments=None, ndmin=2)
    except ValueError:
        return None
    ok = (
        mat.shape[1] == 8
        and np.all(np.isfinite(mat))
        and np.all(np.any(mat[:, 4:] != 0, axis=1))
        and np.all(np.diff(mat[:, 0]) > 0)
    )
    return mat if ok else None


def _parse_checked(lines: list[str], path: Path) -> np.ndarray:
    rows = []
    prev_t, prev_line = -math.inf, 0
    for lineno, line in enumerate(lines, start=1):
        stripped = line.strip()
        if not stripped or stripped.startswith("#"):
            continue
        values = _parse_line(stripped.split(), f"{path}:{lineno}")
        if not values[0] > prev_t:
            raise ValueError(
                f"{path}:{lineno}: timestamp {values[0]!r} does not increase (line {prev_line} has {prev_t!r})"
            )
        prev_t, prev_line = values[0], lineno
        rows.append(values)
    if not rows:
        raise ValueError(f"{path}: no poses")
    return np.asarray(rows, dtype=np.float64)


def read_tum(path: str | os.PathLike) -> TumTrajectory:
    """Read a TUM trajectory file; ValueError (file:line: what) on malformed content."""
    path = Path(path)
    lines = read_text(path, "trajectory").splitlines()
    mat = _parse_fast(lines)
    if mat is None:
        mat = _parse_checked(lines, path)
    q = mat[:, 4:8]
    q = q / np.linalg.norm(q, axis=1, keepdims=True)
    return TumTrajectory(mat[:, 0], mat[:, 1:4], q)


def write_tum(path: str | os.PathLike, traj: TumTrajectory, header: str | None = None) -> None:
    """Write `traj` as a TUM file, atomically; `header` lines are written as `#` comments."""
    path = Path(path)
    if not (
        np.all(np.isfinite(traj.t_s))
        and np.all(np.isfinite(traj.p_world_body))
        and np.all(np.isfinite(traj.q_world_body_xyzw))
    ):
        raise ValueError(f"{path}: refusing to write a trajectory with NaN or infinite values")
    if np.any(np.diff(traj.t_s) <= 0):
        raise ValueError(f"{path}: timestamps must increase strictly")
    mat = np.concatenate([traj.t_s[:, None], traj.p_world_body, traj.q_world_body_xyzw], axis=1)
    lines = [] if header is None else [f"# {h}" for h in header.splitlines()]
    # repr of a Python float is the shortest string that reads back to the same double.
    lines += [" ".join(map(repr, row)) for row in mat.tolist()]
    atomic_write_text(path, "\n".join(lines) + "\n")
