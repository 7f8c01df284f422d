"""CARMEN and `.npz` laser logs: files written here by hand, values checked against what was written."""

import gzip
import math

import numpy as np
import pytest

from jaxquad.io.carmen import (
    LaserLog,
    flaser_bearings,
    in_time_order,
    load_laser_log,
    read_carmen,
    repeated_stamps,
    save_laser_npz,
    scan_clock,
    untie_stamps,
)


def _flaser(ranges, pose, odom, t):
    r = " ".join(f"{x:.3f}" for x in ranges)
    return f"FLASER {len(ranges)} {r} {pose[0]} {pose[1]} {pose[2]} {odom[0]} {odom[1]} {odom[2]} {t} host {t + 0.01}"


def _robotlaser(ranges, remissions, laser, robot, t, start=-1.5, res=0.01, max_range=10.0):
    r = " ".join(str(x) for x in ranges)
    e = " ".join(str(x) for x in remissions)
    fov = res * (len(ranges) - 1)
    head = f"ROBOTLASER1 0 {start} {fov} {res} {max_range} 0.01 0 {len(ranges)} {r} {len(remissions)} {e}"
    poses = " ".join(str(x) for x in (*laser, *robot))
    return f"{head} {poses} 0.1 0.0 0.5 0.3 0.2 {t} host {t + 0.01}"


def _write(tmp_path, lines, name="log.clf"):
    p = tmp_path / name
    p.write_text("\n".join(lines) + "\n")
    return p


def test_flaser_log_with_comments_params_and_odom(tmp_path):
    rng = np.random.default_rng(0)
    ranges = rng.uniform(0.5, 8.0, (3, 181)).round(3)
    lines = ["# a comment", "PARAM robot_front_laser_max 81.9 nohost 0", ""]
    for i in range(3):
        lines.append(f"ODOM {0.1 * i} {0.2 * i} {0.01 * i} 0.3 0.0 0.0 {10.0 + i - 0.5} host 0")
        lines.append(_flaser(ranges[i], (9, 9, 9), (0.1 * i, 0.2 * i, 0.01 * i), 10.0 + i))
        lines.append("SYNC 1 2 3")
        lines.append("TRUEPOS 1 2 3 4 5 6 7 host 8")
    log = read_carmen(_write(tmp_path, lines))
    np.testing.assert_allclose(log.ranges, ranges)
    np.testing.assert_allclose(log.scan_t, [10.0, 11.0, 12.0])
    np.testing.assert_allclose(log.odom_t, [9.5, 10.5, 11.5])
    np.testing.assert_allclose(log.odom_xytheta[2], [0.2, 0.4, 0.02])
    np.testing.assert_allclose(log.scan_odom_xytheta[1], [0.1, 0.2, 0.01])
    # 181 beams over 180 deg: one degree apart, both edges measured.
    np.testing.assert_allclose(np.rad2deg(log.bearings), np.arange(-90.0, 90.5, 1.0), atol=1e-9)
    np.testing.assert_array_equal(log.T_base_laser_xytheta, 0.0)
    assert log.n_scans == 3 and log.gt_xytheta is None


def test_flaser_bearings_even_and_fov_override(tmp_path):
    np.testing.assert_allclose(np.rad2deg(flaser_bearings(180)), np.arange(-90.0, 90.0, 1.0), atol=1e-9)
    np.testing.assert_allclose(np.rad2deg(flaser_bearings(361)), np.arange(-90.0, 90.25, 0.5), atol=1e-9)
    lines = [_flaser(np.ones(240), (0, 0, 0), (0, 0, 0), 1.0)]
    log = read_carmen(_write(tmp_path, lines), flaser_fov_deg=240.0)
    np.testing.assert_allclose(np.rad2deg(log.bearings[[0, 1, -1]]), [-120.0, -119.0, 119.0], atol=1e-9)
    # Without ODOM lines the scans' odometry is the odometry.
    np.testing.assert_array_equal(log.odom_t, log.scan_t)


def test_robotlaser_preferred_offset_remissions_and_max_range(tmp_path, monkeypatch):
    lines = [
        _flaser(np.ones(5), (0, 0, 0), (0, 0, 0), 0.5),  # the same scans as FLASER lines: ignored
        _robotlaser(
            [1.0, 2.0, 10.0, 12.5, 3.0], [0.1, 0.2, 0.3], (1.0, 2.3, math.pi / 2), (1.0, 2.0, math.pi / 2), 1.0
        ),
        _flaser(np.ones(5), (0, 0, 0), (0, 0, 0), 1.5),
        _robotlaser([1.5, 2.5, 3.5, 4.5, 5.5], [], (2.0, 2.3, math.pi / 2), (2.0, 2.0, math.pi / 2), 2.0),
    ]
    log = read_carmen(_write(tmp_path, lines))
    np.testing.assert_allclose(log.scan_t, [1.0, 2.0])
    np.testing.assert_allclose(log.ranges[0], [1.0, 2.0, np.inf, np.inf, 3.0])
    np.testing.assert_allclose(log.bearings, -1.5 + 0.01 * np.arange(5))
    # The laser 0.3 m ahead of a robot facing +y: (0.3, 0, 0) in the base frame.
    np.testing.assert_allclose(log.T_base_laser_xytheta, [0.3, 0.0, 0.0], atol=1e-6)
    np.testing.assert_allclose(log.scan_odom_xytheta[1], [2.0, 2.0, math.pi / 2])
    gz = tmp_path / "log.clf.gz"
    gz.write_bytes(gzip.compress((tmp_path / "log.clf").read_bytes()))
    np.testing.assert_array_equal(load_laser_log(gz).ranges, log.ranges)


def test_stamps_out_of_order_scans_kept_odom_dropped(tmp_path):
    """Scans stay in the file's order with their own stamps; ODOM lines earlier than one before go."""
    lines = [
        "ODOM 0 0 0 0 0 0 1.0 host 1.0",
        "ODOM 0 0 0 0 0 0 1.5 host 1.5",
        _flaser([1.0, 2.0, 3.0], (0, 0, 0), (0.1, 0, 0), 2.0),
        "ODOM 0.1 0 0 0 0 0 0 host 0",  # a corrected log's marker line, stamped 0
        "ODOM 0.2 0 0 0 0 0 1.9 host 1.9",  # later than every ODOM line before it: kept
        _flaser([1.0, 2.0, 3.0], (0, 0, 0), (0.2, 0, 0), 1.95),
        "ODOM 0.3 0 0 0 0 0 2.5 host 2.5",
    ]
    log = read_carmen(_write(tmp_path, lines))
    np.testing.assert_array_equal(log.scan_t, [2.0, 1.95])
    np.testing.assert_array_equal(log.scan_odom_xytheta[:, 0], [0.1, 0.2])
    np.testing.assert_array_equal(log.odom_t, [1.0, 1.5, 1.9, 2.5])
    # Without ODOM lines the scans' odometry is the stream: the same rule keeps it in order.
    log = read_carmen(_write(tmp_path, [ln for ln in lines if ln.startswith("FLASER")], "scans_only.clf"))
    np.testing.assert_array_equal(log.odom_t, [1.95])


def _untie_reference(t, untimed_dt=1.0):
    """Runs of equal consecutive stamps spread by a plain loop over the runs."""
    runs = []  # [first index, size]
    for i, v in enumerate(t):
        if runs and v == t[runs[-1][0]]:
            runs[-1][1] += 1
        else:
            runs.append([i, 1])
    steps = [
        (t[runs[k + 1][0]] - t[i]) / n if k + 1 < len(runs) and t[runs[k + 1][0]] > t[i] else None
        for k, (i, n) in enumerate(runs)
    ]
    known = [d for d in steps if d is not None]
    fallback = float(np.median(known)) if known else untimed_dt
    out = []
    for (i, n), d in zip(runs, steps):
        out += [t[i] + j * (fallback if d is None else d) for j in range(n)]
    return np.array(out)


def test_repeated_stamps_are_spread_and_untimed_logs_clocked_by_scan():
    # Stamps written with six digits (10,000 s a step) and ones written as zeros, as in public corrected logs.
    t = np.array([1.13486e9] * 4 + [1.13487e9] * 2 + [1.13488e9])
    np.testing.assert_allclose(untie_stamps(t), 1.13486e9 + 1e3 * np.array([0.0, 2.5, 5.0, 7.5, 10.0, 15.0, 20.0]))
    assert repeated_stamps(t) == 4
    np.testing.assert_array_equal(untie_stamps(np.array([3.0, 3.0])), [3.0, 4.0])  # no step known: 1 s
    np.testing.assert_array_equal(untie_stamps(np.arange(5.0)), np.arange(5.0))  # unique stamps as they are
    rng = np.random.default_rng(1)
    for _ in range(30):
        t = np.sort(rng.integers(0, 5, rng.integers(1, 12))).astype(float)
        if rng.random() < 0.3:
            t[rng.integers(0, t.size)] = -1.0  # a stray stamp
        np.testing.assert_allclose(untie_stamps(t), _untie_reference(t))
    # Most stamps repeated: they time nothing, and the clock steps 1 s per scan (the node rule goes by travel).
    np.testing.assert_array_equal(scan_clock(np.zeros(5)), np.arange(5.0))
    np.testing.assert_array_equal(scan_clock(np.array([7.0, 7.0, 7.0, 7.0, 8.0])), 7.0 + np.arange(5.0))
    # A few repeats in a timed log: spread to the next stamp.
    np.testing.assert_array_equal(scan_clock(np.array([0.0, 1.0, 1.0, 2.0, 3.0])), [0.0, 1.0, 1.5, 2.0, 3.0])


def test_one_stray_stamp_is_the_one_out_of_order():
    unix = 1.7e9 + np.arange(6.0)
    cases = [
        ([1.0, 2.0, 3.0], [1.0, 2.0, 3.0]),
        ([1.0, 1e9, 2.0, 3.0], [1.0, 1.0, 2.0, 3.0]),  # one stamp far ahead holds nothing back
        ([5.0, 1.0, 2.0, 3.0], [1.0, 1.0, 2.0, 3.0]),  # one far behind at the start
        ([2.0, 2.0, 1.0], [2.0, 3.0, 3.0]),  # a repeat before no later stamp: 1 s apart (no step to copy)
        (np.r_[0.0, unix[1:]], np.r_[0.0, unix[1:]]),  # a zero stamp before Unix ones is in order
    ]
    for t, clock in cases:
        np.testing.assert_array_equal(scan_clock(np.asarray(t)), clock)
    np.testing.assert_array_equal(in_time_order(np.array([1.0, 3.0, 2.0, 4.0])), [True, False, True, True])
    # Against brute force: the mask is a longest non-decreasing subsequence.
    rng = np.random.default_rng(0)
    for _ in range(50):
        t = rng.integers(0, 6, rng.integers(1, 9)).astype(float)
        keep = in_time_order(t)
        best = max(
            bin(m).count("1")
            for m in range(1 << t.size)
            if np.all(np.diff(t[[i for i in range(t.size) if m >> i & 1]]) >= 0)
        )
        assert keep.sum() == best and np.all(np.diff(t[keep]) >= 0)


@pytest.mark.parametrize(
    "bad,message",
    [
        ("FLASER 3 1.0 2.0", ":3: FLASER line has 4 fields, expected 14"),
        ("FLASER x 1.0", ":3: num_readings must be a non-negative integer, got 'x'"),
        (_flaser([1.0, 2.0, 3.0], (0, 0, 0), (0, 0, 0), 5.0).replace("2.000", "two"), ":3: could not convert"),
        (_flaser([1.0, 2.0], (0, 0, 0), (0, 0, 0), 5.0), ":3: FLASER scan has 2 beams"),
        ("ODOM 1 2 3", ":3: ODOM line has 4 fields, expected 8"),
        ("ROBOTLASER1 0 -1.5 3.0 0.01 10 0.01 0 2 1.0 2.0 5 0.1", ":3: ROBOTLASER1 line has 13 fields, expected 31"),
        ("1.0 2.0 3.0", ":3: not a CARMEN message (first field '1.0')"),
    ],
)
def test_malformed_lines_name_file_and_line(tmp_path, bad, message):
    lines = ["# header", _flaser([1.0, 2.0, 3.0], (0, 0, 0), (0, 0, 0), 1.0), bad]
    path = _write(tmp_path, lines)
    with pytest.raises(ValueError) as err:
        read_carmen(path)
    text = str(err.value)
    assert text.startswith(str(path)) and message in text and "\n" not in text


def test_no_scans_and_missing_file(tmp_path):
    with pytest.raises(ValueError, match="no FLASER or ROBOTLASER1 scans"):
        read_carmen(_write(tmp_path, ["# only a comment", "ODOM 0 0 0 0 0 0 1.0 host 1.0"]))
    with pytest.raises(FileNotFoundError, match="nope.clf"):
        read_carmen(tmp_path / "nope.clf")


def _log(S=4, B=6, K=9):
    rng = np.random.default_rng(1)
    return LaserLog(
        scan_t=np.arange(S) * 0.1,
        ranges=rng.uniform(0.2, 5.0, (S, B)),
        bearings=np.linspace(-1.0, 1.0, B),
        odom_t=np.arange(K) * 0.05,
        odom_xytheta=rng.normal(size=(K, 3)),
        gt_xytheta=rng.normal(size=(S, 3)),
    )


def test_npz_round_trip_and_errors(tmp_path):
    log = _log()
    path = save_laser_npz(tmp_path / "laser.npz", log)
    back = load_laser_log(path)
    for k in ("scan_t", "ranges", "bearings", "odom_t", "odom_xytheta", "gt_xytheta", "T_base_laser_xytheta"):
        np.testing.assert_array_equal(getattr(back, k), getattr(log, k))
    assert back.scan_odom_xytheta is None
    arrays = {k: getattr(log, k) for k in ("scan_t", "ranges", "bearings", "odom_t", "odom_xytheta")}
    cases = {
        "missing key 'odom_t'": {k: v for k, v in arrays.items() if k != "odom_t"},
        "key 'ranges' has shape (4, 5), expected (4, 6)": {**arrays, "ranges": arrays["ranges"][:, :5]},
        "key 'odom_xytheta' has non-finite values": {**arrays, "odom_xytheta": np.full((9, 3), np.nan)},
        "key 'odom_t' is not non-decreasing": {**arrays, "odom_t": arrays["odom_t"][::-1].copy()},
    }
    for message, content in cases.items():
        bad = tmp_path / "bad.npz"
        np.savez(bad, **content)
        with pytest.raises(ValueError) as err:
            load_laser_log(bad)
        assert str(err.value) == f"{bad}: {message}"
