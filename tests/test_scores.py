"""Scores against small cases computed by hand (the arithmetic is in the comments)."""

import numpy as np

from jaxquad.estimate import scores



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
    assert d["touchdown"]["matched"] == 1 and d["touchdown"]["missed"] == 1
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
    np.testing.assert_allclose(d["horizontal_pct"], 10.0)
    np.testing.assert_allclose(d["3d_pct"], 100 * 0.7 / (3 + np.sqrt(17)))
