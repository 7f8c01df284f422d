"""Scores of an estimate against ground truth, for one robot, in NumPy (post-processing).

Contacts: precision, recall and F1 of the per-sample contact flags; touchdown and lift-off
detection delays (ms) by matching every true edge with the nearest estimated edge of the same
kind. Forces: RMSE of the vertical force (N). Leg odometry: end-point drift in % of the
distance travelled, horizontal (x, y) and 3D. Every function takes an optional per-sample
`valid` mask; samples outside it are ignored. Ratios with an empty denominator are 0 and the
counts they come from are returned with them, so no NaN reaches a summary.
"""

from __future__ import annotations

import numpy as np


def _mask(valid, n: int) -> np.ndarray:
    return np.ones(n, bool) if valid is None else np.asarray(valid, bool)


def _ratio(num: float, den: float) -> float:
    return float(num / den) if den > 0 else 0.0


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

    per_foot = [prf(*c) for c in zip(tp, fp, fn)]
    p, r, f1 = prf(tp.sum(), fp.sum(), fn.sum())
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
    true edges count as missed.
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
        out[name] = {
            "mean_ms": float(d.mean()) if d.size else 0.0,
            "median_ms": float(np.median(d)) if d.size else 0.0,
            "mean_abs_ms": float(np.abs(d).mean()) if d.size else 0.0,
            "matched": int(d.size),
            "missed": missed,
        }
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
    per_foot = [float(np.sqrt(s.mean())) if n else 0.0 for s in sq.T]
    return {"rmse_n": float(np.sqrt(sq.mean())) if n else 0.0, "rmse_per_foot_n": per_foot, "samples": n}


def odometry_drift(p_est, p_true, valid=None) -> dict:
    """End-point drift of a trajectory (T, 3) in % of the true distance travelled.

    Both trajectories are taken relative to their first valid sample, so the drift is the
    error accumulated over the run: |(p_est[-1] - p_est[0]) - (p_true[-1] - p_true[0])|
    over the true path length, horizontal (x, y) and 3D.
    """
    est = np.asarray(p_est, float)
    true = np.asarray(p_true, float)
    m = _mask(valid, est.shape[0])
    est, true = est[m], true[m]
    if est.shape[0] < 2:
        return {"horizontal_pct": 0.0, "3d_pct": 0.0, "distance_m": 0.0, "horizontal_distance_m": 0.0}
    err = (est[-1] - est[0]) - (true[-1] - true[0])
    step = np.diff(true, axis=0)
    dist3 = float(np.linalg.norm(step, axis=1).sum())
    dist2 = float(np.linalg.norm(step[:, :2], axis=1).sum())
    return {
        "horizontal_pct": 100.0 * _ratio(np.linalg.norm(err[:2]), dist2),
        "3d_pct": 100.0 * _ratio(np.linalg.norm(err), dist3),
        "distance_m": dist3,
        "horizontal_distance_m": dist2,
    }
