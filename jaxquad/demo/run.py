"""`jaxquad demo`: the whole project end to end on a CPU in about a minute.

Stages, all in memory: simulate a small fleet (`jaxquad.sim.rollout`: MJX, depth camera, noisy
sensors), estimate contacts and leg-inertial odometry per contact source and score them
(`jaxquad.estimate.estimate_and_score`: contact precision/recall/F1, touchdown/lift-off delays,
force RMSE, drift, ATE/RPE through jaxquad.metrics), score the laser scans sliced from every depth
frame (baseline and IMU-stabilized bands) against the ground-truth map, draw the pictures; then
write everything.

Output folder (built in a temporary sibling folder and renamed into place when complete, so a
stopped run never leaves a half-written report):
  summary.json                       configuration (the fleet's, every pipeline parameter and
                                     choice per contact source), machine, wall times, mean scores
                                     per contact source and for the scans, list of files
  sim/                               the fleet log, ground-truth TUM per robot, the world map(s)
  estimate_<source>/                 per robot TUM + npz (+ scans), summary.json with per-robot scores
                                     and the parameters used
  trajectories.png                   xy paths per robot against ground truth, over the map
  heights.png                        one robot's base height over time, truth and estimates
  contacts.png                       one robot, a few seconds, every foot: stance and forces
  scan_frame.png                     one depth frame with both bands; the two scans on the map
Contact sources: "tuned" (the mixed-mode observer with grid-tuned numbers shipped for the robot
and gait, when there are some: `demo/tuned/`), "paper" (the same observer with the paper's
published numbers, as the comparison) and "truth" (ground-truth contacts, the odometry's bound).
Scans: the 5 px band of the paper's simulation, ranges 0-10 m, roll and pitch from the attitude of
the first contact source's run; each is placed on the map with the ground-truth camera pose and
scored by the share of rays ending near an occupied cell.
"""

from __future__ import annotations

import dataclasses
import sys
import time
from pathlib import Path

import numpy as np

from jaxquad.demo import pictures
from jaxquad.demo.scans import HIT_TOLERANCE, score_scans, stack_scans
from jaxquad.demo.summary import machine, mean_scores

TUNED = Path(__file__).with_name("tuned")  # grid-tuned observer numbers per robot and gait: <robot>_<style>.yaml
BAND_HEIGHT = 5  # px, the paper's simulation band
RANGE_MIN, RANGE_MAX = 0.0, 10.0  # m, the paper's simulation scan limits
SUMMARY_KIND = "jaxquad demo"


def contact_sources(robot: str, style: str) -> dict[str, tuple[str, Path | None]]:
    """Contact sources the demo compares: name -> (contact source, observer params file or None)."""
    tuned = TUNED / f"{robot}_{style}.yaml"
    sources = {"tuned": ("mixed", tuned)} if tuned.is_file() else {}
    return sources | {"paper": ("mixed", None), "truth": ("truth", None)}


def run_demo(
    out,
    robots: int = 4,
    seconds: float = 20.0,
    robot: str = "go2",
    world: str = "house",
    style: str = "aggressive",
    seed: int = 0,
    resolution: tuple[int, int] = (160, 120),
    progress: bool = True,
    contact_window_s: float = 3.0,
) -> dict:
    """Run every stage and write the report folder `out`; returns the summary dict."""
    from tqdm import tqdm

    from jaxquad.estimate.run import estimate_and_score, load_params, write_run
    from jaxquad.io import atomic_dir, check_output_dir, json_ready, write_json
    from jaxquad.sim import FleetConfig, rollout
    from jaxquad.sim.cli import write_fleet

    if robots < 1:
        raise ValueError(f"--robots must be >= 1, got {robots}")
    if not (seconds > 0 and np.isfinite(seconds)):
        raise ValueError(f"--seconds must be positive, got {seconds}")
    out = Path(out).resolve()
    check_output_dir(out, kind=SUMMARY_KIND)
    config = FleetConfig(
        robot=robot,
        world=world,
        n_robots=robots,
        style=style,
        seed=seed,
        depth=True,
        width=resolution[0],
        height=resolution[1],
    )
    wall: dict[str, float] = {}
    t_all = t0 = time.perf_counter()
    log = rollout(config, seconds, progress)
    wall["simulate"] = time.perf_counter() - t0

    sources = contact_sources(robot, style)
    runs = {}
    for source, (contacts, params_file) in sources.items():
        t0 = time.perf_counter()
        params = load_params(params_file, len(log["gt_contact"][0, 0]), contacts)
        with tqdm(total=robots, desc=f"estimate ({source} contacts)", unit="robot", disable=not progress) as bar:
            runs[source] = estimate_and_score(
                log,
                contacts,
                params,
                lambda done, total: bar.update(done - bar.n),
                BAND_HEIGHT,
                RANGE_MIN,
                RANGE_MAX,
                source="simulated fleet",
            )
        if params_file is not None:
            runs[source].summary["params_file"] = str(params_file)
        wall[f"estimate_{source}"] = time.perf_counter() - t0

    t0 = time.perf_counter()
    maps = log.maps()
    scans = stack_scans(runs[next(iter(sources))].scans)
    scan_scores = score_scans(log, scans, maps)
    wall["scans"] = time.perf_counter() - t0

    with atomic_dir(out) as tmp:
        t0 = time.perf_counter()
        (tmp / "sim").mkdir()
        write_fleet(log, tmp / "sim")
        for source, run in runs.items():
            (tmp / f"estimate_{source}").mkdir()
            write_run(run, tmp / f"estimate_{source}")
        pictures.draw(tmp, log, runs, tuple(sources), scans, maps, contact_window_s, BAND_HEIGHT)
        wall["write"] = time.perf_counter() - t0
        wall["total"] = time.perf_counter() - t_all
        summary = {
            "kind": SUMMARY_KIND,
            "command": " ".join(["jaxquad"] + sys.argv[1:]) if Path(sys.argv[0]).name == "jaxquad" else None,
            "machine": machine(),
            "config": {
                "robots": robots,
                "seconds": seconds,
                "robot": robot,
                "world": world,
                "style": style,
                "seed": seed,
                "resolution": list(resolution),
                "band_height_px": BAND_HEIGHT,
                "scan_range_m": [RANGE_MIN, RANGE_MAX],
                "map_hit_tolerance_m": HIT_TOLERANCE,
                "contact_window_s": contact_window_s,
            },
            "fleet_config": dataclasses.asdict(config),
            "fallen": [bool(v) for v in np.asarray(log["fallen"])],
            "wall_s": wall,
            "sources": {s: mean_scores(runs[s].summary["robots"]) for s in sources},
            "source_params": {s: runs[s].summary.get("observer_params", "ground-truth contacts") for s in sources},
            # Every number of each source's pipeline (PipelineParams) and its static choices (PipelineConfig).
            "params": {s: runs[s].summary["params"] for s in sources},
            "pipeline_config": {s: runs[s].summary["config"] for s in sources},
            "scans": scan_scores,
            "files": sorted(str(p.relative_to(tmp)) for p in tmp.rglob("*") if p.is_file()) + ["summary.json"],
        }
        write_json(tmp / "summary.json", summary)
    return json_ready(summary)  # as written: undefined figures (no matched event) are None
