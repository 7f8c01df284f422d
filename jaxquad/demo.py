"""`jaxquad demo`: the whole project end to end on a CPU in a few minutes.

Stages: simulate a small fleet (MJX, depth camera, noisy sensors), estimate contacts and
leg-inertial odometry with contacts from the mixed-mode momentum observer and from ground truth,
score both (jaxquad.estimate.run: contact precision/recall/F1, touchdown/lift-off delays, force
RMSE, drift, ATE/RPE through jaxquad.metrics), slice laser scans from every depth frame (baseline
and IMU-stabilized bands) and score them against the ground-truth map, then draw the pictures.

Output folder (built in a temporary sibling folder and renamed into place when complete, so a
stopped run never leaves a half-written report):
  summary.json                       configuration, machine, wall times, mean scores per contact
                                     source and for the scans, list of files
  sim/fleet.npz, sim/gt_*.tum,       the fleet log, ground-truth TUM per robot, the world map(s)
  sim/map_*.yaml/.pgm
  estimate_mixed/, estimate_truth/   per robot TUM + npz, summary.json with per-robot scores
  trajectories.png                   xy paths per robot against ground truth, over the map
  contacts.png                       one robot, a few seconds, every foot: stance and forces
  scan_frame.png                     one depth frame with both bands; the two scans on the map
Scans: the 5 px band of the paper's simulation, ranges 0-10 m, roll and pitch from the attitude of
the mixed-contact run (jaxquad.estimate.scans); each is placed on the map with the ground-truth
camera pose and scored by the share of rays ending near an occupied cell.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import shutil
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

SOURCES = ("mixed", "truth")  # contact sources the demo compares
BAND_HEIGHT = 5  # px, the paper's simulation band
RANGE_MIN, RANGE_MAX = 0.0, 10.0  # m, the paper's simulation scan limits
HIT_TOLERANCE = 0.2  # m (4 map cells): a scan end point this close to an occupied cell agrees with the map


def add_arguments(parser: argparse.ArgumentParser) -> None:
    from jaxquad.sim.cli import parse_resolution

    parser.add_argument("--out", default="jaxquad-demo", help="report folder (replaced if it holds an earlier demo)")
    parser.add_argument("--robots", type=int, default=4, help="fleet size (default 4)")
    parser.add_argument("--seconds", type=float, default=20.0, help="simulated time per robot (default 20)")
    parser.add_argument("--robot", default="go2", choices=["go2", "badger"])
    parser.add_argument("--world", default="house", choices=["house", "warehouse"])
    parser.add_argument("--style", default="aggressive", choices=["calm", "aggressive"])
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--resolution", type=parse_resolution, default=(160, 120), help="depth image WxH (default 160x120)")


# ------------------------------------------------------------------------------------- scans


def scan_map_hits(points_world: np.ndarray, occ, tolerance: float = HIT_TOLERANCE) -> np.ndarray:
    """Per end point (..., 2) world x y (m): True where the map cell holding it has an occupied cell
    (occupancy >= 50) whose centre is within `tolerance` m of its own centre (map yaw 0). Points off
    the map or not finite are False."""
    from scipy.ndimage import distance_transform_edt

    occupied = occ.grid >= 50
    pts = np.asarray(points_world, np.float64)
    if not occupied.any():
        return np.zeros(pts.shape[:-1], bool)
    # Distance (m) from every cell centre to the nearest occupied cell centre.
    dist = distance_transform_edt(~occupied) * occ.resolution
    finite = np.all(np.isfinite(pts), axis=-1)
    rc = occ.world_to_cell(np.where(finite[..., None], pts, 0.0))
    rows, cols = occ.grid.shape
    inside = finite & (rc[..., 0] >= 0) & (rc[..., 0] < rows) & (rc[..., 1] >= 0) & (rc[..., 1] < cols)
    rc = np.where(inside[..., None], rc, 0)
    return inside & (dist[rc[..., 0], rc[..., 1]] <= tolerance + 1e-9)


def _frame_samples(t: np.ndarray, depth_t: np.ndarray) -> np.ndarray:
    """Index of the latest log sample at or before each depth frame (the sample whose attitude
    jaxquad.estimate.scans uses for that frame)."""
    return np.clip(np.searchsorted(t, depth_t, side="right") - 1, 0, t.size - 1)


def _camera_pose_2d(gt_pose: np.ndarray, T_base_camera: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """World x y (m) of the camera and the base's heading (rad) from gt_pose (..., 7) [p, wxyz]."""
    import jax.numpy as jnp

    from jaxquad.kernels.lie import SO3, yaw_of

    q = jnp.asarray(gt_pose[..., 3:], jnp.float32)
    xy = gt_pose[..., :2] + np.asarray(SO3(q).apply(jnp.asarray(T_base_camera[:3, 3], jnp.float32)))[..., :2]
    return xy, np.asarray(yaw_of(q))


def load_scans(folder: Path, n: int) -> dict[str, np.ndarray]:
    """The scans `run_estimate` wrote for robots 0..n-1 (`robot_<i>_scans.npz`), stacked:
    "stabilized" and "baseline" ranges (N, F, W) m, "roll" and "pitch" (N, F) rad, "bearings" (W,)."""
    files = [np.load(folder / f"robot_{i:03d}_scans.npz") for i in range(n)]
    out = {k: np.stack([f[k] for f in files]) for k in ("roll", "pitch")}
    out["stabilized"] = np.stack([f["ranges_stabilized"] for f in files])
    out["baseline"] = np.stack([f["ranges_baseline"] for f in files])
    out["bearings"] = files[0]["bearings"]
    return out


def score_scans(log: dict, scans: dict, maps: list) -> dict:
    """Agreement of scan end points with the ground-truth map (ground-truth camera pose), per band:
    % of valid rays ending in a cell within HIT_TOLERANCE of an occupied cell (`scan_map_hits`),
    % of rays with no reading,
    over the frames where each robot is valid."""
    k = _frame_samples(np.asarray(log["t"], np.float64), np.asarray(log["depth_t"], np.float64))
    gt = np.asarray(log["gt_pose"], np.float64)[:, k]  # (N, F, 7)
    xy, yaw = _camera_pose_2d(gt, np.asarray(log["T_base_camera"], np.float64))
    valid = np.asarray(log["valid"], bool)[:, k]
    world = np.asarray(log["world_index"]) % len(maps)
    a = yaw[..., None] + scans["bearings"]  # (N, F, W)
    out = {}
    for name in ("baseline", "stabilized"):
        r = scans[name]
        pts = xy[..., None, :] + r[..., None] * np.stack([np.cos(a), np.sin(a)], axis=-1)
        hits = np.stack([scan_map_hits(pts[i], maps[world[i]]) for i in range(r.shape[0])])
        finite = np.isfinite(r) & valid[..., None]
        rays = int((valid[..., None] & np.ones_like(finite)).sum())
        out[name] = {
            "rays": rays,
            "valid_rays": int(finite.sum()),
            "map_agreement_pct": 100.0 * float((hits & finite).sum()) / max(int(finite.sum()), 1),
            "no_reading_pct": 100.0 * float(rays - finite.sum()) / max(rays, 1),
        }
    return out


# ------------------------------------------------------------------------------------- summary

# (label, path into a robot's scores, format) of the mean table.
_TABLE = (
    ("contact F1", ("contacts", "f1"), "{:.3f}"),
    ("precision", ("contacts", "precision"), "{:.3f}"),
    ("recall", ("contacts", "recall"), "{:.3f}"),
    ("touchdown delay ms", ("delays", "touchdown", "mean_ms"), "{:+.1f}"),
    ("lift-off delay ms", ("delays", "liftoff", "mean_ms"), "{:+.1f}"),
    ("force RMSE N", ("force", "rmse_n"), "{:.1f}"),
    ("drift horiz. %", ("drift", "horizontal_pct"), "{:.1f}"),
    ("drift 3D %", ("drift", "3d_pct"), "{:.1f}"),
    ("ATE m", ("trajectory", "ate", "rmse"), "{:.3f}"),
)


def _get(d: dict, path: tuple[str, ...]):
    for key in path:
        if not isinstance(d, dict) or key not in d:
            return None
        d = d[key]
    return d


def mean_scores(robots: list[dict]) -> dict:
    """Mean over robots of every table entry and of the first RPE's RMSE (entries a robot lacks
    are skipped; a key no robot has is absent)."""
    out = {}
    for label, path, _ in _TABLE:
        vals = [v for r in robots if (v := _get(r["scores"], path)) is not None]
        if vals:
            out[label] = float(np.mean(vals))
    rpe = [(k, v["rmse"]) for r in robots for k, v in r["scores"].get("trajectory", {}).items() if k.startswith("rpe_")]
    if rpe:
        out["RPE m"] = float(np.mean([v for _, v in rpe]))
    return out


def format_table(sources: dict[str, dict], scans: dict | None = None) -> str:
    """Plain-text table: one column per contact source, then the scan agreement lines."""
    labels = [lab for lab, _, _ in _TABLE] + ["RPE m"]
    fmt = {lab: f for lab, _, f in _TABLE} | {"RPE m": "{:.3f}"}
    names = list(sources)
    lines = [f"{'':20s}" + "".join(f"{n:>12s}" for n in names)]
    for lab in labels:
        cells = [fmt[lab].format(sources[n][lab]) if lab in sources[n] else "-" for n in names]
        lines.append(f"{lab:20s}" + "".join(f"{c:>12s}" for c in cells))
    if scans:
        lines.append("")
        lines.append(f"{'scan vs map':20s}" + "".join(f"{n:>12s}" for n in scans))
        lines.append(f"{'rays on map %':20s}" + "".join(f"{s['map_agreement_pct']:>12.1f}" for s in scans.values()))
        lines.append(f"{'no reading %':20s}" + "".join(f"{s['no_reading_pct']:>12.1f}" for s in scans.values()))
    return "\n".join(lines)


def machine() -> dict:
    import jax

    return {"node": platform.node(), "platform": platform.platform(), "processor": platform.processor() or platform.machine(),
            "cpu_count": os.cpu_count(), "python": platform.python_version(), "jax": jax.__version__,
            "jax_devices": [str(d) for d in jax.devices()]}  # fmt: skip


# ------------------------------------------------------------------------------------- the run


def _check_out(out: Path) -> None:
    if out.exists() and not out.is_dir():
        raise ValueError(f"--out {out} exists and is not a folder")
    if out.is_dir() and any(out.iterdir()):
        try:
            earlier = json.loads((out / "summary.json").read_text()).get("kind") == "jaxquad demo"
        except (OSError, ValueError):
            earlier = False
        if not earlier:
            raise ValueError(f"--out {out} is a non-empty folder that holds no earlier demo; choose another")


def _replace_dir(tmp: Path, out: Path) -> None:
    """Move the finished folder into place; an earlier demo is renamed away first, then removed."""
    old = None
    if out.exists():
        old = out.with_name(f".{out.name}.old.{os.getpid()}")
        os.replace(out, old)
    os.replace(tmp, out)
    if old is not None:
        shutil.rmtree(old, ignore_errors=True)


def run_demo(
    out, robots: int = 4, seconds: float = 20.0, robot: str = "go2", world: str = "house",
    style: str = "aggressive", seed: int = 0, resolution: tuple[int, int] = (160, 120),
    progress: bool = True, contact_window_s: float = 3.0,
) -> dict:
    """Run every stage and write the report folder `out`; returns the summary dict."""
    from tqdm import tqdm

    from jaxquad.estimate.run import run_estimate
    from jaxquad.io import load_log, load_map
    from jaxquad.sim.cli import simulate
    from jaxquad.sim.fleet import FleetConfig

    if robots < 1:
        raise ValueError(f"--robots must be >= 1, got {robots}")
    if not (seconds > 0 and np.isfinite(seconds)):
        raise ValueError(f"--seconds must be positive, got {seconds}")
    out = Path(out).resolve()
    _check_out(out)
    out.parent.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(dir=out.parent, prefix=f".{out.name}.tmp."))
    wall: dict[str, float] = {}
    t_all = time.perf_counter()
    try:
        # 1. simulate
        t0 = time.perf_counter()
        config = FleetConfig(robot=robot, world=world, n_robots=robots, style=style, seed=seed,
                             depth=True, width=resolution[0], height=resolution[1])  # fmt: skip
        log_path = simulate(config, seconds, tmp / "sim", progress=progress)
        wall["simulate"] = time.perf_counter() - t0

        # 2. estimate and score, per contact source
        summaries = {}
        for source in SOURCES:
            t0 = time.perf_counter()
            bar = tqdm(total=robots, desc=f"estimate ({source} contacts)", unit="robot", disable=not progress)
            try:
                summaries[source] = run_estimate(log_path, tmp / f"estimate_{source}", source,
                                                 progress=lambda done, total: bar.update(done - bar.n),
                                                 band_height=BAND_HEIGHT, range_min=RANGE_MIN, range_max=RANGE_MAX)  # fmt: skip
            finally:
                bar.close()
            wall[f"estimate_{source}"] = time.perf_counter() - t0

        # 3. the scans of every depth frame (sliced by run_estimate with the mixed run's attitude),
        # scored against the ground-truth map
        t0 = time.perf_counter()
        log = load_log(log_path)
        maps = [load_map(p) for p in sorted((tmp / "sim").glob("map_*.yaml"))]
        with tqdm(total=1, desc="scans vs map", unit="fleet", disable=not progress) as bar:
            scans = load_scans(tmp / "estimate_mixed", robots)
            scan_scores = score_scans(log, scans, maps)
            bar.update()
        wall["scans"] = time.perf_counter() - t0

        # 4. pictures
        t0 = time.perf_counter()
        with tqdm(total=3, desc="pictures", unit="png", disable=not progress) as bar:
            _pictures(tmp, log, summaries, scans, maps, contact_window_s)
            bar.update(3)
        wall["pictures"] = time.perf_counter() - t0
        wall["total"] = time.perf_counter() - t_all

        summary = {
            "kind": "jaxquad demo",
            "command": " ".join(["jaxquad"] + sys.argv[1:]) if Path(sys.argv[0]).name == "jaxquad" else None,
            "machine": machine(),
            "config": {"robots": robots, "seconds": seconds, "robot": robot, "world": world, "style": style,
                       "seed": seed, "resolution": list(resolution), "band_height_px": BAND_HEIGHT,
                       "scan_range_m": [RANGE_MIN, RANGE_MAX], "map_hit_tolerance_m": HIT_TOLERANCE},  # fmt: skip
            "fallen": [bool(v) for v in np.asarray(log["fallen"])],
            "wall_s": wall,
            "sources": {s: mean_scores(summaries[s]["robots"]) for s in SOURCES},
            "scans": scan_scores,
            "files": sorted(str(p.relative_to(tmp)) for p in tmp.rglob("*") if p.is_file()) + ["summary.json"],
        }
        text = json.dumps(summary, indent=2)
        (tmp / "summary.json").write_text(text)
        _replace_dir(tmp, out)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    return summary


def _pictures(folder: Path, log: dict, summaries: dict, scans: dict, maps: list, window_s: float) -> None:
    from jaxquad import report
    from jaxquad.robots import load

    t = np.asarray(log["t"], np.float64)
    gt = np.asarray(log["gt_pose"], np.float64)
    n = gt.shape[0]
    world = np.asarray(log["world_index"]) % len(maps)
    fallen = np.asarray(log["fallen"], bool)
    est = {s: [np.load(folder / f"estimate_{s}" / f"robot_{i:03d}.npz") for i in range(n)] for s in SOURCES}

    # Trajectories, over the map of robot 0's world (all robots share it unless --worlds says else).
    titles = []
    for i in range(n):
        parts = [f"robot {i}" + (" (fell)" if fallen[i] else "")]
        for s in SOURCES:
            d = _get(summaries[s]["robots"][i]["scores"], ("drift", "horizontal_pct"))
            if d is not None:
                parts.append(f"{s}: drift {d:.1f}%")
        titles.append(", ".join(parts))
    report.plot_trajectories(
        folder / "trajectories.png",
        [gt[i, :, :2] for i in range(n)],
        {s: [e["p_world_base"][:, :2] for e in est[s]] for s in SOURCES},
        maps[world[0]],
        titles,
    )

    # Contacts: the first robot that did not fall, a window in the middle of the run.
    i = int(np.flatnonzero(~fallen)[0]) if (~fallen).any() else 0
    mid = 0.5 * (t[0] + t[-1])
    sel = (t >= mid - window_s / 2) & (t <= mid + window_s / 2)
    robot = load(str(np.asarray(log["robot"])))
    e = est["mixed"][i]
    report.plot_contacts(
        folder / "contacts.png", t[sel], np.asarray(log["gt_contact"])[i, sel], e["contact"][sel],
        np.asarray(log["gt_force"])[i, sel, :, 2], e["force_z_filtered"][sel], list(robot.foot_names),
        title=f"Foot contacts of robot {i}: ground truth and mixed-mode observer",
    )  # fmt: skip

    # Scan frame: the valid frame of robot i where the two bands disagree most with the map.
    k = _frame_samples(t, np.asarray(log["depth_t"], np.float64))
    ok = np.asarray(log["valid"], bool)[i, k]
    s, b = scans["stabilized"][i], scans["baseline"][i]
    both = np.isfinite(s) & np.isfinite(b)
    # A ray read by one band only counts 1 m; rays read by neither (inf) never enter a subtraction.
    diff = np.sum(np.abs(np.where(both, s, 0.0) - np.where(both, b, 0.0)) + (np.isfinite(s) ^ np.isfinite(b)), axis=1)
    f = int(np.argmax(np.where(ok, diff, -1)))
    xy, yaw = _camera_pose_2d(gt[i, k[f]], np.asarray(log["T_base_camera"], np.float64))
    pts = {s: report.scan_points_world(scans[s][i, f], scans["bearings"], xy, float(yaw)) for s in ("baseline", "stabilized")}
    report.plot_scan_frame(
        folder / "scan_frame.png", np.asarray(log["depth"])[i, f], np.asarray(log["K"], np.float64),
        float(scans["roll"][i, f]), float(scans["pitch"][i, f]), BAND_HEIGHT, pts, maps[world[i]], xy,
        title=f"Robot {i}, depth frame at t = {float(np.asarray(log['depth_t'])[f]):.2f} s",
    )  # fmt: skip


def run(args: argparse.Namespace) -> int:
    summary = run_demo(args.out, args.robots, args.seconds, args.robot, args.world, args.style, args.seed, args.resolution)
    print()
    print(format_table(summary["sources"], summary["scans"]))
    print()
    fell = sum(summary["fallen"])
    times = ", ".join(f"{k} {v:.0f} s" for k, v in summary["wall_s"].items())
    print(f"{len(summary['fallen'])} robots, {fell} fell; wall time: {times}")
    print(f"wrote {Path(args.out).resolve()}: summary.json, trajectories.png, contacts.png, scan_frame.png, sim/, estimate_*/")
    return 0
