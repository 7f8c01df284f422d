"""Pictures of a fleet run (matplotlib, Agg backend): trajectories, contact timelines, scan bands.

Every function writes one PNG atomically (temporary file in the same folder, then rename) and
returns its path. Inputs are NumPy arrays; nothing here runs JAX.

Conventions follow jaxquad.kernels.scan: camera x right, y down, z forward; pixel rows v grow
downward; roll and pitch are the base's ZYX Euler angles as the IMU reports them; bearings are
counter-clockwise from the camera's forward axis.
"""

from __future__ import annotations

import os
from collections.abc import Mapping, Sequence
from pathlib import Path

import numpy as np

from jaxquad.io.atomic import atomic_open

# One colour per trajectory source, fixed so every picture of a report reads the same way.
COLORS = {
    "ground truth": "black",
    "mixed": "tab:orange",
    "observer": "tab:purple",
    "truth": "tab:blue",
    "tuned": "tab:orange",
    "paper": "tab:purple",
    "stabilized": "tab:green",
    "baseline": "tab:red",
}


def _figure(*args, **kwargs):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt.subplots(*args, **kwargs)


def _save(fig, path: str | os.PathLike) -> Path:
    import matplotlib.pyplot as plt

    path = Path(path)
    try:
        with atomic_open(path, "wb") as f:
            fig.savefig(f, format="png", dpi=110, bbox_inches="tight")
    finally:
        plt.close(fig)
    return path


def band_rows(K: np.ndarray, roll: float, pitch: float, band_height: int, width: int) -> np.ndarray:
    """(band_height, width) pixel rows the stabilized scan samples (facts.md Sec. 3; roll = pitch = 0
    gives the baseline band): v = round(o + (u - c_x) tan(-roll) - f_y tan(pitch)), o = floor(c_y -
    h/2) + k. Rows may fall outside the image (the scan skips them). Rounding is half-to-even."""
    fy, cx, cy = K[1, 1], K[0, 2], K[1, 2]
    u = np.arange(width, dtype=np.float64)
    base = np.floor(cy - band_height / 2) + np.arange(band_height)
    return np.round(base[:, None] + ((u - cx) * np.tan(-roll) - fy * np.tan(pitch))[None, :])


def scan_points_world(ranges: np.ndarray, bearings: np.ndarray, xy_camera: np.ndarray, yaw: float) -> np.ndarray:
    """(M, 2) world x y (m) of the finite rays of a scan taken at planar pose (xy_camera, yaw):
    how a 2D mapper places a scan sliced from a camera that looks along the base's heading."""
    ok = np.isfinite(ranges)
    a = yaw + bearings[ok]
    return np.asarray(xy_camera)[None, :] + ranges[ok, None] * np.stack([np.cos(a), np.sin(a)], axis=-1)


def _zoom(ax, points: np.ndarray, margin: float) -> None:
    """Square axis limits around the finite (M, 2) points, with a margin (m) and at least 3 m wide."""
    points = points[np.all(np.isfinite(points), axis=1)]
    lo, hi = points.min(0), points.max(0)
    half = max(float(np.max(hi - lo)) / 2 + margin, 1.5)
    mid = (lo + hi) / 2
    ax.set_xlim(mid[0] - half, mid[0] + half)
    ax.set_ylim(mid[1] - half, mid[1] + half)


def _draw_map(ax, occ) -> None:
    """Occupied cells black, free white, unknown grey, in world metres."""
    rows, cols = occ.grid.shape
    img = np.where(occ.grid < 0, 0.8, np.where(occ.grid >= 50, 0.0, 1.0))
    x0, y0 = occ.origin[0], occ.origin[1]
    extent = (x0, x0 + cols * occ.resolution, y0, y0 + rows * occ.resolution)
    ax.imshow(img, origin="lower", extent=extent, cmap="gray", vmin=0, vmax=1, interpolation="nearest")


def plot_trajectories(
    path,
    xy_true: Sequence[np.ndarray],
    xy_est: Mapping[str, Sequence[np.ndarray]],
    occ=None,
    titles: Sequence[str] | None = None,
) -> Path:
    """One panel per robot: the ground-truth path (x, y in m) and each estimate's, over the map."""
    n = len(xy_true)
    cols = min(n, 2)
    rows = (n + cols - 1) // cols
    fig, axes = _figure(rows, cols, figsize=(5.2 * cols, 4.6 * rows), squeeze=False, layout="constrained")
    for i, ax in enumerate(axes.ravel()):
        if i >= n:
            ax.axis("off")
            continue
        if occ is not None:
            _draw_map(ax, occ)
        gt = np.asarray(xy_true[i])
        ax.plot(gt[:, 0], gt[:, 1], color=COLORS["ground truth"], lw=2.0, label="ground truth")
        for label, paths in xy_est.items():
            p = np.asarray(paths[i])
            ax.plot(p[:, 0], p[:, 1], color=COLORS.get(label), lw=1.3, label=f"leg odometry ({label} contacts)")
        ax.plot(*gt[0], "o", color="black", ms=6, label="start")
        # Zoom on the paths with a margin, keeping the map's scale.
        _zoom(ax, np.concatenate([gt] + [np.asarray(p[i]) for p in xy_est.values()]), margin=0.75)
        ax.set_aspect("equal")
        ax.set_xlabel("x (m)")
        ax.set_ylabel("y (m)")
        ax.set_title(titles[i] if titles else f"robot {i}", fontsize=10)
    # One legend for every panel, under them, so no path is hidden.
    handles, labels = axes[0, 0].get_legend_handles_labels()
    fig.legend(handles, labels, loc="outside lower center", ncol=len(labels), fontsize=9, frameon=False)
    fig.suptitle("Base trajectory: ground truth and leg-inertial odometry", fontsize=12)
    return _save(fig, path)


def plot_contacts(
    path,
    t: np.ndarray,
    contact_true: np.ndarray,
    contact_est: np.ndarray,
    force_true: np.ndarray,
    force_est: np.ndarray,
    foot_names: Sequence[str],
    title: str = "",
) -> Path:
    """One row per foot over the time window given: true stance shaded, the estimated stance as a
    bar under the axis, true and estimated vertical foot forces (N)."""
    t = np.asarray(t, float)
    n_feet = len(foot_names)
    fig, axes = _figure(n_feet, 1, figsize=(10, 1.9 * n_feet), sharex=True, squeeze=False)
    # Scale to the bulk of the forces: single-sample impact peaks are clipped at the top.
    forces = np.r_[np.asarray(force_true, float).ravel(), np.asarray(force_est, float).ravel()]
    forces = forces[np.isfinite(forces)]
    top = 1.2 * float(max(np.percentile(forces, 98), 1.0)) if forces.size else 1.0
    for f, ax in enumerate(axes[:, 0]):
        ax.fill_between(t, 0, top * 1.05, where=contact_true[:, f], step="mid", color="0.85", label="true stance")
        ax.fill_between(
            t,
            -0.16 * top,
            -0.04 * top,
            where=contact_est[:, f],
            step="mid",
            color=COLORS["mixed"],
            label="estimated stance",
        )
        ax.plot(t, force_true[:, f], color="black", lw=1.0, label="true force z")
        ax.plot(t, force_est[:, f], color=COLORS["mixed"], lw=1.2, label="estimated force z (filtered)")
        ax.set_ylim(-0.2 * top, top * 1.08)
        ax.set_ylabel(f"{foot_names[f]}\nforce (N)", fontsize=9)
        ax.grid(alpha=0.3)
    axes[0, 0].legend(fontsize=7, ncol=4, loc="upper right", framealpha=0.9)
    axes[-1, 0].set_xlabel("time (s)")
    axes[-1, 0].set_xlim(t[0], t[-1])
    fig.suptitle(title or "Foot contacts: ground truth and observer", fontsize=12)
    return _save(fig, path)


def plot_heights(path, t: np.ndarray, z_true: np.ndarray, z_est: dict[str, np.ndarray], title: str = "") -> Path:
    """Base height (m) over time: ground truth and each estimate (label -> (T,) array)."""
    fig, axes = _figure(1, 1, figsize=(10, 3.2), squeeze=False)
    ax = axes[0, 0]
    ax.plot(t, z_true, color=COLORS["ground truth"], lw=1.6, label="ground truth")
    for label, z in z_est.items():
        ax.plot(t, z, color=COLORS.get(label), lw=1.1, label=f"leg odometry ({label} contacts)")
    ax.set_xlabel("time (s)")
    ax.set_ylabel("base height z (m)")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8, ncol=4, loc="lower left", framealpha=0.9)
    fig.suptitle(title or "Base height: ground truth and leg-inertial odometry", fontsize=12)
    return _save(fig, path)


def plot_scan_frame(
    path,
    depth: np.ndarray,
    K: np.ndarray,
    roll: float,
    pitch: float,
    band_height: int,
    scans_world: Mapping[str, np.ndarray] | None = None,
    occ=None,
    xy_camera: np.ndarray | None = None,
    title: str = "",
) -> Path:
    """Left: the depth image with the baseline band (fixed on row c_y) and the IMU-stabilized band
    drawn on it. Right (when scans_world is given): the scans' end points in the map frame over
    the ground-truth map."""
    height, width = depth.shape
    panels = 2 if scans_world is not None else 1
    fig, axes = _figure(1, panels, figsize=(6.0 * panels, 4.6), squeeze=False)
    ax = axes[0, 0]
    shown = np.where(depth > 0, depth, np.nan)
    im = ax.imshow(shown, cmap="viridis", interpolation="nearest")
    fig.colorbar(im, ax=ax, fraction=0.035, pad=0.02, label="depth (m)")
    u = np.arange(width)
    for label, (r, p) in (("baseline", (0.0, 0.0)), ("stabilized", (roll, pitch))):
        rows = band_rows(K, r, p, band_height, width)
        # The band's outer edges (pixel boundaries), clipped to the image.
        for k, edge in enumerate((rows[0] - 0.5, rows[-1] + 0.5)):
            inside = (edge >= -0.5) & (edge <= height - 0.5)
            ax.plot(u[inside], edge[inside], color=COLORS[label], lw=1.4, label=f"{label} band" if k == 0 else None)
    ax.legend(fontsize=8, loc="lower right")
    ax.set_title(f"depth frame, roll {np.degrees(roll):+.1f} deg, pitch {np.degrees(pitch):+.1f} deg", fontsize=10)
    ax.set_xlabel("u (px)")
    ax.set_ylabel("v (px)")
    if scans_world is not None:
        ax = axes[0, 1]
        if occ is not None:
            _draw_map(ax, occ)
        pts_all = [np.asarray(v) for v in scans_world.values() if len(v)]
        for label, pts in scans_world.items():
            pts = np.asarray(pts)
            ax.plot(pts[:, 0], pts[:, 1], ".", ms=3, color=COLORS.get(label), label=f"{label} scan")
        if xy_camera is not None:
            ax.plot(*xy_camera, "^", color="black", ms=8, label="camera")
            _zoom(ax, np.concatenate(pts_all + [np.asarray(xy_camera)[None]]), margin=0.5)
        ax.set_aspect("equal")
        ax.legend(fontsize=8, loc="best")
        ax.set_title("scans in the map frame (ground-truth pose)", fontsize=10)
        ax.set_xlabel("x (m)")
        ax.set_ylabel("y (m)")
    fig.suptitle(title or "Laser scan from depth: baseline and IMU-stabilized bands", fontsize=12)
    return _save(fig, path)
