"""Synthetic 2D pose graphs with known truth: a Manhattan-style random walk on a 1 m grid with noisy
odometry, loop closures where the walk revisits a cell, and optional wrong loop closures."""

from __future__ import annotations

import dataclasses

import numpy as np


@dataclasses.dataclass(frozen=True)
class SyntheticGraph:
    truth: np.ndarray  # (N, 3) true x, y, theta
    initial: np.ndarray  # (N, 3) odometry dead reckoning: the optimizer's starting point
    edge_i: np.ndarray  # (M,) int
    edge_j: np.ndarray  # (M,) int
    measurement: np.ndarray  # (M, 3) measured T_i_j: dx, dy, dtheta
    information: np.ndarray  # (M, 3, 3)
    outlier: np.ndarray  # (M,) bool: a wrong loop closure


def _between(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """a^-1 b for (..., 3) x, y, theta rows."""
    c, s = np.cos(a[..., 2]), np.sin(a[..., 2])
    dx, dy = b[..., 0] - a[..., 0], b[..., 1] - a[..., 1]
    dth = np.angle(np.exp(1j * (b[..., 2] - a[..., 2])))
    return np.stack([c * dx + s * dy, -s * dx + c * dy, dth], -1)


def _compose(a: np.ndarray, d: np.ndarray) -> np.ndarray:
    c, s = np.cos(a[2]), np.sin(a[2])
    return np.array([a[0] + c * d[0] - s * d[1], a[1] + s * d[0] + c * d[1], np.angle(np.exp(1j * (a[2] + d[2])))])


def manhattan_graph(
    n_nodes: int,
    *,
    seed: int = 0,
    size: int = 20,
    sigma_xy: float = 0.05,
    sigma_theta: float = 0.01,
    closure_prob: float = 0.5,
    n_outliers: int = 0,
) -> SyntheticGraph:
    """A walk of `n_nodes` poses, 1 m steps, turning +-90 deg at random (always at the border of a
    `size` x `size` m square). Edges: odometry between consecutive poses and, with `closure_prob`, a
    loop closure to the earliest earlier pose (10 or more steps back) in the same cell. Measurements
    carry Gaussian noise (sigma_xy m, sigma_theta rad), exactly as the information matrix says.
    `n_outliers` extra closures join random node pairs with a made-up 1 m measurement."""
    rng = np.random.default_rng(seed)
    truth = np.zeros((n_nodes, 3))
    heading = 0
    steps = np.array([[1, 0], [0, 1], [-1, 0], [0, -1]])
    cell = np.zeros(2, int)
    seen: dict[tuple[int, int], list[int]] = {(0, 0): [0]}
    pairs = []
    for k in range(1, n_nodes):
        if rng.random() < 0.2:
            heading = (heading + rng.choice([-1, 1])) % 4
        while np.any(np.abs(cell + steps[heading]) > size // 2):
            heading = (heading + rng.choice([-1, 1])) % 4
        cell = cell + steps[heading]
        truth[k] = [cell[0], cell[1], np.angle(np.exp(1j * heading * np.pi / 2))]
        pairs.append((k - 1, k))
        earlier = [i for i in seen.get(tuple(cell), []) if i <= k - 10]
        if earlier and rng.random() < closure_prob:
            pairs.append((earlier[0], k))
        seen.setdefault(tuple(cell), []).append(k)
    for _ in range(n_outliers):
        i, j = sorted(rng.choice(n_nodes, 2, replace=False))
        pairs.append((i, j))
    ij = np.array(pairs, int).reshape(-1, 2)
    m = len(ij)
    sigma = np.array([sigma_xy, sigma_xy, sigma_theta])
    true_rel = _between(truth[ij[:, 0]], truth[ij[:, 1]])
    measurement = true_rel + rng.normal(size=(m, 3)) * sigma
    outlier = np.zeros(m, bool)
    if n_outliers:
        outlier[-n_outliers:] = True
        measurement[-n_outliers:] = [1.0, 0.0, 0.0]
    measurement[:, 2] = np.angle(np.exp(1j * measurement[:, 2]))
    information = np.broadcast_to(np.diag(1.0 / sigma**2), (m, 3, 3)).copy()
    initial = np.zeros_like(truth)
    odo = {(i, j): measurement[e] for e, (i, j) in enumerate(ij) if j == i + 1 and not outlier[e]}
    for k in range(1, n_nodes):
        initial[k] = _compose(initial[k - 1], odo[(k - 1, k)])
    return SyntheticGraph(truth, initial, ij[:, 0], ij[:, 1], measurement, information, outlier)
