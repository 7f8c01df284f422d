"""The demo's scans scored against the ground-truth map, and the camera pose they are placed with."""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np

from jaxquad.estimate.scans import frame_samples
from jaxquad.metrics import scan_map_hits

HIT_TOLERANCE = 0.2  # m (4 map cells): a scan end point this close to an occupied cell agrees with the map


def camera_pose_2d(gt_pose: np.ndarray, T_base_camera: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """World x y (m) of the camera and the base's heading (rad) from gt_pose (..., 7) [p, wxyz]."""
    import jax.numpy as jnp

    from jaxquad.kernels.lie import SO3, yaw_of

    q = jnp.asarray(gt_pose[..., 3:], jnp.float32)
    xy = gt_pose[..., :2] + np.asarray(SO3(q).apply(jnp.asarray(T_base_camera[:3, 3], jnp.float32)))[..., :2]
    return xy, np.asarray(yaw_of(q))


def stack_scans(per_robot: list) -> dict[str, np.ndarray]:
    """Per-robot `LogScans` stacked: "stabilized" and "baseline" ranges (N, F, W) m, "roll" and
    "pitch" (N, F) rad, "bearings" (W,)."""
    out = {k: np.stack([np.asarray(getattr(s, k)) for s in per_robot]) for k in ("roll", "pitch")}
    out["stabilized"] = np.stack([np.asarray(s.ranges_stabilized) for s in per_robot])
    out["baseline"] = np.stack([np.asarray(s.ranges_baseline) for s in per_robot])
    out["bearings"] = np.asarray(per_robot[0].bearings)
    return out


def score_scans(log: Mapping, scans: dict, maps: list) -> dict:
    """Agreement of scan end points with the ground-truth map (ground-truth camera pose), per band:
    % of valid rays ending in a cell within HIT_TOLERANCE of an occupied cell (`scan_map_hits`),
    % of rays with no reading,
    over the frames where each robot is valid."""
    k = frame_samples(np.asarray(log["t"], np.float64), np.asarray(log["depth_t"], np.float64))
    gt = np.asarray(log["gt_pose"], np.float64)[:, k]  # (N, F, 7)
    xy, yaw = camera_pose_2d(gt, np.asarray(log["T_base_camera"], np.float64))
    valid = np.asarray(log["valid"], bool)[:, k]
    world = np.asarray(log["world_index"]) % len(maps)
    a = yaw[..., None] + scans["bearings"]  # (N, F, W)
    out = {}
    for name in ("baseline", "stabilized"):
        r = scans[name]
        pts = xy[..., None, :] + r[..., None] * np.stack([np.cos(a), np.sin(a)], axis=-1)
        hits = np.stack([scan_map_hits(pts[i], maps[world[i]], HIT_TOLERANCE) for i in range(r.shape[0])])
        finite = np.isfinite(r) & valid[..., None]
        rays = int((valid[..., None] & np.ones_like(finite)).sum())
        out[name] = {
            "rays": rays,
            "valid_rays": int(finite.sum()),
            "map_agreement_pct": 100.0 * float((hits & finite).sum()) / max(int(finite.sum()), 1),
            "no_reading_pct": 100.0 * float(rays - finite.sum()) / max(rays, 1),
        }
    return out
