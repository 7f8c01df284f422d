"""Grid search over the observer's bandwidth, filter constants and thresholds.

Objective: pooled F1, counted inside the scan. Among the `top_k` configurations of highest F1 that
lie within `f1_tolerance` of the best, the one with the smallest delay cost wins (exact delays from
a full re-run): mean |touchdown delay| + mean |lift-off delay| in ms, every missed edge counting as
max_delay_s; remaining ties go to the lower index. Configurations run on one vmap axis, robots on
another, configurations in fixed-size chunks to bound memory, each chunk split over the devices
(`jaxquad.parallel`; every device scores its configurations on all robots).
"""

from __future__ import annotations

import dataclasses
import functools
import math
import time
from collections.abc import Callable

import jax
import jax.numpy as jnp
import numpy as np

from jaxquad import parallel
from jaxquad.estimate.tune.observer_inputs import ContactTruth, ObserverInputs
from jaxquad.estimate.tune.observer_scan import Counts, delay_cost, f1_of, fleet_scores, observer_counts
from jaxquad.kernels import ObserverParams


@dataclasses.dataclass(frozen=True)
class GridSpec:
    """Values of each grid axis; the grid is their Cartesian product (bandwidth slowest). Thresholds
    (N) are shared by all feet; threshold_off = threshold_on * off_ratio; alpha per front/rear pair."""

    bandwidth: tuple[float, ...]
    alpha_front: tuple[float, ...]
    alpha_rear: tuple[float, ...]
    threshold_on: tuple[float, ...]
    off_ratio: tuple[float, ...]

    @classmethod
    def default(cls, size: int | tuple[int, int, int, int, int] = 4) -> GridSpec:
        """`size` points per axis (or five sizes): bandwidth 10-150 rad/s and alpha 0.05-1 and
        threshold_on 1-40 N log-spaced, off_ratio 0.3-1 evenly spaced."""
        sizes = (size,) * 5 if isinstance(size, int) else tuple(size)
        if len(sizes) != 5 or min(sizes) < 1:
            raise ValueError(f"grid size must be one positive integer or five, got {size}")
        geo = lambda lo, hi, k: tuple(float(x) for x in (np.geomspace(lo, hi, k) if k > 1 else [math.sqrt(lo * hi)]))  # noqa: E731
        lin = tuple(float(x) for x in (np.linspace(0.3, 1.0, sizes[4]) if sizes[4] > 1 else [1.0]))
        return cls(
            geo(10.0, 150.0, sizes[0]),
            geo(0.05, 1.0, sizes[1]),
            geo(0.05, 1.0, sizes[2]),
            geo(1.0, 40.0, sizes[3]),
            lin,
        )

    def __post_init__(self):
        for name in ("bandwidth", "alpha_front", "alpha_rear", "threshold_on", "off_ratio"):
            v = np.asarray(getattr(self, name), float)
            if v.ndim != 1 or v.size == 0 or not np.all(np.isfinite(v)) or np.any(v <= 0):
                raise ValueError(f"grid axis {name} needs positive finite values, got {getattr(self, name)}")
        if max(self.alpha_front + self.alpha_rear) > 1 or max(self.off_ratio) > 1:
            raise ValueError("grid alpha and off_ratio values must lie in (0, 1]")

    @property
    def size(self) -> int:
        return math.prod(len(getattr(self, f.name)) for f in dataclasses.fields(self))

    def params(self, base: ObserverParams) -> ObserverParams:
        """Every configuration as one ObserverParams with a leading axis C (other numbers from base)."""
        b, af, ar, on, ratio = (
            a.ravel()
            for a in np.meshgrid(
                self.bandwidth, self.alpha_front, self.alpha_rear, self.threshold_on, self.off_ratio, indexing="ij"
            )
        )
        n_feet = base.alpha.shape[0]
        half = n_feet // 2
        alpha = np.concatenate([np.repeat(af[:, None], half, 1), np.repeat(ar[:, None], n_feet - half, 1)], 1)
        c = b.size
        tile = lambda x: jnp.broadcast_to(x, (c,) + x.shape)  # noqa: E731
        batched = jax.tree.map(tile, base)
        return dataclasses.replace(
            batched,
            bandwidth=jnp.asarray(b, jnp.float32),
            alpha=jnp.asarray(alpha, jnp.float32),
            threshold_on=jnp.asarray(np.repeat(on[:, None], n_feet, 1), jnp.float32),
            threshold_off=jnp.asarray(np.repeat((on * ratio)[:, None], n_feet, 1), jnp.float32),
        )


def _grid_counts(params: ObserverParams, inputs: ObserverInputs, truth: ContactTruth) -> Counts:
    """Counts summed over robots for a batch of configurations (leading axis C)."""
    per_robot = jax.vmap(observer_counts, in_axes=(None, 0, 0))
    counts = jax.vmap(per_robot, in_axes=(0, None, None))(params, inputs, truth)
    return jax.tree.map(lambda a: a.sum(axis=1), counts)


@functools.lru_cache(maxsize=8)
def _sharded_counts(mesh):
    return jax.jit(parallel.shard_batched(_grid_counts, mesh, in_axes=(0, None, None), out_axes=0))


def grid_counts(
    params: ObserverParams,
    inputs: ObserverInputs,
    truth: ContactTruth,
    chunk: int = 256,
    progress: Callable[[int, int], None] | None = None,
    devices: int | None = None,
) -> Counts:
    """`observer_counts` of C configurations (leading axis C) summed over the fleet, `chunk`
    configurations per vmapped call (the last chunk padded, so one compilation serves all), split
    over `devices` devices (default all; `chunk` is rounded up to a multiple of them)."""
    mesh = parallel.mesh(devices)
    c = params.bandwidth.shape[0]
    chunk = parallel.padded_size(max(1, min(chunk, c)), mesh)
    shared = parallel.place((inputs, truth), mesh, None)  # every device scores on all robots
    parts = []
    for start in range(0, c, chunk):
        index = np.minimum(np.arange(start, start + chunk), c - 1)
        part = parallel.place(jax.tree.map(lambda a, index=index: a[index], params), mesh)
        out = parallel.gather(_sharded_counts(mesh)(part, *shared))
        n = min(chunk, c - start)
        parts.append(jax.tree.map(lambda a, n=n: np.asarray(a)[:n], out))
        if progress is not None:
            progress(min(start + chunk, c), c)
    return jax.tree.map(lambda *a: np.concatenate(a), *parts)


def pick_best(
    f1: np.ndarray, exact: Callable[[int], dict], f1_tolerance: float = 0.005, top_k: int = 8, max_delay_s: float = 0.1
) -> tuple[int, dict]:
    """Index of the winning configuration by the grid rule of the module docstring, and its scores;
    `exact(i)` returns fleet_scores of configuration i."""
    order = np.argsort(-np.asarray(f1), kind="stable")
    best = float(f1[order[0]])
    candidates = [int(i) for i in order[:top_k] if f1[i] >= best - f1_tolerance]
    scored = [(delay_cost(s := exact(i), max_delay_s), i, s) for i in candidates]
    cost, i, s = min(scored, key=lambda x: (x[0], x[1]))
    return i, s


@dataclasses.dataclass(frozen=True)
class GridResult:
    best: ObserverParams
    index: int
    f1: np.ndarray  # (C,) pooled F1 of every configuration
    force_rmse_n: np.ndarray  # (C,)
    scores: dict  # exact scores of the winner on the tuning robots
    wall_s: float


def grid_search(
    spec: GridSpec,
    base: ObserverParams,
    inputs: ObserverInputs,
    truth: ContactTruth,
    t,
    chunk: int = 256,
    f1_tolerance: float = 0.005,
    top_k: int = 8,
    max_delay_s: float = 0.1,
    progress: Callable[[int, int], None] | None = None,
    devices: int | None = None,
) -> GridResult:
    """Best configuration of the grid on the given robots (see the module docstring for the rule);
    the grid is split over `devices` devices (default all)."""
    start = time.perf_counter()
    params = spec.params(base)
    counts = grid_counts(params, inputs, truth, chunk, progress, devices)
    f1 = np.asarray(f1_of(counts))
    rmse = np.sqrt(counts.force_sq.sum(-1) / np.maximum(counts.samples * counts.force_sq.shape[-1], 1))
    take = lambda i: jax.tree.map(lambda a: a[i], params)  # noqa: E731
    i, s = pick_best(
        f1, lambda i: fleet_scores(take(i), inputs, truth, t, max_delay_s), f1_tolerance, top_k, max_delay_s
    )
    return GridResult(best=take(i), index=i, f1=f1, force_rmse_n=rmse, scores=s, wall_s=time.perf_counter() - start)
