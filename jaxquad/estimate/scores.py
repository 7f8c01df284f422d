"""Scores of an estimate against ground truth, for one robot, in NumPy (post-processing), and
their fleet aggregates.

Contacts: precision, recall and F1 of the per-sample contact flags; touchdown and lift-off
detection delays (ms) by matching every true edge with the nearest estimated edge of the same
kind. Forces: RMSE of the vertical force (N). Leg odometry (`odometry_scores`): KITTI segment
drift (% and deg/m over 2/5/10 m of true path, `jaxquad.metrics.segment_drift`), the end-point
drift (`odometry_drift`) and the vertical error; the path-length ratio at a resolution that the
per-sample velocity noise does not lengthen (`path_ratio`). Every function takes an optional per-sample
`valid` mask; samples outside it are ignored.

A figure with nothing to average (no matched edge, no sample, no segment, no distance) is NaN,
never 0, and comes with the count that says so; write summaries with `jaxquad.io.to_json`
(NaN -> null). Contact precision/recall/F1 keep the usual convention of 0 for an empty
denominator, with the counts beside them. Fleet figures pool events or weight by counts and say
how many robots and events they average (`aggregate_delays`, `fleet_mean`).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np


def _mask(valid, n: int) -> np.ndarray:
    return np.ones(n, bool) if valid is None else np.asarray(valid, bool)


def _ratio(num: float, den: float) -> float:
    return float(num / den) if den > 0 else 0.0


def _nan_ratio(num: float, den: float) -> float:
    return float(num / den) if den > 0 else float("nan")


def contact_scores(contact_est, contact_true, valid=None) -> dict:
    """Precision/recall/F1 of boolean (T, F) contact flags, per foot and over all feet."""
    est = np.asarray(contact_est, bool)
    true = np.asarray(contact_true, bool)
    m = _mask(valid, est.shape[0])[:, None]
    tp = (est & true & m).sum(0)
    fp = (est & ~true & m).sum(0)
    fn = (~est & true & m).sum(0)

    def prf(tp, fp, fn):
        p, r = _ratio(tp, tp + fp), _ratio(tp, tp + fn)
        return p, r, _ratio(2 * p * r, p + r)

    per_foot = [prf(int(a), int(b), int(c)) for a, b, c in zip(tp, fp, fn)]
    p, r, f1 = prf(int(tp.sum()), int(fp.sum()), int(fn.sum()))
    return {
        "precision": p,
        "recall": r,
        "f1": f1,
        "precision_per_foot": [x[0] for x in per_foot],
        "recall_per_foot": [x[1] for x in per_foot],
        "f1_per_foot": [x[2] for x in per_foot],
        "true_positives": int(tp.sum()),
        "false_positives": int(fp.sum()),
        "false_negatives": int(fn.sum()),
    }


def _edges(flags: np.ndarray, rising: bool) -> np.ndarray:
    """Indices k >= 1 where flags goes False -> True (rising) or True -> False."""
    prev, cur = flags[:-1], flags[1:]
    return np.flatnonzero(cur & ~prev if rising else prev & ~cur) + 1


def detection_delays(t, contact_est, contact_true, valid=None, max_delay_s: float = 0.1) -> dict:
    """Touchdown and lift-off delays (ms): t(estimated edge) - t(true edge), per matched event.

    Each true edge (of a foot, inside `valid`) is matched to the nearest estimated edge of the
    same kind on that foot within max_delay_s; negative delays mean early detection. Unmatched
    true edges count as missed. With no matched edge the delays are NaN and n_matched is 0.
    """
    t = np.asarray(t, float)
    est = np.asarray(contact_est, bool)
    true = np.asarray(contact_true, bool)
    m = _mask(valid, t.shape[0])
    out = {}
    for name, rising in (("touchdown", True), ("liftoff", False)):
        delays, missed = [], 0
        for f in range(true.shape[1]):
            t_true = _edges(true[:, f], rising)
            t_true = t_true[m[t_true]]
            t_est = t[_edges(est[:, f], rising)]
            for k in t_true:
                if t_est.size == 0:
                    missed += 1
                    continue
                d = t_est - t[k]
                j = np.argmin(np.abs(d))
                if abs(d[j]) <= max_delay_s:
                    delays.append(1e3 * d[j])
                else:
                    missed += 1
        d = np.asarray(delays)
        nan = float("nan")
        out[name] = {
            "mean_ms": float(d.mean()) if d.size else nan,
            "median_ms": float(np.median(d)) if d.size else nan,
            "mean_abs_ms": float(np.abs(d).mean()) if d.size else nan,
            "n_matched": int(d.size),
            "n_missed": missed,
        }
    return out


def _pooled(rows: Sequence[dict], key: str, n_events: int) -> float:
    return float(sum(r[key] * r["n_matched"] for r in rows) / n_events) if n_events else float("nan")


def aggregate_delays(per_robot: Sequence[dict]) -> dict:
    """Fleet delays from per-robot `detection_delays` results: mean_ms and mean_abs_ms pooled over
    every matched event of every robot (each robot weighted by its n_matched; robots without a
    match contribute nothing), NaN when no robot matched any. Per kind: mean_ms, mean_abs_ms,
    n_events (matched events averaged), n_missed, n_robots (robots given), n_robots_matched (robots
    with at least one match). Medians do not pool and are left out."""
    out = {}
    for kind in ("touchdown", "liftoff"):
        rows = [r[kind] for r in per_robot]
        hit = [r for r in rows if r["n_matched"] > 0]
        n_events = sum(r["n_matched"] for r in hit)
        out[kind] = {
            "mean_ms": _pooled(hit, "mean_ms", n_events),
            "mean_abs_ms": _pooled(hit, "mean_abs_ms", n_events),
            "n_events": int(n_events),
            "n_missed": int(sum(r["n_missed"] for r in rows)),
            "n_robots": len(rows),
            "n_robots_matched": len(hit),
        }
    return out


def _lookup(d: dict, path: Sequence[str]):
    for key in path:
        if not isinstance(d, dict) or key not in d:
            return None
        d = d[key]
    return d


def fleet_mean(per_robot: Sequence[dict], path: Sequence[str], weight: Sequence[str] | None = None) -> dict:
    """Mean over robots of the score at key `path` of each per-robot dict (e.g. ("drift", "drift_pct",
    "mean")), skipping robots where it is missing or not finite. With `weight` (a key path to a count,
    e.g. ("drift", "drift_pct", "n_segments")) robots are weighted by it, which pools the events when
    the score is a per-robot mean. Returns mean (NaN when nothing is averaged), n_robots (robots
    averaged), n_skipped, and with a weight, weight_sum."""
    vals, weights = [], []
    for r in per_robot:
        v = _lookup(r, path)
        w = 1.0 if weight is None else _lookup(r, weight)
        if v is None or w is None or not np.isfinite(v) or not np.isfinite(w) or (weight is not None and w <= 0):
            continue
        vals.append(float(v))
        weights.append(float(w))
    total = sum(weights)
    out = {
        "mean": sum(v * w for v, w in zip(vals, weights)) / total if total > 0 else float("nan"),
        "n_robots": len(vals),
        "n_skipped": len(per_robot) - len(vals),
    }
    if weight is not None:
        out["weight_sum"] = total
    return out


def force_rmse(force_z_est, force_z_true, valid=None, max_force_n: float | None = None) -> dict:
    """RMSE (N) of vertical foot forces (T, F), per foot and over all feet.

    With max_force_n the truth is clipped to [0, max_force_n] first, the range an estimate clipped
    there can reach (impact spikes of a simulator then do not dominate the score)."""
    est = np.asarray(force_z_est, float)
    true = np.asarray(force_z_true, float)
    if max_force_n is not None:
        true = np.clip(true, 0.0, max_force_n)
    m = _mask(valid, est.shape[0])
    sq = (est[m] - true[m]) ** 2
    n = sq.shape[0]
    nan = float("nan")
    per_foot = [float(np.sqrt(s.mean())) if n else nan for s in sq.T]
    return {"rmse_n": float(np.sqrt(sq.mean())) if n else nan, "rmse_per_foot_n": per_foot, "samples": n}


def odometry_drift(p_est, p_true, valid=None) -> dict:
    """End-point drift of a trajectory (T, 3): the end point's error over the true distance travelled,
    in %, horizontal (x, y) and 3D.

    Both trajectories are taken relative to their first valid sample, so the figure is
    |(p_est[-1] - p_est[0]) - (p_true[-1] - p_true[0])| over the true path length. On a loop the
    truth ends near its start, so an estimate that never moves scores about as well as one that
    walks: read it beside the segment drift of `odometry_scores`. NaN with fewer than 2 samples or
    no distance travelled.
    """
    est = np.asarray(p_est, float)
    true = np.asarray(p_true, float)
    m = _mask(valid, est.shape[0])
    est, true = est[m], true[m]
    if est.shape[0] < 2:
        nan = float("nan")
        return {
            "endpoint_drift_horizontal_pct": nan,
            "endpoint_drift_3d_pct": nan,
            "distance_m": 0.0,
            "horizontal_distance_m": 0.0,
        }
    err = (est[-1] - est[0]) - (true[-1] - true[0])
    step = np.diff(true, axis=0)
    dist3 = float(np.linalg.norm(step, axis=1).sum())
    dist2 = float(np.linalg.norm(step[:, :2], axis=1).sum())
    return {
        "endpoint_drift_horizontal_pct": 100.0 * _nan_ratio(np.linalg.norm(err[:2]), dist2),
        "endpoint_drift_3d_pct": 100.0 * _nan_ratio(np.linalg.norm(err), dist3),
        "distance_m": dist3,
        "horizontal_distance_m": dist2,
    }


def path_ratio(t, p_est, p_true, valid=None, window_s: float = 1.0) -> dict:
    """Horizontal path length of the estimate over the truth's (T, 3) at two samplings.

    path_ratio: both trajectories taken every `window_s` seconds (the first valid sample at or after
    each multiple, and the last), the scale of the estimate. path_ratio_raw: every sample. A
    per-sample velocity error e that averages out within a window adds length without moving the
    robot (E|v + e| > |v|: about sigma^2 / (2 |v|^2) of the path for a cross-track error of standard
    deviation sigma), so the raw ratio of a densely sampled, unbiased estimate exceeds 1. NaN without
    a true distance.
    """
    t = np.asarray(t, float)
    est = np.asarray(p_est, float)
    true = np.asarray(p_true, float)
    m = _mask(valid, est.shape[0])
    t, est, true = t[m], est[m, :2], true[m, :2]
    length = lambda p: float(np.linalg.norm(np.diff(p, axis=0), axis=1).sum())  # noqa: E731
    if t.size < 2:
        return {"path_ratio": float("nan"), "path_ratio_raw": float("nan")}
    k = np.floor((t - t[0]) / window_s)
    pick = np.flatnonzero(np.diff(k, prepend=-1.0) > 0)
    pick = np.append(pick, t.size - 1) if pick[-1] != t.size - 1 else pick
    return {
        "path_ratio": _nan_ratio(length(est[pick]), length(true[pick])),
        "path_ratio_raw": _nan_ratio(length(est), length(true)),
    }


def z_error(p_est, p_true, valid=None) -> dict:
    """Vertical error of the base (m), estimate minus truth, in the world frame both share:
    z_error_final_m at the last valid sample (signed; negative = below the truth) and z_error_rms_m
    over the valid samples. NaN without a valid sample."""
    est = np.asarray(p_est, float)
    true = np.asarray(p_true, float)
    m = _mask(valid, est.shape[0])
    dz = est[m, 2] - true[m, 2]
    if dz.size == 0:
        return {"z_error_final_m": float("nan"), "z_error_rms_m": float("nan")}
    return {"z_error_final_m": float(dz[-1]), "z_error_rms_m": float(np.sqrt(np.mean(dz * dz)))}


def odometry_scores(
    p_est, q_est_wxyz, pose_true, valid=None, lengths_m: Sequence[float] = (2.0, 5.0, 10.0), step: int = 10
) -> dict:
    """Leg-odometry scores of one robot against its true pose (T, 7: x y z qw qx qy qz).

    drift_pct / drift_deg_per_m: KITTI segment drift over the valid samples (see
    `jaxquad.metrics.segment_drift`: mean over every segment of every length in lengths_m, starts
    every `step` samples, with per_length values and the segment counts; NaN with 0 segments when
    the path is shorter than every length). Beside it the end-point figures of `odometry_drift` and
    the vertical error of `z_error`.
    """
    from jaxquad.metrics import evaluate_drift

    p_est = np.asarray(p_est, float)
    q_est = np.asarray(q_est_wxyz, float)
    true = np.asarray(pose_true, float)
    m = _mask(valid, p_est.shape[0])
    xyzw = [1, 2, 3, 0]
    drift = evaluate_drift(true[m, :3], true[m][:, 3:7][:, xyzw], p_est[m], q_est[m][:, xyzw], lengths_m, step)
    return {**drift.to_dict(), **odometry_drift(p_est, true[:, :3], m), **z_error(p_est, true[:, :3], m)}
