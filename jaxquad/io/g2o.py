"""2D pose graphs in g2o's text format (the format of intel.g2o, M3500 and the other public benchmarks).

Lines read and written:
  VERTEX_SE2 id x y theta
  EDGE_SE2 i j dx dy dtheta I11 I12 I13 I22 I23 I33   (upper triangle of the information matrix)
  FIX id [id ...]
Blank lines and lines starting with '#' are skipped. Any other tag is an error naming the tag, the
file and the line (a graph with landmarks or 3D poses would otherwise be optimized without them).
Ids are kept as they are (they need not be contiguous); edges must join declared vertices.
"""

from __future__ import annotations

import dataclasses
import os
from pathlib import Path

import numpy as np

from jaxquad.io.atomic import atomic_write_text
from jaxquad.io.files import read_text

_UPPER = np.triu_indices(3)


@dataclasses.dataclass(frozen=True)
class G2oGraph:
    ids: np.ndarray  # (N,) int vertex ids, in file order
    poses: np.ndarray  # (N, 3) x, y, theta
    fixed_ids: np.ndarray  # (F,) int ids of FIX lines, in file order
    edge_ids: np.ndarray  # (M, 2) int (i, j) vertex ids
    measurement: np.ndarray  # (M, 3) dx, dy, dtheta
    information: np.ndarray  # (M, 3, 3) symmetric

    def edge_index(self) -> np.ndarray:
        """(M, 2) node indices (positions in `ids`) of the edges' endpoints."""
        order = np.argsort(self.ids)
        pos = np.searchsorted(self.ids[order], self.edge_ids)
        return order[pos]

    def fixed_mask(self) -> np.ndarray:
        """(N,) bool: the FIX vertices, or the first vertex when the file has no FIX line."""
        if len(self.fixed_ids) == 0:
            return np.arange(len(self.ids)) == 0
        return np.isin(self.ids, self.fixed_ids)


def _numbers(path, lineno, tag, fields, count, names):
    if len(fields) != count:
        raise ValueError(f"{path}:{lineno}: {tag} needs {count} values ({names}), got {len(fields)}")
    try:
        values = [float(f) for f in fields]
    except ValueError:
        raise ValueError(f"{path}:{lineno}: {tag} has a value that is not a number: {' '.join(fields)}") from None
    if not np.all(np.isfinite(values)):
        raise ValueError(f"{path}:{lineno}: {tag} has a non-finite value: {' '.join(fields)}")
    return values


def _vertex_id(path, lineno, tag, text):
    try:
        return int(text)
    except ValueError:
        raise ValueError(f"{path}:{lineno}: {tag} id {text!r} is not an integer") from None


def read_g2o(path: str | os.PathLike) -> G2oGraph:
    """Read VERTEX_SE2, EDGE_SE2 and FIX lines; raise a one-line ValueError on any malformed line."""
    path = Path(path)
    text = read_text(path, "g2o")
    ids, poses, fixed, edges, meas, info = [], [], [], [], [], []
    seen: set[int] = set()
    for lineno, line in enumerate(text.splitlines(), 1):
        fields = line.split()
        if not fields or fields[0].startswith("#"):
            continue
        tag, rest = fields[0], fields[1:]
        if tag == "VERTEX_SE2":
            _numbers(path, lineno, tag, rest, 4, "id x y theta")
            vid = _vertex_id(path, lineno, tag, rest[0])
            if vid in seen:
                raise ValueError(f"{path}:{lineno}: VERTEX_SE2 id {vid} is declared twice")
            seen.add(vid)
            ids.append(vid)
            poses.append([float(v) for v in rest[1:]])
        elif tag == "EDGE_SE2":
            values = _numbers(path, lineno, tag, rest, 11, "i j dx dy dtheta I11 I12 I13 I22 I23 I33")
            i, j = (_vertex_id(path, lineno, tag, t) for t in rest[:2])
            for v in (i, j):
                if v not in seen:
                    raise ValueError(f"{path}:{lineno}: EDGE_SE2 refers to vertex {v}, not declared before it")
            omega = np.zeros((3, 3))
            omega[_UPPER] = values[5:]
            omega = omega + np.triu(omega, 1).T
            if np.linalg.eigvalsh(omega)[0] < -1e-9 * max(1.0, np.abs(omega).max()):
                raise ValueError(f"{path}:{lineno}: EDGE_SE2 information matrix is not positive semidefinite")
            edges.append((i, j))
            meas.append(values[2:5])
            info.append(omega)
        elif tag == "FIX":
            if not rest:
                raise ValueError(f"{path}:{lineno}: FIX needs at least one vertex id")
            fixed.extend(_vertex_id(path, lineno, tag, t) for t in rest)
        else:
            raise ValueError(f"{path}:{lineno}: unknown tag {tag!r} (only VERTEX_SE2, EDGE_SE2 and FIX are read)")
    if not ids:
        raise ValueError(f"{path}: no VERTEX_SE2 line")
    missing = sorted(set(fixed) - seen)
    if missing:
        raise ValueError(f"{path}: FIX names vertex {missing[0]}, which is not declared")
    return G2oGraph(
        ids=np.array(ids, np.int64),
        poses=np.array(poses, np.float64).reshape(-1, 3),
        fixed_ids=np.array(fixed, np.int64),
        edge_ids=np.array(edges, np.int64).reshape(-1, 2),
        measurement=np.array(meas, np.float64).reshape(-1, 3),
        information=np.array(info, np.float64).reshape(-1, 3, 3),
    )


def format_g2o(graph: G2oGraph) -> str:
    """The file text: vertices, then FIX lines, then edges; floats with 17 significant digits (exact)."""
    num = lambda v: format(float(v), ".17g")
    lines = [f"VERTEX_SE2 {i} {' '.join(map(num, p))}" for i, p in zip(graph.ids, graph.poses)]
    lines += [f"FIX {i}" for i in graph.fixed_ids]
    for (i, j), z, omega in zip(graph.edge_ids, graph.measurement, graph.information):
        lines.append(f"EDGE_SE2 {i} {j} {' '.join(map(num, z))} {' '.join(map(num, omega[_UPPER]))}")
    return "\n".join(lines) + "\n"


def write_g2o(path: str | os.PathLike, graph: G2oGraph) -> Path:
    """Write `graph` atomically (a temporary file renamed into place)."""
    return atomic_write_text(path, format_g2o(graph))
