"""The SLAM's error over time in exploration runs: lost runs against the others, beside the heading drift of
the simulated IMU's reported yaw.

    python experiments/exploration.py --runs 100 --robots go2 --worlds warehouse --variants full --seconds 240 \
        --traces traces/
    python experiments/exploration_errors.py traces/go2_warehouse_full.npz --out errors.png

Two panels: the SLAM position error (m) and the absolute heading error (deg) of every run against time,
the runs that ended `lost` in red, the others grey, with the median over the runs still active; the
heading panel adds the median absolute value of the reported yaw's random walk (`sim.sensors`'
`yaw_walk`: 0.6745 x yaw_walk x sqrt(t)), which the leg odometry's heading follows. It prints, as JSON,
the medians at each whole minute and per lost run its end time, its largest change of error from one sample to
the next (`sample_s` apart: a control tick, or `exploration.py --trace-every`'s period), its final heading
error and a cause (`lost_causes` counts them): `jump` where the error rose by more than `JUMP_M` from one sample to
the next, else `heading` where the final heading error is `HEADING_DEG` or more, else `drift`. Per collided run
(the world's boxes rebuilt from the traces' world and seed) it prints the box nearest the footprint's outline at the
last sample (a sample can precede the collision by up to `sample_s`: the distance need not be 0), the control mode
then, whether the run was walking to a view goal and its SLAM error, and `collisions_by_box` counts them (with the
final maps in the traces, also what the run's map called the true map's occupied cells within `NEAR_M` of the
footprint: `near_cells`, summed over the runs in `collisions_near_cells`); with
the loop candidates in the traces (`exploration.py`'s `loop_events`), per lost run the accepted closure that changed
its SLAM error most, the last accepted closure that carried its error from under `LOST_M` (the loop's lost limit) to
`LOST_M` or more, and how many of its candidates were refused; and `loops`: how many candidates were accepted and
refused, the accepted ones that moved a run's error by more than `JUMP_M` (their count, runs, and chi-squares), per
band of chi-square (`CHI2_BANDS`) the accepted closures that raised and lowered a run's error by more than `MOVED_M`,
their mean change and how many carried an error across `LOST_M` (`by_chi2`: which closures a stricter
`loop_consistency_chi2` would have refused, and what they did), and how many lost runs a closure carried across
`LOST_M` (`lost_across_by_closure`); with the final maps in the
traces (`exploration.py --traces` keeps them since `6a3bdcf`), their scores against the true map per outcome
(`jaxquad.metrics.map_scores`: IoU median and 10-90 %, precision and recall medians) and, over the runs that ended
`explored`, the correlation of the map IoU with the run's median SLAM position error.
"""

from __future__ import annotations

import argparse
import json
import sys
from collections import Counter
from pathlib import Path

import numpy as np

JUMP_M = 0.3  # m: an accepted closure that moves the SLAM position error by more than this
LOST_M = 0.5  # m: the exploration loop's `lost_error` (jaxquad.explore.fleet)
MOVED_M = 0.05  # m: a closure that raises or lowers the SLAM position error by more than this moved it
# the accepted closures' chi-square bands (3 dof: the 50, 90, 95 and 99 % points); the last runs to the gate the
# traces ran with (exploration's full variant: 7.81 since its 100-run Badger cells; slam.yaml's 16.27 before)
CHI2_BANDS = (0.0, 2.37, 6.25, 7.81, 11.34)
# deg: a lost run's final heading error from which the heading counts as its cause: walls seen at the 4 m map range
# then land 0.2 m astray, beyond what scan matching against the run's own map pulls back.
HEADING_DEG = 3.0
# m: at a collision, the true map's occupied cells this close to the footprint are the ones it met or was about to
NEAR_M = 0.3


def heading_error_deg(d: dict) -> np.ndarray:
    """(ticks, runs) absolute SLAM heading error (deg)."""
    from jaxquad.kernels.lie import wrap_angle

    return np.degrees(np.abs(np.asarray(wrap_angle(d["pose"][..., 2] - d["true_pose"][..., 2]))))


def load(path: Path) -> dict:
    """A traces file of `exploration.py --traces`; a one-line error for anything else."""
    need = ("t", "error", "active", "outcome", "end_t", "pose", "true_pose")
    try:
        with np.load(path) as z:
            d = {k: z[k] for k in z.files}
    except (OSError, ValueError, TypeError, AttributeError) as e:  # a missing file, not an .npz, a bare .npy
        raise SystemExit(f"exploration_errors: cannot read {path} as an .npz: {e}") from None
    missing = [k for k in need if k not in d]
    if missing:
        raise SystemExit(f"exploration_errors: {path} lacks {', '.join(missing)} (exploration.py --traces writes it)")
    T, N = d["error"].shape if d["error"].ndim == 2 else (-1, -1)
    shapes = {"t": (T,), "active": (T, N), "outcome": (N,), "end_t": (N,), "pose": (T, N, 3), "true_pose": (T, N, 3)}
    bad = [f"{k} {d[k].shape}" for k, shape in shapes.items() if d[k].shape != shape]
    if T < 1 or bad:
        raise SystemExit(
            f"exploration_errors: {path}: error must be (ticks, runs) and the rest agree with it "
            f"(every run's path kept: --traces keeps them all); got error {d['error'].shape}, {', '.join(bad)}"
        )
    return d


def yaw_walk_median(yaw_walk: float, t: np.ndarray, randomize: bool = True) -> np.ndarray:
    """Median over robots of |yaw drift| at times t (rad): the drift is yaw_walk x s x sqrt(t) x N(0, 1), with
    s = 1, or uniform over `sim.fleet.NOISE_SCALE` in a randomized fleet (the median of the mixture, by
    bisection on its distribution function)."""
    from scipy.special import ndtr

    from jaxquad.sim.fleet import NOISE_SCALE

    s = np.linspace(*NOISE_SCALE, 2001) if randomize else np.ones(1)
    lo, hi = 0.0, 10.0
    for _ in range(60):
        m = 0.5 * (lo + hi)
        lo, hi = (m, hi) if np.mean(2 * ndtr(m / s) - 1) < 0.5 else (lo, m)
    return 0.5 * (lo + hi) * yaw_walk * np.sqrt(t)


def summarize(d: dict, yaw_walk: float) -> dict:
    from jaxquad.explore import OUTCOMES

    t, err, active = d["t"], d["error"], d["active"].astype(bool)
    randomize = bool(d.get("randomize", True))
    heading = heading_error_deg(d)
    lost = np.flatnonzero(d["outcome"] == OUTCOMES.index("lost"))
    minutes = []
    tick = float(t[1] - t[0]) if len(t) > 1 else 0.0
    for m in range(1, int((t[-1] + tick) // 60) + 1):  # the samples hold each tick's end time
        k = int(np.searchsorted(t, 60.0 * m + 1e-3 * tick, side="right")) - 1  # the last sample at or before m min
        a = active[k]
        minutes.append({
            "t_s": float(t[k]),
            "active_runs": int(a.sum()),
            "position_error_median_m": float(np.median(err[k, a])) if a.any() else None,
            "heading_error_median_deg": float(np.median(heading[k, a])) if a.any() else None,
            "imu_yaw_walk_median_deg": float(np.degrees(yaw_walk_median(yaw_walk, t[k], randomize))),
        })  # fmt: skip
    runs = []
    for i in lost:
        k = _last_tick(active, i)
        steps = np.diff(err[: k + 1, i])
        rise, final_heading = float(np.max(steps, initial=0.0)), float(heading[k, i])
        runs.append({
            "run": int(i),
            "end_s": float(d["end_t"][i]),
            "largest_tick_change_m": float(np.max(np.abs(steps), initial=0.0)),
            "final_heading_error_deg": final_heading,
            "cause": "jump" if rise > JUMP_M else ("heading" if final_heading >= HEADING_DEG else "drift"),
        })  # fmt: skip
        if "loop_chi2" in d:
            runs[-1]["largest_closure"] = _largest_closure(d, i)
            runs[-1]["closure_across_lost"] = _closure_across_lost(d, i)
            runs[-1]["refused_closures"] = int(np.sum((d["loop_run"] == i) & ~d["loop_accepted"].astype(bool)))
    causes = {c: sum(r["cause"] == c for r in runs) for c in ("jump", "heading", "drift")}
    loops = {}
    if "loop_chi2" in d:
        across = sum(r["closure_across_lost"] is not None for r in runs)
        loops = {"loops": loop_summary(d), "lost_across_by_closure": across}
    return loops | {"runs": int(err.shape[1]), "lost": len(runs), "randomized_noise": randomize, "sample_s": tick,
            "per_minute": minutes, "lost_runs": runs, "lost_causes": causes}  # fmt: skip


def _last_tick(active: np.ndarray, run: int) -> int:
    """The tick a run ended on: its last active one (0 for a run never active)."""
    ticks = np.flatnonzero(active[:, run])
    return int(ticks[-1]) if ticks.size else 0


def collision_summary(d: dict, world, footprint) -> dict:
    """Per collided run, at its last sample: the box of `world` (`sim.worlds.World`) nearest the outline of the
    footprint (`footprint` = its centre and half extents in the base frame, m) at the true pose, that distance (m,
    < 0 inside), the control mode (`loop.MODES`), whether a view goal was being walked to, and the SLAM error; and
    how many collided runs each box has."""
    import jax.numpy as jnp

    from jaxquad.explore.loop import MODES, OUTCOMES
    from jaxquad.kernels.footprint import footprint_outline
    from jaxquad.sim.worlds import box_distances

    outline = np.asarray(footprint_outline(*(jnp.asarray(a, jnp.float32) for a in footprint)), np.float64)  # (6, 2)
    active = d["active"].astype(bool)
    runs = []
    for i in np.flatnonzero(d["outcome"] == OUTCOMES.index("collided")):
        k = _last_tick(active, i)
        x, y, th = (float(v) for v in d["true_pose"][k, i])
        c, s = np.cos(th), np.sin(th)
        xy = np.array([x, y]) + outline @ np.array([[c, s], [-s, c]])  # the outline's points in the world
        dist = box_distances(world, xy).min(axis=0)  # (B,): each box's nearest outline point
        b = int(np.argmin(dist))
        run = {"run": int(i), "end_s": float(d["end_t"][i]), "true_pose": [x, y, th], "box": b,
               "box_distance_m": float(dist[b]), "slam_error_m": float(d["error"][k, i])}  # fmt: skip
        if "mode" in d:
            run["mode"] = MODES[int(d["mode"][k, i])]
        if "viewing" in d:
            run["viewing"] = bool(d["viewing"][k, i])
        if "maps" in d:
            run["near_cells"] = near_cells(d, i, (x, y, th), footprint)
        runs.append(run)
    by_box = Counter(str(r["box"]) for r in runs)
    out = {"collided_runs": runs, "collisions_by_box": dict(by_box.most_common())}
    if "maps" in d:
        out["collisions_near_cells"] = {c: sum(r["near_cells"][c] for r in runs) for c in NEAR_CLASSES}
    return out


NEAR_CLASSES = ("cells", "unknown", "free", "uncertain", "occupied")


def near_cells(d: dict, run: int, pose: tuple[float, float, float], footprint) -> dict:
    """What run `run`'s final map (it ends at the collision) calls the true map's occupied cells within `NEAR_M` of
    the footprint's rectangle (`footprint` = its centre and half extents in the base frame, m) at the true `pose`:
    how many there are and how many the map holds unknown, free, uncertain and occupied (the map format's
    thresholds). Unknown ones are faces no scan had seen, which the controller's footprint checks let it approach."""
    from jaxquad.io.maps import FREE_THRESH, OCCUPIED_THRESH, OccupancyMap
    from jaxquad.sim.worlds import rectangle_distances

    truth = OccupancyMap(d["true_map"], float(d["map_resolution"]), tuple(float(v) for v in d["map_origin"]))
    c, s = np.cos(pose[2]), np.sin(pose[2])
    centre, half = (np.asarray(a, np.float64) for a in footprint)
    centre_world = np.array([pose[0] + c * centre[0] - s * centre[1], pose[1] + s * centre[0] + c * centre[1]])
    dist = rectangle_distances(centre_world[None], half[None], np.array([pose[2]]), truth.cell_centers())[..., 0]
    v = d["maps"][run][(truth.grid > 100 * OCCUPIED_THRESH) & (dist <= NEAR_M)].astype(np.int16)
    free = (v >= 0) & (v < 100 * FREE_THRESH)
    occupied = v > 100 * OCCUPIED_THRESH
    counts = (v.size, (v < 0).sum(), free.sum(), (v >= 0).sum() - free.sum() - occupied.sum(), occupied.sum())
    return {k: int(n) for k, n in zip(NEAR_CLASSES, counts)}


def _closure_change(d: dict) -> np.ndarray:
    """Per loop candidate, the change of its run's SLAM position error across its tick (m)."""
    return d["loop_error_after_m"] - d["loop_error_before_m"]


def _candidate(d: dict, k: int) -> dict:
    """Loop candidate k: its time, chi-square and its run's SLAM position error before and after it."""
    keys = ("t_s", "chi2", "error_before_m", "error_after_m")
    values = (d["loop_t"][k], d["loop_chi2"][k], d["loop_error_before_m"][k], d["loop_error_after_m"][k])
    return {key: float(v) for key, v in zip(keys, values)}


def _largest_closure(d: dict, run: int) -> dict | None:
    """The run's accepted closure that changed its SLAM position error most (None without one)."""
    k = np.flatnonzero((d["loop_run"] == run) & d["loop_accepted"].astype(bool))
    if not k.size:
        return None
    k = k[np.argmax(np.abs(np.nan_to_num(_closure_change(d)[k])))]
    return _candidate(d, k)


def _across_lost(d: dict) -> np.ndarray:
    """The candidates that were accepted and carried their run's SLAM position error from under `LOST_M` to more."""
    before, after = d["loop_error_before_m"], d["loop_error_after_m"]
    return d["loop_accepted"].astype(bool) & (before < LOST_M) & (after >= LOST_M)


def _closure_across_lost(d: dict, run: int) -> dict | None:
    """The run's last accepted closure that carried its SLAM position error from under `LOST_M` to `LOST_M` or more
    (None where none did)."""
    k = np.flatnonzero((d["loop_run"] == run) & _across_lost(d))
    if not k.size:
        return None
    k = k[np.argmax(d["loop_t"][k])]
    return _candidate(d, k)


def loop_summary(d: dict) -> dict:
    """The loop candidates (past the match tests) accepted and refused by the consistency test, and the accepted
    ones that moved their run's SLAM position error by more than `JUMP_M`: count, runs, chi-square median and
    range."""
    accepted = d["loop_accepted"].astype(bool)
    jump = accepted & (np.abs(np.nan_to_num(_closure_change(d))) > JUMP_M)
    chi2 = d["loop_chi2"][jump]
    return {
        "accepted": int(accepted.sum()),
        "refused": int((~accepted).sum()),
        "jumps": int(jump.sum()),
        "jump_runs": sorted({int(r) for r in d["loop_run"][jump]}),
        "jump_chi2": _percentiles(chi2, [0, 50, 100]),
        "accepted_chi2": _percentiles(d["loop_chi2"][accepted & ~jump], [50, 90]),
        "by_chi2": chi2_bands(d),
    }


def chi2_bands(d: dict) -> list[dict]:
    """Per band of `CHI2_BANDS` (from its lower edge, up to the next), the accepted closures: how many, in how many
    runs, how many raised and lowered their run's SLAM position error by more than `MOVED_M`, the mean change (m; the
    closures whose error after is not traced left out) and how many carried an error across `LOST_M`."""
    accepted, across = d["loop_accepted"].astype(bool), _across_lost(d)
    change = _closure_change(d)
    bands = []
    for lo, hi in zip(CHI2_BANDS, CHI2_BANDS[1:] + (np.inf,)):
        k = accepted & (d["loop_chi2"] >= lo) & (d["loop_chi2"] < hi)
        moved = change[k][np.isfinite(change[k])]
        bands.append({
            "chi2_from": lo,
            "chi2_to": None if np.isinf(hi) else hi,
            "accepted": int(k.sum()),
            "runs": len(set(d["loop_run"][k].tolist())),
            "raised": int(np.sum(moved > MOVED_M)),
            "lowered": int(np.sum(moved < -MOVED_M)),
            "mean_change_m": float(moved.mean()) if moved.size else None,
            "carried_across_lost": int(np.sum(across & k)),
        })  # fmt: skip
    return bands


def _percentiles(x: np.ndarray, q: list[float]) -> list[float | None]:
    """Percentiles `q` of the finite values of `x` (None where there are none: a map with no occupied cell has no
    precision)."""
    x = x[np.isfinite(x)]
    return [float(v) for v in np.percentile(x, q)] if x.size else [None] * len(q)


def map_summary(d: dict) -> dict:
    """The final maps' scores by outcome, and how the explored runs' map IoU follows their median SLAM error."""
    from jaxquad.explore import OUTCOMES
    from jaxquad.io.maps import OccupancyMap
    from jaxquad.metrics import map_scores

    truth = OccupancyMap(d["true_map"], float(d["map_resolution"]), tuple(float(v) for v in d["map_origin"]))
    scores = [map_scores(OccupancyMap(m, truth.resolution, truth.origin), truth) for m in d["maps"]]
    iou, precision, recall = (np.array([getattr(s, k) for s in scores]) for k in ("iou", "precision", "recall"))
    active = d["active"].astype(bool)
    err = np.array([np.median(d["error"][active[:, i], i]) if active[:, i].any() else np.nan for i in range(len(iou))])
    per_outcome = {}
    for code, name in enumerate(OUTCOMES):
        k = d["outcome"] == code
        if k.any():
            p10, p50, p90 = _percentiles(iou[k], [10, 50, 90])
            per_outcome[name] = {"runs": int(k.sum()), "iou_median": p50, "iou_p10": p10, "iou_p90": p90,
                                 "precision_median": _percentiles(precision[k], [50])[0],
                                 "recall_median": _percentiles(recall[k], [50])[0]}  # fmt: skip
    done = (d["outcome"] == OUTCOMES.index("explored")) & np.isfinite(iou) & np.isfinite(err)
    r = float(np.corrcoef(iou[done], err[done])[0, 1]) if done.sum() > 2 else None
    return {"per_outcome": per_outcome, "explored_iou_vs_median_error_correlation": r}


def plot(d: dict, yaw_walk: float, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from jaxquad.explore import OUTCOMES
    from jaxquad.io.atomic import atomic_open

    t, active = d["t"], d["active"].astype(bool)
    err = np.where(active, d["error"], np.nan)
    heading = np.where(active, heading_error_deg(d), np.nan)
    lost = d["outcome"] == OUTCOMES.index("lost")
    fig, axes = plt.subplots(1, 2, figsize=(11, 3.8), constrained_layout=True)
    for ax, y, label in ((axes[0], err, "SLAM position error (m)"), (axes[1], heading, "SLAM heading error (deg)")):
        ax.plot(t / 60, y[:, ~lost], color="0.75", lw=0.5)
        ax.plot(t / 60, y[:, lost], color="tab:red", lw=0.7)
        with np.errstate(all="ignore"):
            ax.plot(t / 60, np.nanmedian(y, axis=1), color="k", lw=2, label="median of the active runs")
        ax.set_xlabel("time (min)")
        ax.set_ylabel(label)
        ax.grid(alpha=0.3)
    axes[0].axhline(0.5, color="tab:red", ls=":", lw=1, label="lost above this for 2 s")
    walk = yaw_walk_median(yaw_walk, t, bool(d.get("randomize", True)))
    axes[1].plot(t / 60, np.degrees(walk), color="tab:blue", lw=2, ls="--",
                 label="median of the IMU yaw's random walk")  # fmt: skip
    axes[1].set_ylim(0, min(15.0, float(np.nanmax(heading)) + 1))
    for ax in axes:
        ax.plot([], [], color="tab:red", lw=0.7, label=f"lost runs ({int(lost.sum())})")
        ax.plot([], [], color="0.75", lw=0.5, label=f"other runs ({int((~lost).sum())})")
        ax.legend(fontsize=7, loc="upper left")
    title = " ".join(str(d[k]) for k in ("robot", "world", "variant") if k in d)
    fig.suptitle(f"exploration {title}".strip(), fontsize=9)
    with atomic_open(path, "wb") as f:
        fig.savefig(f, format="png", dpi=80)
    plt.close(fig)


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("traces", type=Path, help="a cell's traces, from exploration.py --traces")
    p.add_argument("--out", type=Path, default=None, help="the figure (.png; default: none)")
    args = p.parse_args()
    if args.out is not None:
        from jaxquad.io.atomic import check_output_file

        try:
            check_output_file(args.out, "--out")
        except (ValueError, OSError) as e:
            p.error(str(e))
    from jaxquad.sim.sensors import SensorNoise

    yaw_walk = float(SensorNoise.default().yaw_walk)
    d = load(args.traces)
    summary = summarize(d, yaw_walk)
    if all(k in d for k in ("robot", "world", "seed")):
        from jaxquad.nav.missions import footprint
        from jaxquad.robots import load as load_robot
        from jaxquad.sim.worlds import make_world

        try:
            world = make_world(str(d["world"]), int(d["seed"]))
            fp = footprint(load_robot(str(d["robot"])))
        except (ValueError, OSError) as e:
            raise SystemExit(f"exploration_errors: {args.traces}: {e}") from None
        summary |= collision_summary(d, world, fp)
    if "maps" in d:
        summary["maps"] = map_summary(d)
    print(json.dumps(summary, indent=1))
    if args.out is not None:
        plot(d, yaw_walk, args.out)
        print(f"figure: {args.out}", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
