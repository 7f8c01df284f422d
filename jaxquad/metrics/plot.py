"""Figures of an evaluation: xy trajectories coloured by translation error, and the error over time."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from jaxquad.io.atomic import atomic_open
from jaxquad.metrics._evaluate import Evaluation


def plot_evaluation(ev: Evaluation, out_path: str | os.PathLike) -> None:
    """Write a PNG (atomically): left, the reference and the aligned estimate in the xy plane, the estimate
    coloured by its APE translation error; right, that error (m) over time since the first pose."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.collections import LineCollection

    err = ev.ape_translation_m
    fig, (ax_xy, ax_t) = plt.subplots(1, 2, figsize=(12, 5), constrained_layout=True)
    ax_xy.plot(ev.p_ref[:, 0], ev.p_ref[:, 1], "--", color="0.5", lw=1, label="reference")
    xy = ev.p_est_aligned[:, :2]
    segments = np.stack([xy[:-1], xy[1:]], axis=1)
    lines = LineCollection(segments, cmap="viridis", lw=2)
    lines.set_array(0.5 * (err[:-1] + err[1:]) if err.size > 1 else err)
    ax_xy.add_collection(lines)
    ax_xy.scatter(xy[:1, 0], xy[:1, 1], c=err[:1], cmap="viridis", s=8, label=f"estimate ({ev.result.align_mode})")
    fig.colorbar(lines, ax=ax_xy, label="APE translation (m)")
    ax_xy.set(xlabel="x (m)", ylabel="y (m)", aspect="equal", title="trajectories (xy)")
    ax_xy.autoscale()
    ax_xy.legend(loc="best")
    ate = ev.result.ate
    ax_t.plot(ev.t_s - ev.t_s[0], err, lw=1)
    ax_t.axhline(float(ate.rmse), color="C3", ls="--", label=f"ATE (RMSE) {float(ate.rmse):.4g} m")
    ax_t.set(xlabel="time (s)", ylabel="APE translation (m)", title="translation error over time")
    ax_t.legend(loc="best")
    Path(out_path).parent.mkdir(parents=True, exist_ok=True)
    try:
        with atomic_open(out_path, "wb") as f:
            fig.savefig(f, format="png", dpi=120)
    finally:
        plt.close(fig)
