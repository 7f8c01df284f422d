"""The summary and the picture of a navigation run (`jaxquad.nav.fleet.NavResult`).

summary (JSON-ready dict): the configuration and AMCL parameters used; `success_rate` (goals reached
over all goals given, the skipped ones included: reached = the navigation stack reported arrival and
the true pose was within 0.25 m / 0.25 rad of the goal); counts of each outcome; time to goal of the
reached goals; localization error statistics over every camera frame of every robot still running; timing
(compilation apart; `real_time_factor` = simulated seconds per wall second for the whole fleet);
one entry per goal.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from jaxquad.nav.closed_loop import OUTCOMES, REACHED
from jaxquad.nav.fleet import SUCCESS_XY, SUCCESS_YAW

SUMMARY_KIND = "jaxquad navigate"


def timing(result, n: int) -> dict:
    """Compile and run wall times of a fleet run of `n` robots, and its speed against simulated time."""
    speed = result.sim_s / result.run_s if result.run_s > 0 else None
    return {
        "compile_s": result.compile_s,
        "run_s": result.run_s,
        "simulated_s": result.sim_s,
        "real_time_factor": speed,
        "robot_seconds_per_s": None if speed is None else n * speed,
    }


def _stats(x: np.ndarray) -> dict:
    x = np.asarray(x, np.float64)
    if x.size == 0:
        return {"n": 0, "median": None, "mean": None, "p95": None, "p99": None, "max": None, "rmse": None}
    return {
        "n": int(x.size),
        "median": float(np.median(x)),
        "mean": float(x.mean()),
        "p95": float(np.percentile(x, 95)),
        "p99": float(np.percentile(x, 99)),
        "max": float(x.max()),
        "rmse": float(np.sqrt(np.mean(x**2))),
    }


def summarize(result) -> dict:
    """The summary dict of a NavResult (see the module doc)."""
    cfg, n, g = result.config, result.outcome.shape[0], result.outcome.shape[1]
    reached = result.outcome == REACHED
    err = result.loc_error[result.active]  # (frames of running robots, F)
    rising = result.recovering & ~np.concatenate([np.zeros_like(result.recovering[:1]), result.recovering[:-1]])
    per_robot_err = [result.loc_error[result.active[:, i], i].ravel() for i in range(n)]
    per_goal = [
        {
            "robot": i,
            "index": k,
            "goal": result.goals[i, k].tolist(),
            "outcome": OUTCOMES[result.outcome[i, k]],
            "time_s": float(result.elapsed[i, k]),
            "true_error_m": float(result.end_error[i, k, 0]),
            "true_error_yaw_rad": float(result.end_error[i, k, 1]),
        }
        for i in range(n)
        for k in range(g)
    ]
    loop = cfg.loop_config()
    return {
        "kind": SUMMARY_KIND,
        "config": dataclasses.asdict(cfg),
        "loop": dataclasses.asdict(loop),
        "amcl_params": dataclasses.asdict(cfg.localize_params()),
        "robots": n,
        "goals": n * g,
        "success_rate": float(reached.mean()),
        "outcomes": {name: int((result.outcome == code).sum()) for code, name in enumerate(OUTCOMES)},
        "success_tolerance": {"xy_m": SUCCESS_XY, "yaw_rad": SUCCESS_YAW},
        "controller_goal_tolerance": {"xy_m": cfg.arrive_xy, "yaw_rad": cfg.arrive_yaw},
        "time_to_goal_s": _stats(result.elapsed[reached]),
        "localization_error_m": _stats(err.ravel()),
        "localization_error_median_per_robot_m": _stats(np.array([np.median(e) for e in per_robot_err if e.size])),
        "recoveries": int(rising.sum()),
        "timing": timing(result, n),
        "per_goal": per_goal,
    }


def plot_paths(result, path, max_robots: int = 8) -> None:
    """Paths on the map: true (solid) and estimated (dotted) for the first robots, their starts (circles)
    and goals (numbered, coloured by outcome)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from jaxquad.io.atomic import atomic_open

    occ = result.occ
    rows, cols = occ.grid.shape
    x0, y0 = occ.origin[0], occ.origin[1]
    extent = (x0, x0 + cols * occ.resolution, y0, y0 + rows * occ.resolution)
    image = np.where(occ.grid < 0, 0.8, 1.0 - np.clip(occ.grid, 0, 100) / 100.0)
    colors = {
        "reached": "tab:green",
        "missed": "gold",
        "collided": "tab:red",
        "lost": "tab:purple",
        "timeout": "tab:orange",
        "fallen": "tab:brown",
        "skipped": "tab:gray",
        "pending": "tab:gray",
    }
    fig, ax = plt.subplots(figsize=(8, 8 * rows / max(cols, 1) + 0.5))
    ax.imshow(image, cmap="gray", vmin=0, vmax=1, origin="lower", extent=extent)
    m = min(max_robots, result.true_pose.shape[1])
    cmap = plt.get_cmap("tab10")
    for i in range(m):
        run = result.active[:, i]
        c = cmap(i % 10)
        ax.plot(*result.true_pose[run, i, :2].T, "-", color=c, lw=1.2, label=f"robot {i}")
        ax.plot(*result.pose[run, i, :2].T, ":", color=c, lw=1.0)
        ax.plot(*result.starts[i, :2], "o", color=c, ms=6)
        for k, goal in enumerate(result.goals[i]):
            outcome = OUTCOMES[result.outcome[i, k]]
            ax.plot(*goal[:2], "*", color=colors[outcome], ms=11, mec="k", mew=0.5)
            ax.annotate(f"{i}.{k + 1}", goal[:2], textcoords="offset points", xytext=(4, 4), fontsize=7)
            ax.arrow(goal[0], goal[1], 0.3 * np.cos(goal[2]), 0.3 * np.sin(goal[2]), color="k", width=0.01)
    ax.set_xlabel("x (m)")
    ax.set_ylabel("y (m)")
    s = result.config
    ax.set_title(
        f"{s.robot}, {s.world}, {s.variant}: true paths (solid), localization (dotted); goals by outcome", fontsize=9
    )
    ax.legend(fontsize=7, loc="upper right")
    fig.tight_layout()
    with atomic_open(path, "wb") as f:
        fig.savefig(f, format="png", dpi=120)
    plt.close(fig)
