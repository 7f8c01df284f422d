"""Occupancy maps as PGM image + YAML (the ROS map_server format, trinary mode).

In memory a map is an `OccupancyMap`: a grid of int8 values -1 (unknown), 0..100 (occupancy),
row-major from the lower-left corner (row 0 is the bottom of the map, +y upward), the cell size
in metres and the pose [x, y, yaw] of the lower-left cell in the world.

On disk: the PGM (binary P5, maxval 255) stores free = 254, occupied = 0, unknown = 205 with the
first image row at the top of the map; the YAML holds `image`, `mode: trinary`, `resolution`,
`origin`, `negate: 0`, `occupied_thresh: 0.65`, `free_thresh: 0.196`. Reading applies the
thresholds to p = (255 - pixel) / 255 (or pixel / 255 when `negate` is set).
"""

from __future__ import annotations

import dataclasses
import os
from pathlib import Path

import numpy as np

from jaxquad.io.atomic import atomic_write_bytes
from jaxquad.io.files import read_text

FREE_PIXEL, OCCUPIED_PIXEL, UNKNOWN_PIXEL = 254, 0, 205
OCCUPIED_THRESH, FREE_THRESH = 0.65, 0.196


@dataclasses.dataclass(frozen=True)
class OccupancyMap:
    grid: np.ndarray  # (rows, cols) int8: -1 unknown, 0..100 occupancy; row 0 = bottom
    resolution: float  # m per cell
    origin: tuple[float, float, float]  # x (m), y (m), yaw (rad) of the lower-left cell

    def __post_init__(self):
        if self.grid.ndim != 2:
            raise ValueError(f"occupancy grid must be 2-D, got shape {self.grid.shape}")
        if not (self.resolution > 0 and np.isfinite(self.resolution)):
            raise ValueError(f"map resolution must be positive, got {self.resolution}")

    def world_to_cell(self, xy: np.ndarray) -> np.ndarray:
        """(…, 2) world x y (m) -> (…, 2) integer (row, col); the map's yaw must be 0."""
        rc = np.floor((np.asarray(xy)[..., ::-1] - np.array(self.origin[1::-1])) / self.resolution)
        return rc.astype(np.int64)

    def cell_centers(self) -> np.ndarray:
        """(rows, cols, 2) world x y (m) of every cell centre (yaw 0)."""
        rows, cols = self.grid.shape
        x = self.origin[0] + (np.arange(cols) + 0.5) * self.resolution
        y = self.origin[1] + (np.arange(rows) + 0.5) * self.resolution
        return np.stack(np.meshgrid(x, y), axis=-1)


def save_map(yaml_path: str | os.PathLike, occ: OccupancyMap) -> Path:
    """Write `<stem>.pgm` and the YAML at `yaml_path` (each atomically); returns the YAML path."""
    import yaml

    yaml_path = Path(yaml_path)
    pgm_path = yaml_path.with_suffix(".pgm")
    g = occ.grid
    pixels = np.full(g.shape, UNKNOWN_PIXEL, np.uint8)
    pixels[(g >= 0) & (g / 100.0 < FREE_THRESH)] = FREE_PIXEL
    pixels[g / 100.0 > OCCUPIED_THRESH] = OCCUPIED_PIXEL
    rows, cols = g.shape
    header = f"P5\n{cols} {rows}\n255\n".encode()
    atomic_write_bytes(pgm_path, header + np.flipud(pixels).tobytes())
    meta = {
        "image": pgm_path.name,
        "mode": "trinary",
        "resolution": float(occ.resolution),
        "origin": [float(v) for v in occ.origin],
        "negate": 0,
        "occupied_thresh": OCCUPIED_THRESH,
        "free_thresh": FREE_THRESH,
    }
    atomic_write_bytes(yaml_path, yaml.safe_dump(meta, sort_keys=False).encode())
    return yaml_path


def _read_pgm(path: Path) -> np.ndarray:
    data = path.read_bytes()
    tokens, pos = [], 0
    # Header: magic, width, height, maxval, separated by whitespace, with '#' comments.
    while len(tokens) < 4:
        while pos < len(data) and data[pos : pos + 1].isspace():
            pos += 1
        if data[pos : pos + 1] == b"#":
            pos = data.index(b"\n", pos) + 1
            continue
        start = pos
        while pos < len(data) and not data[pos : pos + 1].isspace():
            pos += 1
        tokens.append(data[start:pos])
    if tokens[0] != b"P5":
        raise ValueError(f"{path}: not a binary PGM (magic {tokens[0]!r}, expected P5)")
    cols, rows, maxval = (int(t) for t in tokens[1:])
    if maxval > 255:
        raise ValueError(f"{path}: 16-bit PGM (maxval {maxval}) is not supported")
    pixels = np.frombuffer(data, np.uint8, count=rows * cols, offset=pos + 1)
    return pixels.reshape(rows, cols)


def load_map(yaml_path: str | os.PathLike) -> OccupancyMap:
    """Read a map YAML and its image into an `OccupancyMap` (trinary thresholds)."""
    import yaml

    yaml_path = Path(yaml_path)
    try:
        meta = yaml.safe_load(read_text(yaml_path, "map"))
    except yaml.YAMLError as e:
        raise ValueError(f"map {yaml_path}: not valid YAML ({str(e).splitlines()[0]})") from None
    if meta is not None and not isinstance(meta, dict):
        raise ValueError(f"map {yaml_path}: expected a mapping with image, resolution and origin")
    missing = {"image", "resolution", "origin"} - set(meta or {})
    if missing:
        raise ValueError(f"{yaml_path}: missing map keys {sorted(missing)}")
    image = yaml_path.parent / meta["image"]
    if not image.is_file():
        raise FileNotFoundError(f"map image not found: {image}")
    pixels = np.flipud(_read_pgm(image)).astype(np.float64)
    p = pixels / 255.0 if meta.get("negate", 0) else (255.0 - pixels) / 255.0
    grid = np.full(pixels.shape, -1, np.int8)
    grid[p > meta.get("occupied_thresh", OCCUPIED_THRESH)] = 100
    grid[p < meta.get("free_thresh", FREE_THRESH)] = 0
    x, y, yaw = (float(v) for v in meta["origin"])
    return OccupancyMap(grid, float(meta["resolution"]), (x, y, yaw))
