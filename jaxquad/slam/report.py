"""What `jaxquad slam` writes per robot: trajectories (TUM), the map, the graph (g2o) and scores.

  trajectory.tum        each scan's base pose as the online SLAM estimated it at that scan (z = 0)
  trajectory_final.tum  each scan's base pose after the last optimization, stamped with the scan's time
                        (both in time order, one pose per stamp: `tum_of`)
  map.pgm, map.yaml     the occupancy map at the final node poses (map_server format)
  graph.g2o             the final pose graph: nodes (base poses) and edges (matches, leg odometry, loops)
  map_vs_truth.png      with a true map: the map beside it, walls overlaid, and the trajectories

Scores (with ground truth): ATE/ARE/APE/RPE and segment drift of the online, final and odometry-only
trajectories against the truth (evo's definitions, SE(3) Umeyama alignment, 2D poses at z = 0), and
the final map's scores against the true map (`jaxquad.metrics.map_scores`; with the truth path, also
in view: the walls an ideal laser at the true laser poses first hits, out to the map's range), and each
edge kind's error at the true node poses against its information (`edge_errors`).
"""

from __future__ import annotations

from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

from jaxquad.io import G2oGraph, TumTrajectory, save_map, write_g2o, write_tum
from jaxquad.kernels.lie import se2, xy_theta
from jaxquad.kernels.occupancy import GridSpec
from jaxquad.kernels.posegraph import edge_error
from jaxquad.slam import online
from jaxquad.slam.mapping import to_occupancy_map

EDGE_KIND_NAMES = {
    online.EDGE_MATCH: "match",
    online.EDGE_ODOMETRY: "odometry",
    online.EDGE_LEG: "leg_odometry",
    online.EDGE_LOOP: "loop",
    online.EDGE_HEADING: "wall_heading",
}


def _quat_yaw(theta: np.ndarray) -> np.ndarray:
    """(w, x, y, z) of rotations about z."""
    return np.stack([np.cos(theta / 2), np.zeros_like(theta), np.zeros_like(theta), np.sin(theta / 2)], -1)


def tum_of(t: np.ndarray, pose: np.ndarray) -> TumTrajectory:
    """The finite rows of 2D poses (S, 3) as a TUM trajectory at z = 0, in time order (a log's stamps
    may go back); of scans with one stamp the first is kept (a TUM file has one pose per time)."""
    keep = np.flatnonzero(np.all(np.isfinite(pose), axis=1) & np.isfinite(t))
    keep = keep[np.argsort(t[keep], kind="stable")]
    keep = keep[np.r_[True, np.diff(t[keep]) > 0]]
    p = np.c_[pose[keep, :2], np.zeros(keep.size)]
    q = _quat_yaw(pose[keep, 2])
    return TumTrajectory(t[keep], p, q[:, [1, 2, 3, 0]])


def graph_of(state) -> G2oGraph:
    """One robot's final pose graph (its used slots) as a g2o graph; node 0 fixed."""
    n, m = int(state.n_nodes), int(state.n_edges)
    g = state.graph
    keep = np.asarray(g.edge_mask[:m], bool)
    return G2oGraph(
        ids=np.arange(n),
        poses=np.asarray(g.poses[:n], np.float64),
        fixed_ids=np.array([0]),
        edge_ids=np.stack([np.asarray(g.edge_i[:m])[keep], np.asarray(g.edge_j[:m])[keep]], 1),
        measurement=np.asarray(g.measurement[:m], np.float64)[keep],
        information=np.asarray(g.information[:m], np.float64)[keep],
    )


OFF_M = 0.3  # an edge whose translation error exceeds this counts as off


def edge_errors(state, out, gt: np.ndarray) -> dict | None:
    """Each edge kind's error at the true node poses: g2o's edge error (`kernels.posegraph.edge_error`) with
    the nodes at the truth of their scans, so 0 for a perfect measurement. Per kind: `n` edges, the rms of
    the error's x, y (m) and heading (rad) over the edges with information on them (NaN for none: a wall-heading
    prior holds only a heading), `chi2_mean` (e^T Omega e averaged; its degrees of freedom, 3 or 1, when the
    information matches the errors, less when it is cautious, more when it is overconfident) and `off` (edges
    whose translation error exceeds `OFF_M`). `gt` (S, 3) is the truth at every scan; None when a node's scan
    has no finite truth."""
    n, m = int(state.n_nodes), int(state.n_edges)
    node_scan = np.flatnonzero(np.asarray(out.added, bool))
    if node_scan.size != n or not np.all(np.isfinite(gt[node_scan])):
        return None
    g = state.graph
    keep = np.asarray(g.edge_mask[:m], bool)
    kinds = np.asarray(state.edge_kind[:m])[keep]
    truth = jnp.asarray(gt[node_scan], jnp.float32)
    ei, ej = np.asarray(g.edge_i[:m])[keep], np.asarray(g.edge_j[:m])[keep]
    e = np.asarray(jax.vmap(edge_error)(truth[ei], truth[ej], jnp.asarray(g.measurement[:m])[keep]), np.float64)
    # An edge scores only the components it has information on (a wall-heading prior: its heading alone).
    has = np.diagonal(np.asarray(g.information[:m], np.float64)[keep], axis1=1, axis2=2) > 0
    e = np.where(has, e, 0.0)
    chi2 = np.einsum("ma,mab,mb->m", e, np.asarray(g.information[:m], np.float64)[keep], e)
    rows = {}
    for kind, name in EDGE_KIND_NAMES.items():
        k = kinds == kind
        if k.any():
            count = (has[k]).sum(axis=0)
            rms = np.sqrt((e[k] ** 2).sum(axis=0) / np.maximum(count, 1))
            rms = np.where(count > 0, rms, np.nan)
            rows[name] = {
                "n": int(k.sum()),
                "rms_x_m": float(rms[0]),
                "rms_y_m": float(rms[1]),
                "rms_theta_rad": float(rms[2]),
                "chi2_mean": float(chi2[k].mean()),
                "off": int((np.hypot(e[k, 0], e[k, 1]) > OFF_M).sum()),
            }
    return rows


def _trajectory_scores(t: np.ndarray, pose: np.ndarray, gt: np.ndarray, valid: np.ndarray) -> dict:
    from jaxquad.estimate.run import trajectory_metrics

    # Scans without truth, or that do not advance the clock (a laser log's stamps that went back), are not scored.
    ok = valid & np.all(np.isfinite(pose), axis=1) & np.all(np.isfinite(gt), axis=1) & np.r_[True, np.diff(t) > 0]
    if ok.sum() < 3:
        return {"error": f"only {int(ok.sum())} scans have a pose"}
    z = np.zeros((len(t), 1))
    est = {"p_world_base": np.c_[pose[:, :2], z], "q_world_base": _quat_yaw(pose[:, 2])}
    truth = np.c_[gt[:, :2], z, _quat_yaw(gt[:, 2])]
    scores = trajectory_metrics(t, est, truth, ok)
    scores["scans_scored"] = int(ok.sum())
    return scores


def robot_report(
    spec: online.SlamSpec,
    t: np.ndarray,
    state,
    out,
    final: np.ndarray,
    x: dict,
    i: int,
    true_map=None,
    in_view=None,
) -> dict:
    """Counts and (with ground truth) scores of robot i; `state`/`out` hold that robot's arrays.
    `in_view`: robot i's `truth_in_view` when already computed (it depends on the truth alone)."""
    kinds = np.asarray(state.edge_kind[: int(state.n_edges)])
    mask = np.asarray(state.graph.edge_mask[: int(state.n_edges)], bool)
    rep = {
        "scans": int(len(t)),
        "nodes": int(state.n_nodes),
        "node_capacity": spec.nodes,
        "capacity_reached": bool(state.full),
        "edges": {name: int(((kinds == k) & mask).sum()) for k, name in EDGE_KIND_NAMES.items()},
        "loop_closures": int(state.loops),
        "match_response_mean": float(np.nanmean(out.response)) if np.any(np.isfinite(out.response)) else None,
    }
    if "gt" in x:
        gt, valid = x["gt"][i], np.asarray(x["valid"][i], bool)
        rep["scores"] = {
            "online": _trajectory_scores(t, np.asarray(out.pose), gt, valid),
            "final": _trajectory_scores(t, final, gt, valid),
            "odometry": _trajectory_scores(t, x["odom"][i], gt, valid),
        }
        rep["edge_errors"] = edge_errors(state, out, gt)
    if true_map is not None:
        from dataclasses import asdict

        from jaxquad.metrics import map_scores

        if in_view is None:
            in_view = truth_in_view(x, i, true_map, spec.grid.max_range)
        rep["map_scores"] = asdict(map_scores(to_occupancy_map(spec.grid, state.grid), true_map, in_view))
    return rep


def truth_in_view(x: dict, i: int, true_map, range_max: float):
    """The true map's walls in view of robot i's true laser poses (`jaxquad.metrics.cells_in_view`), or
    None without ground truth."""
    from jaxquad.metrics import cells_in_view

    if "gt" not in x:
        return None
    gt = x["gt"][i][np.asarray(x["valid"][i], bool)]
    T_world_laser = se2(jnp.asarray(gt, jnp.float32)) @ se2(jnp.asarray(x["T_base_laser"], jnp.float32))
    return cells_in_view(true_map, np.asarray(xy_theta(T_world_laser)), x["bearings"], range_max)


def robot_slice(tree, i: int):
    """Robot i's arrays of a fleet pytree."""
    return jax.tree.map(lambda a: a[i], tree)


def write_robot(folder: Path, grid: GridSpec, t: np.ndarray, state, out, final: np.ndarray) -> None:
    """One robot's files into `folder` (which exists)."""
    write_tum(folder / "trajectory.tum", tum_of(t, np.asarray(out.pose)), header="online SLAM pose at each scan")
    write_tum(folder / "trajectory_final.tum", tum_of(t, final), header="SLAM pose at each scan, last optimization")
    save_map(folder / "map.yaml", to_occupancy_map(grid, state.grid))
    write_g2o(folder / "graph.g2o", graph_of(state))


def draw_map_vs_truth(
    path: Path, grid: GridSpec, state, final: np.ndarray, odom: np.ndarray, gt: np.ndarray | None, true_map
) -> None:
    """The SLAM map (left) and the true map (right, with the SLAM's occupied cells in red), with the final
    SLAM, odometry and true trajectories."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from jaxquad.io.atomic import atomic_open
    from jaxquad.metrics import resample_map

    est = to_occupancy_map(grid, state.grid)
    fig, axes = plt.subplots(1, 2, figsize=(13, 6), constrained_layout=True)
    res, ox, oy = true_map.resolution, true_map.origin[0], true_map.origin[1]
    extent = [ox, ox + true_map.grid.shape[1] * res, oy, oy + true_map.grid.shape[0] * res]
    shown = np.where(est.grid < 0, 0.5, 1.0 - est.grid / 100.0)  # unknown grey, free white, occupied black
    axes[0].imshow(
        shown,
        origin="lower",
        cmap="gray",
        vmin=0,
        vmax=1,
        extent=[
            grid.origin_x,
            grid.origin_x + grid.cols * grid.resolution,
            grid.origin_y,
            grid.origin_y + grid.rows * grid.resolution,
        ],
    )
    axes[0].set_title("SLAM map (final poses)")
    overlay = np.ones(true_map.grid.shape + (3,))
    overlay[true_map.grid > 65] = (0.2, 0.2, 0.2)
    overlay[resample_map(est, true_map).grid > 65] = (0.85, 0.1, 0.1)
    axes[1].imshow(overlay, origin="lower", extent=extent)
    axes[1].set_title("true map (grey) and SLAM occupied cells (red)")
    for ax in axes:
        if gt is not None:
            ax.plot(gt[:, 0], gt[:, 1], color="tab:green", lw=1.2, label="truth")
        ax.plot(odom[:, 0], odom[:, 1], color="tab:orange", lw=0.8, label="odometry")
        ax.plot(final[:, 0], final[:, 1], color="tab:blue", lw=0.8, label="SLAM (final)")
        ax.set_xlim(extent[0], extent[1])
        ax.set_ylim(extent[2], extent[3])
        ax.set_aspect("equal")
        ax.set_xlabel("x (m)")
        ax.set_ylabel("y (m)")
    axes[0].legend(loc="upper right", fontsize=8)
    with atomic_open(path, "wb") as f:
        fig.savefig(f, format="png", dpi=90)
    plt.close(fig)
