"""Online SLAM (`jaxquad.slam.online`) on scans cast by the independent NumPy caster: a drifting loop
closed and corrected, a corrupted scan overruled by leg odometry, fleets equal to single robots, and
`jaxquad slam` end to end on generated CARMEN and laser-npz logs."""

from __future__ import annotations

import functools
import json

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest
from _laser2d import box, cast
from scipy import stats

from jaxquad.cli import main
from jaxquad.io import load_map, read_tum
from jaxquad.io.carmen import LaserLog, save_laser_npz
from jaxquad.kernels.scan_grid import MatchParams, MatchSpec, cells_for_range
from jaxquad.slam import (
    SlamParams,
    SlamSpec,
    final_poses,
    grid_spec,
    load_params,
    map_from_scans,
    redraw_maps,
    run_fleet,
)
from jaxquad.slam.online import ODOMETRY_STEP_FLOOR, _match_odometry_chi2
from jaxquad.slam.report import tum_of
from jaxquad.slam.run import nodes_needed
from jaxquad.slam.state import EDGE_ODOMETRY

# A 2 m wide corridor around a block, with features on its walls so that places differ.
WORLD = np.concatenate(
    [
        box(-5, -4, 5, 4),
        box(-3, -2, 3, 2),
        box(-1.0, -4.0, -0.6, -3.6),
        box(1.5, -2.3, 2.3, -2.0),
        box(4.6, 0.5, 5.0, 1.3),
        box(-5.0, -1.0, -4.7, -0.2),
        box(0.0, 3.7, 0.8, 4.0),
    ]
)
BEARINGS = np.linspace(-np.pi, np.pi, 120, endpoint=False)
DT = 0.1  # s between scans
GRID = grid_spec((-6.0, -5.0, 6.0, 5.0), 0.05, 6.0)
MATCH = MatchSpec(cells=cells_for_range(4.0, 0.01, 50))


def _spec(lo: str) -> SlamSpec:
    return SlamSpec(grid=GRID, nodes=96, buffer=20, match=MATCH, lo_constraints=lo)


def _path(corners, spacing):
    out = []
    for a, b in zip(corners[:-1], corners[1:]):
        d = np.subtract(b, a)
        length = np.linalg.norm(d)
        for s in np.arange(0.0, length, spacing):
            out.append([*(a + d * s / length), np.arctan2(d[1], d[0])])
    return np.array(out)


def _relative(a, b):
    c, s = np.cos(a[..., 2]), np.sin(a[..., 2])
    d = b[..., :2] - a[..., :2]
    yaw = (b[..., 2] - a[..., 2] + np.pi) % (2 * np.pi) - np.pi
    return np.stack([c * d[..., 0] + s * d[..., 1], -s * d[..., 0] + c * d[..., 1], yaw], -1)


def _integrate(start, steps):
    out = [np.asarray(start, float)]
    for dx, dy, dth in steps:
        x, y, th = out[-1]
        out.append(np.array([x + np.cos(th) * dx - np.sin(th) * dy, y + np.sin(th) * dx + np.cos(th) * dy, th + dth]))
    return np.array(out)


def _drifted(truth, scale, yaw_rate_bias):
    """Odometry integrated from the true steps with a scale error and a heading-rate bias (rad/s)."""
    steps = _relative(truth[:-1], truth[1:]) * np.array([1 + scale, 1 + scale, 1.0]) + [0, 0, yaw_rate_bias * DT]
    return _integrate(truth[0], steps)


def _inputs(truth, odom, lo, ranges):
    S = len(truth)
    step = _relative(lo[:-1], lo[1:]) / DT
    twist = np.vstack([step, step[-1:]])
    return {
        "t": np.arange(S) * DT,
        "odom": odom[None],
        "lo_pose": lo[None],
        "ranges": ranges[None],
        "bearings": BEARINGS,
        "T_base_laser": np.zeros(3),
        "valid": np.ones((1, S), bool),
        "lo_twist": twist[None],
        "lo_twist_cov": np.broadcast_to(np.diag([0.01, 0.01, 4e-4]), (1, S, 3, 3)),
        "lo_valid": np.ones((1, S), bool),
        "gt": truth[None],
    }


LOOP = _path([(0.0, -3.0), (4.0, -3.0), (4.0, 3.0), (-4.0, 3.0), (-4.0, -3.0), (2.0, -3.0)], 0.1)
LOOP_RANGES = np.stack([cast(WORLD, p, BEARINGS, 6.0) for p in LOOP])


def _ate(est, truth):
    ok = np.all(np.isfinite(est), axis=1)
    return float(np.sqrt(np.mean(np.sum((est[ok, :2] - truth[ok, :2]) ** 2, 1))))


@functools.cache
def _loop_run(lo: str):
    odom = _drifted(LOOP, 0.05, 0.04)
    lo_pose = _drifted(LOOP, 0.01, 0.005)
    x = _inputs(LOOP, odom, lo_pose, LOOP_RANGES)
    state, out, online_state = run_fleet(_spec(lo), SlamParams(), x)
    return x, state, out, online_state, final_poses(state, out)[0]


def test_loop_closed_and_drift_removed():
    x, state, out, online_state, final = _loop_run("preintegrated")
    odom_ate = _ate(x["odom"][0], LOOP)
    assert odom_ate > 1.0  # the odometry alone is far off after the loop
    assert int(state.loops[0]) >= 1 and out.loop_closed[0].any()
    assert _ate(final, LOOP) < 0.05 < 0.1 * odom_ate
    # The first closure's chi-square lies between the 3-dof 95 % and 99.9 % points: the leg odometry's heading-rate
    # bias (0.005 rad/s) is not in its twist covariance, so exploration's gate (7.81) would refuse what slam.yaml's
    # (16.27) accepts.
    first_chi2 = float(np.asarray(out.loop_chi2[0])[np.asarray(out.loop_closed[0])][0])
    file_gate = load_params()["loop_consistency_chi2"]
    assert file_gate == pytest.approx(stats.chi2.ppf(0.999, 3), abs=5e-3)
    assert stats.chi2.ppf(0.95, 3) < first_chi2 <= file_gate
    # Node spacing follows the thresholds: one node per 0.5 s slot while moving.
    n = int(state.n_nodes[0])
    assert abs(n - len(LOOP) * DT / 0.5) <= 2 and not bool(state.full[0])
    added = np.flatnonzero(out.added[0])
    assert np.all(np.diff(added) >= 5)
    # Between nodes (before any closure moves them) a scan hangs from the last node by the odometry.
    odom = x["odom"][0]
    for s in range(added[0], 100):
        a = added[added <= s][-1]
        pose = _integrate(out.pose[0, a], [_relative(odom[a], odom[s])])[-1]
        np.testing.assert_allclose(out.pose[0, s, :2], pose[:2], atol=1e-4)
    # The final poses: node scans at their optimized nodes.
    np.testing.assert_allclose(final[added], state.graph.poses[0, :n], atol=1e-5)
    # The map holds the walls where the truth has them: occupied cells lie on segments.
    from jaxquad.slam import to_occupancy_map

    occ = to_occupancy_map(GRID, jax.tree.map(lambda a: a[0], state.grid))
    rows, cols = np.nonzero(occ.grid > 65)
    xy = np.c_[cols + 0.5, rows + 0.5] * GRID.resolution + [GRID.origin_x, GRID.origin_y]
    a, b = WORLD[:, None, :2], WORLD[:, None, 2:]
    u = np.clip(np.sum((xy - a) * (b - a), -1) / np.sum((b - a) ** 2, -1), 0, 1)
    dist = np.linalg.norm(xy - (a + u[..., None] * (b - a)), axis=-1).min(0)
    assert len(xy) > 300 and np.mean(dist < 0.1) > 0.95


def test_map_from_every_scan():
    """`redraw_maps` draws every scan from the first node on at its final pose composed with T_base_laser:
    the grid kernel's map of those scans at sensor poses composed here in NumPy; with no laser offset its
    known cells hold every cell of the nodes' map and more; the graph is left as it was."""
    x, state, out, _, final = _loop_run("preintegrated")
    every = redraw_maps(_spec("preintegrated"), SlamParams(), state, out, x)
    nodes_seen, every_seen = np.asarray(state.grid.observed[0]), np.asarray(every.grid.observed[0])
    assert np.all(every_seen[nodes_seen]) and every_seen.sum() > nodes_seen.sum()
    np.testing.assert_array_equal(every.graph.poses, state.graph.poses)

    T = np.array([0.2, 0.05, 0.1])  # base -> laser
    params = SlamParams(T_base_laser=jnp.asarray(T, jnp.float32))
    every = redraw_maps(_spec("preintegrated"), params, state, out, x)
    ok = np.all(np.isfinite(final), axis=1)
    assert ok[np.argmax(ok) :].all() and ok.sum() > 0.9 * len(ok)  # no pose only before the first node
    c, s = np.cos(final[:, 2]), np.sin(final[:, 2])
    sensor = np.c_[final[:, 0] + c * T[0] - s * T[1], final[:, 1] + s * T[0] + c * T[1], final[:, 2] + T[2]]
    f32 = lambda a: jnp.asarray(a, jnp.float32)  # noqa: E731
    poses = f32(np.where(ok[:, None], sensor, 0.0))
    ref = map_from_scans(GRID, params.occupancy, poses, f32(x["ranges"][0]), f32(BEARINGS), jnp.asarray(ok))
    np.testing.assert_array_equal(every.grid.observed[0], ref.observed)
    np.testing.assert_allclose(every.grid.log_odds[0], ref.log_odds, atol=1e-4)


# These sparse scans (120 beams) match along the corridor only with a lidar's smear (laser.yaml's 0.1 m): with the
# depth camera's 0.03 m each node's match stays at the last node.
SMEAR = SlamParams(match=MatchParams(smear_sigma=jnp.asarray(0.1)))


def test_leg_constraints_pull_back_a_corrupted_match():
    """One scan cast 0.35 m to the side of where the robot is (as a shaking robot's scan can be): with
    no leg constraint the node goes where that scan matched; with either kind it stays near the truth."""
    truth = LOOP[:60]
    ranges = np.stack([cast(WORLD, p, BEARINGS, 6.0) for p in truth])
    k = 35  # a node scan (every 5th scan from the first)
    ranges[k] = cast(WORLD, truth[k] + [0.0, 0.35, 0.0], BEARINGS, 6.0)
    x = _inputs(truth, truth.copy(), truth.copy(), ranges)
    errors = {}
    for lo in ("off", "preintegrated"):
        state, out, _ = run_fleet(_spec(lo), SMEAR, x)
        assert np.abs(out.pose[0, k - 5, :2] - truth[k - 5, :2]).max() < 0.05  # the nodes before it matched well
        assert out.added[0, k]
        errors[lo] = float(np.linalg.norm(out.pose[0, k, :2] - truth[k, :2]))
    assert errors["off"] > 0.25 and errors["preintegrated"] < 0.05, errors


def test_odometry_gate_refuses_a_turned_match():
    """One node scan cast from a pose turned 8.6 deg (a match far from where the wheels say the robot went): without
    the odometry test the node takes the turn; with it the odometry step replaces that match, and at most the next
    one (matched against a buffer that holds the turned scan), no earlier one."""
    truth = LOOP[:60]
    ranges = np.stack([cast(WORLD, p, BEARINGS, 6.0) for p in truth])
    k = 35  # a node scan
    ranges[k] = cast(WORLD, truth[k] + [0.0, 0.0, 0.15], BEARINGS, 6.0)
    x = _inputs(truth, truth.copy(), truth.copy(), ranges)
    heading, fallbacks = {}, {}
    laser = eqx.tree_at(lambda p: p.match_cov_scale, SMEAR, jnp.float32(1.0))  # laser.yaml's: the spread as it is
    for gate in (np.inf, 16.27):
        state, out, _ = run_fleet(
            _spec("off"), eqx.tree_at(lambda p: p.match_odometry_gate, laser, jnp.float32(gate)), x
        )
        assert out.added[0, k]
        heading[gate] = abs(float(out.pose[0, k, 2] - truth[k, 2]))
        m = int(state.n_edges[0])
        fallbacks[gate] = state.graph.edge_j[0, :m][state.edge_kind[0, :m] == EDGE_ODOMETRY].tolist()
    assert heading[np.inf] > 0.1 and heading[16.27] < 0.01, heading
    node = int(out.node[0, k])
    assert fallbacks[np.inf] == [] and fallbacks[16.27][0] == node and fallbacks[16.27] in ([node], [node, node + 1])


def test_match_odometry_chi2_against_numpy():
    """The test's chi-square: the match's pose in the predicted pose's frame against the step's motion model plus
    the match's covariance, computed here with NumPy's SE(2) and solve."""
    rng = np.random.default_rng(3)
    std = np.array([0.05, 0.02, 0.05])
    params = SlamParams(odometry_step_std=jnp.asarray(std, jnp.float32))
    for _ in range(5):
        x_last, step = rng.normal(size=3), np.array([0.4, -0.1, 0.3]) * rng.uniform(0.2, 2.0)
        pred = _integrate(x_last, [step])[-1]
        matched = pred + rng.normal(scale=[0.03, 0.03, 0.02])
        A = rng.normal(size=(3, 3)) * 0.01
        cov_match = A @ A.T + 1e-4 * np.eye(3)
        d = np.hypot(step[0], step[1])
        sigma = np.array([std[0] * d, std[0] * d, std[1] * d + std[2] * abs(step[2])]) + ODOMETRY_STEP_FLOOR
        r = _relative(pred, matched)
        want = r @ np.linalg.solve(np.diag(sigma**2) + cov_match, r)
        f = lambda a: jnp.asarray(a, jnp.float32)  # noqa: E731
        got = _match_odometry_chi2(params, f(pred), f(step), f(matched), f(cov_match))
        assert float(got) == pytest.approx(want, rel=1e-3)


def test_fleet_equals_single_robots():
    """Two robots batched (one on a shorter, different path) give each robot's single run."""
    x, state, out, _, _ = _loop_run("preintegrated")
    other = LOOP[200:].copy()
    x2 = _inputs(other, _drifted(other, -0.03, -0.02), other, LOOP_RANGES[200:])
    pad = len(LOOP) - len(other)
    both = {}
    for key, v in x.items():
        if key in ("t", "bearings", "T_base_laser"):
            both[key] = v
            continue
        w = x2[key]
        w = np.concatenate([w, np.repeat(w[:, -1:], pad, 1)], 1) if w.ndim > 1 else w
        if key == "valid":
            w[:, len(other) :] = False  # the second robot's log ends early
        both[key] = np.concatenate([v, w])
    state2, out2, _ = run_fleet(_spec("preintegrated"), SlamParams(), both)
    single2, outs2, _ = run_fleet(_spec("preintegrated"), SlamParams(), {k: v for k, v in x2.items()})
    np.testing.assert_allclose(out2.pose[0], out.pose[0], atol=1e-4)  # solver sums in another order
    assert int(state2.n_nodes[1]) == int(single2.n_nodes[0])
    np.testing.assert_allclose(out2.pose[1, : len(other)], outs2.pose[0], atol=1e-4)


def test_leg_odometry_bias_learned_and_taken_out():
    """Leg odometry that reads 3 cm/s too far to the left of the base at every step (exact otherwise): with the bias
    estimated (`lo_bias_std`, both axes or the sideways one) the SLAM learns most of it from the matches and its online
    poses err less."""
    b = 0.03
    lo = _integrate(LOOP[0], _relative(LOOP[:-1], LOOP[1:]) + [0.0, b * DT, 0.0])
    x = _inputs(LOOP, lo, lo, LOOP_RANGES)
    _, out_off, online_off = run_fleet(_spec("preintegrated"), SlamParams(), x)
    both = SlamParams(lo_bias_std=jnp.full(2, 0.05, jnp.float32))
    _, out_on, online_on = run_fleet(_spec("preintegrated"), both, x)
    np.testing.assert_array_equal(online_off.lo_bias.x[0, 2:], 0.0)
    bias = online_on.lo_bias.x[0, 2:]
    assert 0.5 * b < bias[1] < 1.5 * b and abs(bias[0]) < 0.3 * b, bias
    # The sideways axis alone (exploration's setting for the Badger): the forward bias stays exactly 0.
    sideways = SlamParams(lo_bias_std=jnp.asarray([0.0, 0.05], jnp.float32))
    _, out_side, online_side = run_fleet(_spec("preintegrated"), sideways, x)
    bias = online_side.lo_bias.x[0, 2:]
    assert bias[0] == 0.0 and 0.5 * b < bias[1] < 1.5 * b, bias
    assert _ate(out_side.pose[0], LOOP) < 0.7 * _ate(out_off.pose[0], LOOP)
    assert _ate(out_on.pose[0], LOOP) < 0.7 * _ate(out_off.pose[0], LOOP)
    # A known bias (a prior mean with std 0, a robot's calibration) is taken out of every leg edge as it is.
    known = SlamParams(lo_bias_mean=jnp.asarray([0.0, b], jnp.float32), lo_bias_std=jnp.zeros(2, jnp.float32))
    _, out_known, online_known = run_fleet(_spec("preintegrated"), known, x)
    np.testing.assert_array_equal(online_known.lo_bias.x[0, 2:], np.float32([0.0, b]))
    assert _ate(out_known.pose[0], LOOP) < 0.7 * _ate(out_side.pose[0], LOOP)


def _small_params(tmp_path):
    p = tmp_path / "slam.yaml"
    p.write_text("node_capacity: 32\nscan_buffer_size: 20\nmatch_max_range: 4.0\nmax_laser_range: 6.0\n")
    return p


def test_node_count_is_the_online_slams():
    x, state, *_ = _loop_run("off")
    assert not state.full[0] and nodes_needed(SlamParams(), x) == int(state.n_nodes[0]) > 20


def test_trajectory_files_in_time_order_one_pose_per_stamp():
    pose = np.arange(15.0).reshape(5, 3)
    pose[3] = np.nan
    traj = tum_of(np.array([1.0, 3.0, 2.0, 4.0, 3.0]), pose)
    np.testing.assert_array_equal(traj.t_s, [1.0, 2.0, 3.0])
    np.testing.assert_array_equal(traj.p_world_body[:, 0], [0.0, 6.0, 3.0])  # the first scan stamped 3 s


def test_cli_on_a_laser_npz_with_truth_and_a_carmen_log(tmp_path, capsys):
    odom = _drifted(LOOP, 0.05, 0.04)
    t = np.arange(len(LOOP)) * DT + 1.7e9  # Unix stamps: float32 would round them to 128 s
    log = LaserLog(scan_t=t, ranges=LOOP_RANGES, bearings=BEARINGS, odom_t=t, odom_xytheta=odom, gt_xytheta=LOOP)
    save_laser_npz(tmp_path / "loop.npz", log)
    params = _small_params(tmp_path)
    assert main(["slam", str(tmp_path / "loop.npz"), "--out", str(tmp_path / "a"), "--params", str(params)]) == 0
    summary = json.loads((tmp_path / "a" / "summary.json").read_text())
    r = summary["robots"][0]
    assert summary["format"] == "laser-npz" and summary["lo_constraints"] == "off" and r["loop_closures"] >= 1
    assert summary["map_scans"] == "every"
    # A laser log takes laser.yaml's overrides under the params file's.
    assert summary["params_defaults"][-1].endswith("laser.yaml") and summary["params"]["robust_loop_edges"] == 1
    # The log adds more nodes than the params file's 32 slots: the capacity grew to hold them all.
    assert r["nodes"] > 32 and not r["capacity_reached"] and r["node_capacity"] % 256 == 0
    assert r["scores"]["final"]["ate"]["rmse"] < 0.1 * r["scores"]["odometry"]["ate"]["rmse"]
    # The edges against the true node poses: every edge scored, the matches and closures within centimetres.
    ee = r["edge_errors"]
    assert {k: v["n"] for k, v in ee.items()} == {k: v for k, v in r["edges"].items() if v}
    assert ee["loop"]["off"] == 0 and ee["match"]["off"] == 0
    final = read_tum(tmp_path / "a" / "trajectory_final.tum")
    np.testing.assert_allclose(final.t_s, log.scan_t, rtol=0, atol=1e-6)  # every scan, stamped with its own time
    for f in ("trajectory.tum", "map.pgm", "map.yaml", "graph.g2o"):
        assert (tmp_path / "a" / f).stat().st_size > 0
    capsys.readouterr()

    # The same scans as a CARMEN log (FLASER lines, stamps in ipc_timestamp), with a comment.
    lines = ["# generated loop"]
    for t, r, o in zip(log.scan_t, LOOP_RANGES, odom):
        rr = " ".join(f"{v:.4f}" if np.isfinite(v) else "81.91" for v in r)
        lines.append(f"FLASER {len(r)} {rr} {o[0]} {o[1]} {o[2]} {o[0]} {o[1]} {o[2]} {t:.3f} host {t:.3f}")
    (tmp_path / "loop.clf").write_text("\n".join(lines) + "\n")
    argv = [
        "slam",
        str(tmp_path / "loop.clf"),
        "--out",
        str(tmp_path / "b"),
        "--params",
        str(params),
        "--flaser-fov-deg",
        "357",
        "--map-scans",
        "nodes",
    ]
    assert main(argv) == 0
    summary = json.loads((tmp_path / "b" / "summary.json").read_text())
    assert summary["format"] == "carmen" and summary["map_scans"] == "nodes"
    # The nodes' scans alone (one in five here) leave more of the map unknown than every scan.
    unknown = {k: int((load_map(tmp_path / k / "map.yaml").grid < 0).sum()) for k in "ab"}
    assert unknown["a"] < unknown["b"], unknown
    np.testing.assert_allclose(read_tum(tmp_path / "b" / "trajectory_final.tum").t_s, log.scan_t, rtol=0, atol=1e-3)
    capsys.readouterr()

    # The same log with every stamp written as 0 (as some public logs are): the scans are clocked 1 s apart, so
    # the node rule goes by travel and adds about the nodes of the timed log, and every scan keeps a pose.
    zero = [ln.replace(f"{t:.3f} host {t:.3f}", "0 host 0") for ln, t in zip(lines[1:], log.scan_t)]
    (tmp_path / "zero.clf").write_text("\n".join(zero) + "\n")
    assert main(argv[:1] + [str(tmp_path / "zero.clf"), "--out", str(tmp_path / "z")] + argv[4:]) == 0
    assert json.loads(capsys.readouterr().out)["scans_with_repeated_stamps"] == len(zero) - 1
    nodes = [json.loads((tmp_path / k / "summary.json").read_text())["robots"][0]["nodes"] for k in "bz"]
    assert abs(nodes[0] - nodes[1]) <= 2 and nodes[1] > 20, nodes
    np.testing.assert_array_equal(read_tum(tmp_path / "z" / "trajectory_final.tum").t_s, np.arange(len(zero)))

    # One-line errors before any work: a malformed line, a bad parameter, an output in the way.
    (tmp_path / "bad.clf").write_text(lines[1] + "\nFLASER 3 1.0 oops\n")
    assert main(["slam", str(tmp_path / "bad.clf"), "--out", str(tmp_path / "c")]) == 1
    assert "bad.clf:2" in capsys.readouterr().err and not (tmp_path / "c").exists()
    (tmp_path / "neg.yaml").write_text("resolution: -1\n")
    argv = ["slam", str(tmp_path / "loop.npz"), "--out", str(tmp_path / "c"), "--params", str(tmp_path / "neg.yaml")]
    assert main(argv) == 1
    assert "resolution" in capsys.readouterr().err
    (tmp_path / "file").write_text("x")
    assert main(["slam", str(tmp_path / "loop.npz"), "--out", str(tmp_path / "file")]) == 1


def test_params_file_checks(tmp_path):
    values = load_params()
    assert values["minimum_travel_distance"] == 0.1 and values["loop_match_minimum_chain_size"] == 7
    laser = load_params(laser=True)
    assert laser["minimum_travel_distance"] == 0.5 and laser["robust_match_links"] == 0
    assert {k: v for k, v in laser.items() if values[k] == v}.keys() >= {"resolution", "loop_search_maximum_distance"}
    p = tmp_path / "p.yaml"
    for text, words in [
        ("nope: 1\n", "unknown key"),
        ("node_capacity: 2.5\n", "integer"),
        ("loop_ambiguity_ratio: 2\n", "out of range"),
        ("resolution: .nan\n", "finite"),
        ("robust_loop_edges: 2\n", "0 or 1"),
        ("occupancy_miss_probability: 0.5\n", "occupancy_hit_probability must lie in"),
        ("occupancy_hit_probability: 0.3\n", "occupancy_hit_probability must lie in"),
        ("occupancy_hit_offset_cells: 1.5\n", "out of range"),
        ("occupancy_hit_offset_cells: -0.1\n", "out of range"),
        ("occupancy_clamp_min_probability: 0.4\n", "occupancy_clamp_min_probability must lie in"),
        ("occupancy_clamp_max_probability: 0.75\n", "occupancy_clamp_max_probability in"),
        ("occupancy_clamp_max_probability: 1.0\n", "occupancy_clamp_max_probability in"),
    ]:
        p.write_text(text)
        with pytest.raises(ValueError, match=words):
            load_params(p)
    with pytest.raises(ValueError, match="lo_constraints"):
        SlamSpec(grid=GRID, lo_constraints="odometry")
    # The map's inverse sensor model as log-odds: the defaults are the grid's own, a file's values their logits.
    from jaxquad.kernels.occupancy import OccupancyParams
    from jaxquad.slam.params import slam_config

    values = values | {"occupancy_clear_range": 0.0}  # GRID's rays stop at 6 m, short of slam.yaml's 8 m clearing
    occ = slam_config(values, GRID, "off")[1].occupancy
    assert float(occ.l_occ) == pytest.approx(float(OccupancyParams().l_occ), rel=1e-6)
    assert float(occ.l_free) == pytest.approx(float(OccupancyParams().l_free), rel=1e-6)
    # slam.yaml's clamps are OctoMap's log-odds -2 and 3.5, the kernel's defaults, to float32.
    assert float(occ.l_min) == float(OccupancyParams().l_min) and float(occ.l_max) == float(OccupancyParams().l_max)
    occ = slam_config(values | {"occupancy_clamp_min_probability": 0.05}, GRID, "off")[1].occupancy
    assert float(occ.l_min) == pytest.approx(np.log(0.05 / 0.95))
    occ = slam_config(values | {"occupancy_hit_probability": 0.9, "occupancy_miss_probability": 0.3}, GRID, "off")[1]
    assert float(occ.occupancy.l_occ) == pytest.approx(np.log(9.0)) and float(occ.occupancy.l_free) == pytest.approx(
        np.log(3.0 / 7.0)
    )
    assert float(occ.occupancy.hit_offset) == pytest.approx(0.5 * GRID.resolution)  # slam.yaml's: half a cell, in m
    occ = slam_config(values | {"occupancy_hit_offset_cells": 0.2}, GRID, "off")[1]
    assert float(occ.occupancy.hit_offset) == pytest.approx(0.2 * GRID.resolution)
    assert laser["occupancy_hit_offset_cells"] == 0.0  # slam_toolbox's for 2D lidars
    # Loop chains: by the count alone in slam.yaml; laser logs also take a chain spanning 4.5 m of path.
    assert values["loop_match_minimum_chain_distance"] == 0.0 and laser["loop_match_minimum_chain_distance"] == 4.5
    loop = slam_config(values | {"loop_match_minimum_chain_distance": 4.5}, GRID, "off")[1].loop
    assert float(loop.min_chain_distance) == 4.5 and int(loop.min_chain) == 7
    p.write_text("loop_match_minimum_chain_distance: -1\n")
    with pytest.raises(ValueError, match="out of range"):
        load_params(p)
    # The matches' odometry test: off (0, no limit) in both files.
    assert values["link_match_odometry_gate_chi2"] == 0.0 == laser["link_match_odometry_gate_chi2"]
    assert float(slam_config(values, GRID, "off")[1].match_odometry_gate) == np.inf
    odo = slam_config(values | {"link_match_odometry_gate_chi2": 9.0, "odometry_step_std_yaw": 0.1}, GRID, "off")[1]
    assert float(odo.match_odometry_gate) == 9.0 and np.allclose(odo.odometry_step_std, [0.02, 0.01, 0.1])
    p.write_text("odometry_step_std_xy: -0.01\n")
    with pytest.raises(ValueError, match="out of range"):
        load_params(p)
    # Exploration's own offset replaces the file's, whatever the file holds.
    from jaxquad.explore import ExploreConfig
    from jaxquad.explore.config import SCAN_RANGE
    from jaxquad.slam import map_max_range

    assert ExploreConfig().slam_values()["occupancy_hit_offset_cells"] == 1.0  # exploration's default: a whole cell
    assert ExploreConfig(map_hit_offset_cells=0.0).slam_values()["occupancy_hit_offset_cells"] == 0.0
    # Far readings clear the map (slam.yaml: walls to 5 m, clearing to 8 m); the map's grids reach the clear range.
    occ = slam_config(values | {"occupancy_clear_range": 6.0, "occupancy_clear_margin": 0.02}, GRID, "off")[1]
    assert float(occ.occupancy.clear_range) == 6.0 and float(occ.occupancy.clear_margin) == pytest.approx(0.02)
    defaults = load_params()
    assert defaults["occupancy_clear_range"] == 8.0 and map_max_range(defaults) == 8.0 > defaults["max_laser_range"]
    with pytest.raises(ValueError, match="occupancy_clear_range 8.0 m lies beyond the map grid's rays"):
        slam_config(defaults, GRID, "off")
    with pytest.raises(ValueError, match="occupancy_clear_range 30.0 m lies beyond the map grid's rays"):
        slam_config(values | {"occupancy_clear_range": 30.0}, GRID, "off")
    explore_values = ExploreConfig(map_range=4.0, map_clear_range=20.0).slam_values()
    assert explore_values["max_laser_range"] == 4.0 and map_max_range(explore_values) == SCAN_RANGE
    assert ExploreConfig(map_range=6.0).slam_values()["max_laser_range"] == 6.0  # beyond slam.yaml's walls, to 8 m
    assert ExploreConfig(map_hit_offset_cells=1.0).slam_values()["occupancy_hit_offset_cells"] == 1.0
    with pytest.raises(ValueError, match="map_hit_offset_cells"):
        ExploreConfig(map_hit_offset_cells=1.5)
    # A file's lower clamp must stay below exploration's own miss probability, which replaces the file's.
    clamp = tmp_path / "clamp.yaml"
    clamp.write_text("occupancy_clamp_min_probability: 0.32\n")
    with pytest.raises(ValueError, match="must lie below map_miss_probability"):
        ExploreConfig(slam_params=str(clamp))
    assert (
        ExploreConfig(slam_params=str(clamp), map_miss_probability=0.34).slam_values()["occupancy_miss_probability"]
        == 0.34
    )
    # The sideways leg-odometry bias: estimated for the Badger by default, not for the Go2; an explicit value wins.
    assert load_params()["leg_bias_std_sideways"] == 0.0 == load_params()["leg_bias_std_forward"]
    assert load_params()["leg_bias_mean_sideways"] == 0.0 == load_params()["leg_bias_mean_forward"]
    signed = tmp_path / "signed.yaml"
    signed.write_text("leg_bias_mean_sideways: -0.004\n")  # a mean may be negative, a std may not
    np.testing.assert_allclose(slam_config(load_params(signed) | {"occupancy_clear_range": 0.0}, GRID,
                                           "preintegrated")[1].lo_bias_mean, [0.0, -0.004])  # fmt: skip
    signed.write_text("leg_bias_std_sideways: -0.004\n")
    with pytest.raises(ValueError, match="leg_bias_std_sideways"):
        load_params(signed)
    assert ExploreConfig(robot="badger").slam_values()["leg_bias_std_sideways"] == 0.01
    assert ExploreConfig(robot="go2").slam_values()["leg_bias_std_sideways"] == 0.0
    assert ExploreConfig(robot="badger", variant="baseline").slam_values()["leg_bias_std_sideways"] == 0.0
    assert ExploreConfig(robot="badger", leg_bias_sideways=0.0).slam_values()["leg_bias_std_sideways"] == 0.0
    bias_values = ExploreConfig(leg_bias_sideways=0.02).slam_values() | {"occupancy_clear_range": 0.0}
    sideways = slam_config(bias_values, GRID, "preintegrated")[1].lo_bias_std
    np.testing.assert_allclose(sideways, [0.0, 0.02])
    with pytest.raises(ValueError, match="leg_bias_sideways"):
        ExploreConfig(leg_bias_sideways=-0.01)
    # Exploration's full variant gates loop closures at the 3-dof 95 % point in place of the file's; the baseline
    # keeps the file's.
    assert ExploreConfig().slam_values()["loop_consistency_chi2"] == pytest.approx(stats.chi2.ppf(0.95, 3), abs=5e-3)
    baseline = ExploreConfig(variant="baseline").slam_values()["loop_consistency_chi2"]
    assert baseline == load_params()["loop_consistency_chi2"]
    assert ExploreConfig(loop_consistency_chi2=3.0).slam_values()["loop_consistency_chi2"] == 3.0
    with pytest.raises(ValueError, match="loop_consistency_chi2"):
        ExploreConfig(loop_consistency_chi2=0.0)
