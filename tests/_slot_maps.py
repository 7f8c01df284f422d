"""Occupancy grids of the view-goal tests: a known room (0.05 m cells; -1 unknown, 0 free, 100 occupied) with
slots in its top wall, each 0.4 m wide and too narrow to enter: its first 0.3 m free, the rest unknown (a frontier
0.4 m long)."""

from __future__ import annotations

import numpy as np


def room_with_slots(cols: int, slot_cols: tuple[int, ...]) -> np.ndarray:
    """(80, cols) grid: walls on its border and from row 60 up, a slot of 8 columns from each of `slot_cols`."""
    grid = np.zeros((80, cols), np.int8)
    grid[[0, -1], :] = 100
    grid[:, [0, -1]] = 100
    grid[60:, :] = 100
    for c in slot_cols:
        grid[60:78, c : c + 8] = 0
        grid[66:78, c : c + 8] = -1
    return grid
