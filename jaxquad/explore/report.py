"""The summary and the pictures of an exploration run (`jaxquad.explore.config.ExploreResult`).

summary (JSON-ready dict): the configuration, loop and SLAM parameters used; `coverage` (each robot's final map:
known-free cells among the true reachable free cells, over those cells; per robot and mean); `coverage_clear` (the
same over the reachable cells whose whole square is clear of every box: a cell a box's face passes through holds
range returns, and no range-sensor map can show it free); `coverage_over_time` (sampled every `every` s: the map at
the last tick at or before each time, held after a run ended); `uncovered` (what each final map says of the
reachable cells coverage misses, as shares of the reachable cells: `unknown`, no ray went there; `uncertain`, seen
but neither free nor occupied by the map format's thresholds; `occupied`; and `on_box_faces`, those of them not
clear of the boxes); the map scores of each final map against the true map (`jaxquad.metrics.map_scores`: occupied-
cell IoU, precision, recall within one cell); outcome counts and per-robot flags (explored, collided, lost,
fallen); distance walked; the revisits (`ExploreConfig.revisit_after`: begun, ended by a loop closure, and per robot
the seconds spent on them); the SLAM position error; for the traced robots, the seconds spent in each control mode
(`loop.MODES`: MPPI, the goal turn, standing at the goal, recovery, the look-around turn, waiting) and the mode of
each run's last tick, counted over the traced collided runs in `collided_while`; timing (compilation apart; each
chunk's wall time in `chunk_s`).
"""

from __future__ import annotations

import dataclasses

import numpy as np

from jaxquad.explore.loop import COLLIDED, MODES, OUTCOMES, coverage
from jaxquad.io.maps import OCCUPIED_THRESH
from jaxquad.nav.missions import known_free
from jaxquad.nav.report import timing

SUMMARY_KIND = "jaxquad explore"


def _stats(x) -> dict:
    x = np.asarray(x, np.float64)
    x = x[np.isfinite(x)]
    if x.size == 0:
        return {"n": 0, "mean": None, "std": None, "min": None, "median": None, "max": None}
    return {
        "n": int(x.size),
        "mean": float(x.mean()),
        "std": float(x.std()),
        "min": float(x.min()),
        "median": float(np.median(x)),
        "max": float(x.max()),
    }


def coverage_samples(result, every: float = 5.0) -> tuple[np.ndarray, np.ndarray]:
    """(times (S,) s every `every` s from 0 to the configured run length, coverage (S, N)): at each time the
    value of the last tick at or before it (the first tick's before it; the last tick's after the run)."""
    times = np.arange(0.0, result.config.seconds + 1e-9, every)
    k = np.clip(np.searchsorted(result.t, times + 1e-9, side="right") - 1, 0, len(result.t) - 1)
    return times, result.coverage[k]


def _final_coverage(result, cells=None) -> np.ndarray:
    """(N,) coverage of each robot's final map over `cells` (default: the reachable cells)."""
    import jax.numpy as jnp

    cells = jnp.asarray(result.reachable if cells is None else cells)
    return np.array([float(coverage(jnp.asarray(m), cells)) for m in result.maps])


def _last_modes(result) -> np.ndarray:
    """(n_trace,) the mode each traced robot's run ended in (-1: never active): that of the tick before its last,
    whose command the robot was executing on its last tick."""
    active = result.active[:, : result.mode.shape[1]]
    last = np.maximum(active.shape[0] - 2 - np.argmax(active[::-1], axis=0), 0)
    return np.where(active.any(axis=0), result.mode[last, np.arange(active.shape[1])], -1)


def uncovered(maps: np.ndarray, reachable: np.ndarray, clear: np.ndarray) -> dict[str, np.ndarray]:
    """Per map of `maps` (N, H, W; -1 unknown, else 0..100), the `reachable` cells it does not call free, by what
    it calls them, each as a share (N,) of the reachable cells; `on_box_faces`: those of them outside `clear`."""
    missed = reachable & ~known_free(maps)
    occupied = maps > 100 * OCCUPIED_THRESH
    share = lambda m: m.sum(axis=(1, 2)) / max(int(reachable.sum()), 1)
    return {
        "unknown": share(missed & (maps < 0)),
        "uncertain": share(missed & (maps >= 0) & ~occupied),
        "occupied": share(missed & occupied),
        "on_box_faces": share(missed & ~clear),
    }


def final_maps(result) -> list:
    from jaxquad.io.maps import OccupancyMap

    return [OccupancyMap(m, result.truth.resolution, result.truth.origin) for m in result.maps]


def summarize(result, every: float = 5.0) -> dict:
    """The summary dict of an ExploreResult (see the module doc)."""
    from jaxquad.metrics import map_scores

    cfg, n = result.config, result.outcome.shape[0]
    final = _final_coverage(result)
    final_clear = _final_coverage(result, result.clear)
    scores = [dataclasses.asdict(map_scores(m, result.truth)) for m in final_maps(result)]
    times, cov_t = coverage_samples(result, every)
    n_trace = result.mode.shape[1]
    tick_s = float(result.t[1] - result.t[0]) if len(result.t) > 1 else float(result.t[0])  # the first ends one in
    last_mode = _last_modes(result)
    missed = uncovered(result.maps, result.reachable, result.clear)
    per_robot = []
    for i in range(n):
        err = result.error[result.active[:, i], i]
        outcome = OUTCOMES[result.outcome[i]]
        per_robot.append(
            {
                "robot": i,
                "start": result.starts[i].tolist(),
                "outcome": outcome,
                **{flag: outcome == flag for flag in ("explored", "collided", "lost", "fallen")},
                "end_s": None if np.isnan(result.end_t[i]) else float(result.end_t[i]),
                "coverage": float(final[i]),
                "coverage_clear": float(final_clear[i]),
                "uncovered": {k: float(v[i]) for k, v in missed.items()},
                "distance_m": float(result.distance[i]),
                "slam_error_m": _stats(err),
                "slam_nodes": int(result.nodes[i]),
                "loop_closures": int(result.loops[i]),
                "leg_bias_mps": result.lo_bias[i].tolist(),  # the SLAM's estimate, base frame x y (0: not estimated)
                "revisits": int(result.revisits[i]),
                "revisits_closed": int(result.revisits_closed[i]),
                "revisit_s": float(result.revisiting[result.active[:, i], i].sum() * tick_s),
                "view_s": float(result.viewing[result.active[:, i], i].sum() * tick_s),
                "map_scores": scores[i],
            }
        )
        if i < n_trace:
            mode = result.mode[result.active[:, i], i]
            per_robot[-1]["control_s"] = {m: float((mode == k).sum() * tick_s) for k, m in enumerate(MODES[:-1])}
            per_robot[-1]["mode_at_end"] = MODES[last_mode[i]] if last_mode[i] >= 0 else None
    iou = np.array([s["iou"] for s in scores], np.float64)
    return {
        "kind": SUMMARY_KIND,
        "config": dataclasses.asdict(cfg),
        "loop": dataclasses.asdict(cfg.loop_config()),
        "slam_params": cfg.slam_values(),
        "robots": n,
        "reachable_free_m2": float(result.reachable.sum() * result.truth.resolution**2),
        "coverage": {**_stats(final), "per_robot": final.tolist()},
        "clear_free_m2": float(result.clear.sum() * result.truth.resolution**2),
        "coverage_clear": {**_stats(final_clear), "per_robot": final_clear.tolist()},
        "uncovered": {k: _stats(v) for k, v in missed.items()},
        "coverage_over_time": {
            "t_s": times.tolist(),
            "mean": cov_t.mean(axis=1).tolist(),
            "min": cov_t.min(axis=1).tolist(),
            "max": cov_t.max(axis=1).tolist(),
            "per_robot": cov_t.T.tolist(),
        },
        "map_iou": _stats(iou),
        "outcomes": {name: int((result.outcome == code).sum()) for code, name in enumerate(OUTCOMES)},
        "collided_while": {
            m: int(((result.outcome[:n_trace] == COLLIDED) & (last_mode == k)).sum()) for k, m in enumerate(MODES[:-1])
        },
        "distance_m": _stats(result.distance),
        "revisits": _stats(result.revisits),
        "revisits_closed": _stats(result.revisits_closed),
        "view_s": _stats((result.viewing & result.active).sum(0) * tick_s),
        "slam_error_m": _stats(result.error[result.active]),
        "timing": timing(result, n) | {"chunk_s": np.round(result.chunk_s, 3).tolist()},
        "per_robot": per_robot,
    }


def plot_maps(result, path, max_robots: int = 4) -> None:
    """Each of the first robots' final map with its true path (solid), SLAM path (dotted) and start (circle)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from jaxquad.io.atomic import atomic_open

    occ = result.truth
    rows, cols = occ.grid.shape
    x0, y0 = occ.origin[0], occ.origin[1]
    extent = (x0, x0 + cols * occ.resolution, y0, y0 + rows * occ.resolution)
    m = max(1, min(max_robots, result.maps.shape[0], result.true_pose.shape[1]))
    fig, axes = plt.subplots(1, m, figsize=(5 * m, 5 * rows / max(cols, 1) + 0.8), squeeze=False)
    final = _final_coverage(result)
    for i, ax in enumerate(axes[0]):
        grid = result.maps[i]
        ax.imshow(np.where(grid < 0, 0.8, 1.0 - np.clip(grid, 0, 100) / 100.0), cmap="gray", vmin=0, vmax=1,
                  origin="lower", extent=extent)  # fmt: skip
        if result.low[i].size:  # the obstacles marked under the scan plane (`ExploreConfig.low_obstacles`)
            low_rc = np.argwhere(result.low[i])
            ax.plot(x0 + (low_rc[:, 1] + 0.5) * occ.resolution, y0 + (low_rc[:, 0] + 0.5) * occ.resolution, "s",
                    color="tab:red", ms=1.5, label="low obstacles")  # fmt: skip
        run = result.active[:, i]
        ax.plot(*result.true_pose[run, i, :2].T, "-", color="tab:blue", lw=1.0, label="true path")
        ax.plot(*result.pose[run, i, :2].T, ":", color="tab:orange", lw=1.0, label="SLAM pose")
        ax.plot(*result.starts[i, :2], "o", color="tab:green", ms=6, label="start")
        ax.set_title(f"robot {i}: {OUTCOMES[result.outcome[i]]}, coverage {100 * final[i]:.1f} %", fontsize=9)
        ax.set_xlabel("x (m)")
        ax.set_ylabel("y (m)")
    axes[0, 0].legend(fontsize=7, loc="upper right")
    s = result.config
    fig.suptitle(f"{s.robot}, {s.world}, {s.variant}: SLAM maps after {result.sim_s:.0f} s", fontsize=10)
    fig.tight_layout()
    with atomic_open(path, "wb") as f:
        fig.savefig(f, format="png", dpi=110)
    plt.close(fig)


def plot_coverage(result, path, every: float = 5.0) -> None:
    """Coverage against time: every robot (thin) and the fleet's mean (thick)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from jaxquad.io.atomic import atomic_open

    times, cov = coverage_samples(result, every)
    fig, ax = plt.subplots(figsize=(6, 4))
    ax.plot(result.t, 100 * result.coverage, color="0.7", lw=0.8)
    ax.plot(times, 100 * cov.mean(axis=1), "o-", color="tab:blue", lw=2, ms=3, label=f"mean of {cov.shape[1]}")
    ax.set_xlabel("time (s)")
    ax.set_ylabel("coverage (% of the reachable free area)")
    ax.set_ylim(0, 100)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8)
    s = result.config
    ax.set_title(f"{s.robot}, {s.world}, {s.variant}", fontsize=9)
    fig.tight_layout()
    with atomic_open(path, "wb") as f:
        fig.savefig(f, format="png", dpi=110)
    plt.close(fig)
