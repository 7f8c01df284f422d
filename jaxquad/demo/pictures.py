"""The demo's pictures: trajectories over the map, a contact timeline, one depth frame with its scans."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from jaxquad.demo.scans import camera_pose_2d, frame_samples
from jaxquad.demo.summary import _get


def draw(
    folder: Path, log, runs: dict, sources: tuple[str, ...], scans: dict, maps: list, window_s: float, band_height: int
) -> None:
    """trajectories.png, contacts.png and scan_frame.png into `folder`."""
    from jaxquad import report
    from jaxquad.robots import load

    t = np.asarray(log["t"], np.float64)
    gt = np.asarray(log["gt_pose"], np.float64)
    n = gt.shape[0]
    world = np.asarray(log["world_index"]) % len(maps)
    fallen = np.asarray(log["fallen"], bool)
    est = {s: runs[s].estimate for s in sources}

    # Trajectories, over the map of robot 0's world (all robots share it unless --worlds says else).
    titles = []
    for i in range(n):
        parts = [f"robot {i}" + (" (fell)" if fallen[i] else "")]
        for s in sources:
            d = _get(runs[s].summary["robots"][i]["scores"], ("drift", "drift_pct", "mean"))
            if d is not None and np.isfinite(d):
                parts.append(f"{s}: segment drift {d:.1f}%")
        titles.append(", ".join(parts))
    report.plot_trajectories(
        folder / "trajectories.png",
        [gt[i, :, :2] for i in range(n)],
        {s: [est[s].p_world_base[i, :, :2] for i in range(n)] for s in sources},
        maps[world[0]],
        titles,
    )

    # Contacts and height: the first robot that did not fall; contacts in a window mid-run.
    i = int(np.flatnonzero(~fallen)[0]) if (~fallen).any() else 0
    report.plot_heights(
        folder / "heights.png",
        t,
        gt[i, :, 2],
        {s: est[s].p_world_base[i, :, 2] for s in sources},
        title=f"Base height of robot {i}: ground truth and leg-inertial odometry",
    )
    mid = 0.5 * (t[0] + t[-1])
    sel = (t >= mid - window_s / 2) & (t <= mid + window_s / 2)
    robot = load(str(np.asarray(log["robot"])))
    e = est[sources[0]]
    report.plot_contacts(
        folder / "contacts.png",
        t[sel],
        np.asarray(log["gt_contact"])[i, sel],
        e.contact[i, sel],
        np.asarray(log["gt_force"])[i, sel, :, 2],
        e.force_z_filtered[i, sel],
        list(robot.foot_names),
        title=f"Foot contacts of robot {i}: ground truth and the mixed-mode observer ({sources[0]} numbers)",
    )

    # Scan frame: the valid frame of robot i where the two bands disagree most with the map.
    k = frame_samples(t, np.asarray(log["depth_t"], np.float64))
    ok = np.asarray(log["valid"], bool)[i, k]
    s, b = scans["stabilized"][i], scans["baseline"][i]
    both = np.isfinite(s) & np.isfinite(b)
    # A ray read by one band only counts 1 m; rays read by neither (inf) never enter a subtraction.
    diff = np.sum(np.abs(np.where(both, s, 0.0) - np.where(both, b, 0.0)) + (np.isfinite(s) ^ np.isfinite(b)), axis=1)
    f = int(np.argmax(np.where(ok, diff, -1)))
    xy, yaw = camera_pose_2d(gt[i, k[f]], np.asarray(log["T_base_camera"], np.float64))
    pts = {
        s: report.scan_points_world(scans[s][i, f], scans["bearings"], xy, float(yaw))
        for s in ("baseline", "stabilized")
    }
    report.plot_scan_frame(
        folder / "scan_frame.png",
        np.asarray(log["depth"])[i, f],
        np.asarray(log["K"], np.float64),
        float(scans["roll"][i, f]),
        float(scans["pitch"][i, f]),
        band_height,
        pts,
        maps[world[i]],
        xy,
        title=f"Robot {i}, depth frame at t = {float(np.asarray(log['depth_t'])[f]):.2f} s",
    )
