"""Scores against small cases computed by hand (the arithmetic is in the comments)."""

import json

import numpy as np
from scipy.spatial.transform import Rotation

from jaxquad.estimate import scores
from jaxquad.io import to_json


def test_contact_scores_by_hand():
    true = np.array([[1, 0], [1, 0], [0, 1], [0, 1], [1, 1]], bool)
    est = np.array([[1, 0], [0, 0], [0, 1], [1, 1], [1, 0]], bool)
    s = scores.contact_scores(est, true)
    # foot 0: tp 2 (rows 0, 4), fp 1 (row 3), fn 1 (row 1) -> p 2/3, r 2/3
    # foot 1: tp 2 (rows 2, 3), fp 0, fn 1 (row 4)        -> p 1, r 2/3, f1 0.8
    np.testing.assert_allclose(s["precision_per_foot"], [2 / 3, 1.0])
    np.testing.assert_allclose(s["recall_per_foot"], [2 / 3, 2 / 3])
    np.testing.assert_allclose(s["f1_per_foot"], [2 / 3, 0.8])
    # all feet: tp 4, fp 1, fn 2 -> p 0.8, r 2/3, f1 = 2 * 0.8 * 2/3 / (0.8 + 2/3) = 8/11
    assert (s["true_positives"], s["false_positives"], s["false_negatives"]) == (4, 1, 2)
    np.testing.assert_allclose([s["precision"], s["recall"], s["f1"]], [0.8, 2 / 3, 8 / 11])
    # Masking rows 3 and 4 leaves foot 0: tp 1, fn 1; foot 1: tp 1
    m = scores.contact_scores(est, true, valid=np.array([1, 1, 1, 0, 0], bool))
    np.testing.assert_allclose([m["precision"], m["recall"]], [1.0, 2 / 3])


def test_contact_scores_empty_is_zero_not_nan():
    z = np.zeros((4, 4), bool)
    s = scores.contact_scores(z, z)
    assert s["precision"] == 0.0 and s["f1"] == 0.0


def test_detection_delays_by_hand():
    t = np.arange(12) * 0.01  # 10 ms samples
    true = np.zeros((12, 1), bool)
    est = np.zeros((12, 1), bool)
    true[2:6, 0] = True  # touchdown at k 2 (20 ms), lift-off at k 6 (60 ms)
    est[4:7, 0] = True  # touchdown at 40 ms (+20), lift-off at 70 ms (+10)
    true[9:, 0] = True  # touchdown at 90 ms, never detected -> missed
    d = scores.detection_delays(t, est, true, max_delay_s=0.03)
    assert d["touchdown"]["n_matched"] == 1 and d["touchdown"]["n_missed"] == 1
    np.testing.assert_allclose(d["touchdown"]["mean_ms"], 20.0, atol=1e-9)
    np.testing.assert_allclose(d["liftoff"]["mean_ms"], 10.0, atol=1e-9)
    # An early detection is a negative delay; nearest estimated edge wins.
    est2 = np.zeros((12, 1), bool)
    est2[1:6, 0] = True
    d2 = scores.detection_delays(t, est2, true, max_delay_s=0.03)
    np.testing.assert_allclose(d2["touchdown"]["mean_ms"], -10.0, atol=1e-9)
    np.testing.assert_allclose(d2["liftoff"]["mean_ms"], 0.0, atol=1e-9)


def test_force_rmse_by_hand():
    est = np.array([[10.0, 0.0], [20.0, 5.0], [np.nan, 0.0]])
    true = np.array([[13.0, 0.0], [16.0, 0.0], [0.0, 0.0]])
    r = scores.force_rmse(est, true, valid=np.array([1, 1, 0], bool))
    # foot 0: errors -3, 4 -> sqrt(12.5); foot 1: 0, 5 -> sqrt(12.5); all: sqrt((9+16+0+25)/4)
    np.testing.assert_allclose(r["rmse_per_foot_n"], [np.sqrt(12.5)] * 2)
    np.testing.assert_allclose(r["rmse_n"], np.sqrt(12.5))
    # Truth clipped to [0, 15]: foot 0 errors -3, 5 -> sqrt(17); foot 1 unchanged.
    c = scores.force_rmse(est, true, valid=np.array([1, 1, 0], bool), max_force_n=15.0)
    np.testing.assert_allclose(c["rmse_per_foot_n"], [np.sqrt(17.0), np.sqrt(12.5)])


def test_odometry_drift_by_hand():
    # True path: 3 m along x, then 4 m along y (7 m travelled horizontally), 1 m up on the way.
    true = np.array([[0, 0, 0], [3, 0, 0], [3, 4, 1.0]])
    est = np.array([[5, 5, 0], [8, 5, 0], [8.7, 9, 1.0]])  # ends 0.7 m off in x
    d = scores.odometry_drift(est, true)
    np.testing.assert_allclose(d["horizontal_distance_m"], 7.0)
    np.testing.assert_allclose(d["distance_m"], 3 + np.sqrt(17))
    np.testing.assert_allclose(d["endpoint_drift_horizontal_pct"], 10.0)
    np.testing.assert_allclose(d["endpoint_drift_3d_pct"], 100 * 0.7 / (3 + np.sqrt(17)))
    short = scores.odometry_drift(est[:1], true[:1])
    assert np.isnan(short["endpoint_drift_3d_pct"]) and short["distance_m"] == 0.0


def test_no_matched_edge_is_nan_not_zero():
    t = np.arange(12) * 0.01
    true = np.zeros((12, 1), bool)
    true[3:8, 0] = True  # one touchdown (30 ms), one lift-off (80 ms)
    never = scores.detection_delays(t, np.zeros((12, 1), bool), true)
    for kind in ("touchdown", "liftoff"):
        row = never[kind]
        assert row["n_matched"] == 0 and row["n_missed"] == 1
        assert np.isnan(row["mean_ms"]) and np.isnan(row["median_ms"]) and np.isnan(row["mean_abs_ms"])


def _delays(mean_ms, n_matched, n_missed=0):
    row = {
        "mean_ms": mean_ms,
        "mean_abs_ms": abs(mean_ms),
        "median_ms": mean_ms,
        "n_matched": n_matched,
        "n_missed": n_missed,
    }
    return {"touchdown": row, "liftoff": dict(row)}


def test_aggregate_delays_weights_by_events_and_skips_robots_without_one():
    # Robot 0: 3 events of mean +10 ms; robot 1: 1 event of -20 ms; robot 2: none (NaN), 2 missed.
    rows = [_delays(10.0, 3), _delays(-20.0, 1), _delays(float("nan"), 0, 2)]
    agg = scores.aggregate_delays(rows)["touchdown"]
    # Pooled: (3 * 10 - 20) / 4 = 2.5 ms, not the robot mean (10 - 20) / 2 = -5 nor a NaN.
    np.testing.assert_allclose(agg["mean_ms"], 2.5)
    np.testing.assert_allclose(agg["mean_abs_ms"], (3 * 10 + 20) / 4)
    assert (agg["n_events"], agg["n_missed"], agg["n_robots"], agg["n_robots_matched"]) == (4, 2, 3, 2)
    none = scores.aggregate_delays([_delays(float("nan"), 0, 5)])["liftoff"]
    assert np.isnan(none["mean_ms"]) and none["n_events"] == 0 and none["n_robots"] == 1


def test_aggregate_delays_equals_pooled_events():
    """Per-robot results of real edges pooled by aggregate_delays = one mean over every event."""
    t = np.arange(40) * 0.01
    rng = np.random.default_rng(0)
    true = rng.random((3, 40, 2)) < 0.5
    est = np.roll(true, 1, axis=1) & (rng.random((3, 40, 2)) < 0.9)
    rows = [scores.detection_delays(t, est[i], true[i], max_delay_s=0.02) for i in range(3)]
    events = []  # every matched touchdown delay, by a direct loop
    for i in range(3):
        for f in range(2):
            t_true = [k for k in range(1, 40) if true[i, k, f] and not true[i, k - 1, f]]
            t_est = [k for k in range(1, 40) if est[i, k, f] and not est[i, k - 1, f]]
            for k in t_true:
                if t_est:
                    j = min(t_est, key=lambda e: abs(t[e] - t[k]))  # the earlier edge on a tie
                    if abs(t[j] - t[k]) <= 0.02:
                        events.append(1e3 * (t[j] - t[k]))
    agg = scores.aggregate_delays(rows)["touchdown"]
    assert agg["n_events"] == len(events) > 0
    np.testing.assert_allclose(agg["mean_ms"], np.mean(events), atol=1e-9)


def test_fleet_mean_counts_robots_and_weights():
    rows = [
        {"drift": {"pct": 2.0, "n": 10}},
        {"drift": {"pct": 4.0, "n": 30}},
        {"drift": {"pct": float("nan"), "n": 0}},
        {"other": 1},
    ]
    m = scores.fleet_mean(rows, ("drift", "pct"))
    assert m == {"mean": 3.0, "n_robots": 2, "n_skipped": 2}
    w = scores.fleet_mean(rows, ("drift", "pct"), weight=("drift", "n"))
    np.testing.assert_allclose(w["mean"], (2 * 10 + 4 * 30) / 40)
    assert (w["n_robots"], w["n_skipped"], w["weight_sum"]) == (2, 2, 40.0)
    assert np.isnan(scores.fleet_mean(rows[2:], ("drift", "pct"))["mean"])


def test_force_rmse_without_samples_is_nan():
    r = scores.force_rmse(np.ones((3, 2)), np.ones((3, 2)), valid=np.zeros(3, bool))
    assert r["samples"] == 0 and np.isnan(r["rmse_n"]) and all(np.isnan(r["rmse_per_foot_n"]))


def test_z_error_closed_form():
    # Truth at 0.3 m; the estimate sinks linearly to 0.3 - 0.4 m: dz_k = -0.4 k / (n - 1).
    n = 101
    true = np.zeros((n, 3))
    true[:, 2] = 0.3
    est = true.copy()
    est[:, 2] -= 0.4 * np.arange(n) / (n - 1)
    z = scores.z_error(est, true)
    np.testing.assert_allclose(z["z_error_final_m"], -0.4)
    # RMS of 0.4 k / (n - 1), k = 0..n-1: 0.4 sqrt(sum k^2 / n) / (n - 1) = 0.4 sqrt((n - 1)(2n - 1) / 6) / (n - 1)
    np.testing.assert_allclose(z["z_error_rms_m"], 0.4 * np.sqrt((n - 1) * (2 * n - 1) / 6) / (n - 1))
    valid = np.arange(n) <= 50  # the last valid sample is k = 50: dz = -0.2
    np.testing.assert_allclose(scores.z_error(est, true, valid)["z_error_final_m"], -0.2)
    assert np.isnan(scores.z_error(est, true, np.zeros(n, bool))["z_error_rms_m"])


def _loop_pose(n, laps=1.0):
    """A 6 m-radius horizontal circle walked `laps` times, heading along it,
    as (n, 7) x y z qw qx qy qz."""
    s = np.linspace(0.0, 2 * np.pi * laps, n)
    p = np.stack([6 * np.cos(s), 6 * np.sin(s), np.full(n, 0.3)], 1)
    q_xyzw = Rotation.from_euler("z", s[:, None] + np.pi / 2).as_quat()
    return np.concatenate([p, q_xyzw[:, [3, 0, 1, 2]]], 1)


def test_standing_still_on_a_loop():
    """The end-point figure rewards an estimate that never moves on a loop; segment drift does not."""
    pose = _loop_pose(2000)
    still = np.tile(pose[:1], (2000, 1))
    s = scores.odometry_scores(still[:, :3], still[:, 3:], pose)
    assert s["endpoint_drift_horizontal_pct"] < 1e-6  # the loop closes: the end point is the start
    t, r = s["drift_pct"], s["drift_deg_per_m"]
    # Poses dtheta apart on a circle of radius 6 m: path steps of h = 12 sin(dtheta / 2); a segment of
    # length L spans the first k with k h > L, so its error is the chord 12 sin(k dtheta / 2) and the
    # truth's turn k dtheta (the standing estimate keeps its heading).
    dtheta = 2 * np.pi / 1999
    h = 12 * np.sin(dtheta / 2)
    k = [int(np.floor(x / h)) + 1 for x in (2.0, 5.0, 10.0)]
    np.testing.assert_allclose(
        t["per_length"], [100 * 12 * np.sin(kk * dtheta / 2) / x for kk, x in zip(k, (2, 5, 10))], rtol=1e-6
    )
    np.testing.assert_allclose(
        r["per_length"], [np.degrees(kk * dtheta) / x for kk, x in zip(k, (2, 5, 10))], rtol=1e-6
    )
    assert 85.0 < t["mean"] < 101.0 and t["n_segments"] == sum(t["n_segments_per_length"]) > 0


def test_odometry_scores_perfect_and_too_short():
    pose = _loop_pose(500)
    s = scores.odometry_scores(pose[:, :3], pose[:, 3:], pose)
    np.testing.assert_allclose(
        [s["drift_pct"]["mean"], s["drift_deg_per_m"]["mean"], s["z_error_rms_m"]], 0.0, atol=1e-9
    )
    short = scores.odometry_scores(pose[:20, :3], pose[:20, 3:], pose[:20])  # 1.4 m of path
    assert short["drift_pct"]["n_segments"] == 0 and np.isnan(short["drift_pct"]["mean"])
    text = to_json(short)
    assert json.loads(text)["drift_pct"]["mean"] is None  # strict JSON: NaN written as null


def test_path_ratio_raw_is_lengthened_by_white_velocity_noise_and_windowed_is_not():
    from scipy.stats import rice

    # A straight walk at v along x sampled every dt; the estimate integrates v plus white noise of
    # standard deviation sigma per axis. Each raw step's length is Rice(v / sigma, scale sigma) dt,
    # so the raw ratio tends to rice.mean / v (> 1: about 1 + sigma^2 / (2 v^2)); a 1 s window holds
    # 250 samples, its displacement noise sigma dt sqrt(250) is 0.3 % of v * 1 s: ratio 1.
    rng = np.random.default_rng(5)
    v, sigma, dt, n = 0.5, 0.1, 0.004, 50_000
    t = dt * np.arange(n)
    true = np.stack([v * t, np.zeros(n), np.full(n, 0.3)], 1)
    step = np.column_stack([np.full(n - 1, v), np.zeros(n - 1)]) + sigma * rng.standard_normal((n - 1, 2))
    est = true.copy()
    est[1:, :2] = np.cumsum(step * dt, 0)
    r = scores.path_ratio(t, est, true)
    np.testing.assert_allclose(r["path_ratio_raw"], rice.mean(v / sigma, scale=sigma) / v, rtol=2e-3)
    assert r["path_ratio_raw"] > 1.015
    np.testing.assert_allclose(r["path_ratio"], 1.0, atol=2e-3)
    # A 2 % scale error shows at both samplings; no valid sample gives NaN.
    scaled = true.copy()
    scaled[:, :2] *= 1.02
    np.testing.assert_allclose(scores.path_ratio(t, scaled, true)["path_ratio"], 1.02, rtol=1e-9)
    assert np.isnan(scores.path_ratio(t, est, true, np.zeros(n, bool))["path_ratio"])
