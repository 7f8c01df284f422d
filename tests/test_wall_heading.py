"""Heading from wall directions (`kernels.wall_heading`) on scans cast by the independent NumPy caster: the
walls' directions in closed form, the correlation search against a brute-force pairwise NumPy sum, a known
heading error recovered in a rotated room, an unrelated room rejected by its quality, and the online SLAM
holding its heading with priors where its odometry drifts."""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp
import numpy as np
from _laser2d import box, cast

from jaxquad.kernels.wall_heading import (
    HeadingParams,
    HeadingSpec,
    direction_spectrum,
    measure_heading,
    rotate_spectrum,
    wall_directions,
)

SPEC = HeadingSpec()
PARAMS = HeadingParams()
BEARINGS = np.linspace(0.75, -0.75, 160)  # a depth camera's 86 deg, left to right


def _rotated(segments: np.ndarray, angle: float) -> np.ndarray:
    c, s = np.cos(angle), np.sin(angle)
    R = np.array([[c, -s], [s, c]])
    return np.c_[segments[:, :2] @ R.T, segments[:, 2:] @ R.T]


# A room with furniture: walls in two directions, and a table 25 deg off them.
ROOM = np.concatenate(
    [box(-4, -3, 4, 3), box(1.0, 1.8, 2.5, 3.0), box(-3.2, -3.0, -2.0, -2.2), _rotated(box(-0.5, -0.3, 0.5, 0.3), 0.44)]
)


@functools.cache
def _jit():
    bearings = jnp.asarray(BEARINGS, jnp.float32)
    directions = jax.jit(jax.vmap(lambda r: wall_directions(SPEC, PARAMS, r, bearings, r > 0)))
    spectrum = jax.jit(jax.vmap(lambda d, w, h: direction_spectrum(SPEC, d, w, h)))
    measure = jax.jit(lambda s, m: measure_heading(SPEC, PARAMS, s, m))
    return directions, spectrum, measure


def _scans(world, poses, noise=0.0, seed=0):
    rng = np.random.default_rng(seed)
    r = np.stack([cast(world, p, BEARINGS, 8.0) for p in poses])
    r = np.where(np.isfinite(r), r, 0.0)
    return (r + noise * r**2 * rng.standard_normal(r.shape)).astype(np.float32)


def _map_spectrum(world, poses, noise=0.0):
    directions, spectrum, _ = _jit()
    d, w = directions(jnp.asarray(_scans(world, poses, noise)))
    return np.asarray(spectrum(d, w, jnp.asarray(poses[:, 2], jnp.float32))).sum(0)


POSES = np.array([[-2.5, -1.0, 0.3], [0.0, -1.5, 1.2], [2.0, 0.0, 2.6], [-1.0, 1.0, -2.0], [2.5, -2.0, -0.7]])


def test_directions_of_a_straight_wall_and_a_corner():
    """Noise-free returns off one wall 2 m ahead, seen at 30 deg: each fitted direction is the wall's in the
    sensor frame (mod pi); the returns whose stretch spans a box's corner weigh nothing."""
    directions, _, _ = _jit()
    wall = np.array([[2.0, -10.0, 2.0, 10.0]])
    pose = np.array([0.0, 0.0, np.deg2rad(30.0)])
    d, w = (np.asarray(a)[0] for a in directions(jnp.asarray(_scans(wall, pose[None]))))
    expected = np.pi / 2 - pose[2]
    ok = w > 0
    assert ok.mean() > 0.9
    np.testing.assert_allclose(np.sin(d[ok] - expected), 0.0, atol=1e-3)

    corner = box(1.0, -1.0, 3.0, 1.0)
    pose = np.array([-0.5, -1.6, np.deg2rad(45.0)])  # the corner (1, -1) straight ahead
    r = _scans(corner, pose[None])
    d, w = (np.asarray(a)[0] for a in directions(jnp.asarray(r)))
    c = np.cos(BEARINGS + pose[2]), np.sin(BEARINGS + pose[2])
    xy = pose[:2] + r[0][:, None] * np.stack(c, -1)
    near = np.linalg.norm(xy - [1.0, -1.0], axis=1) < 0.1
    assert near.any() and np.all(w[near] == 0)
    assert np.all(w[r[0] == 0] == 0)


def _pairwise_correlation(d_s, w_s, h_s, d_m, w_m, h_m, deltas):
    """sum_ij w_i v_j sum_k g_k cos(2k(phi_i + h_s + delta - psi_j - h_j)), from pairwise sums over the two
    scans' returns (no spectra): cos(2k(x + delta)) = cos(2kx) cos(2k delta) - sin(2kx) sin(2k delta)."""
    k = np.arange(1, SPEC.harmonics + 1)
    g = np.exp(-2.0 * (k * float(PARAMS.kernel_std)) ** 2)
    i = np.flatnonzero(w_s)
    j = np.flatnonzero(w_m)
    diff = (d_s[i] + h_s)[:, None] - (d_m + h_m[:, None]).ravel()[j][None, :]
    ww = w_s[i][:, None] * w_m.ravel()[j][None, :]
    A = np.array([np.sum(ww * np.cos(2 * kk * diff)) for kk in k])
    B = np.array([np.sum(ww * np.sin(2 * kk * diff)) for kk in k])
    return np.cos(2 * np.outer(deltas, k)) @ (g * A) - np.sin(2 * np.outer(deltas, k)) @ (g * B)


def test_search_equals_a_pairwise_numpy_correlation():
    """A scan whose heading is 0.05 rad off, against the map of five others: the search's peak is the
    pairwise correlation's (within a step of the search) and the error is 0.05 rad."""
    directions, spectrum, measure = _jit()
    pose = np.array([2.0, -1.0, -0.4])
    d, w = (np.asarray(a, np.float64) for a in directions(jnp.asarray(_scans(ROOM, pose[None], noise=0.01))))
    dm, wm = (np.asarray(a, np.float64) for a in directions(jnp.asarray(_scans(ROOM, POSES, noise=0.01))))
    h = pose[2] + 0.05
    s = spectrum(jnp.asarray(d, jnp.float32), jnp.asarray(w, jnp.float32), jnp.asarray([h], jnp.float32))[0]
    m = spectrum(jnp.asarray(dm, jnp.float32), jnp.asarray(wm, jnp.float32), jnp.asarray(POSES[:, 2], jnp.float32))
    got = measure(s, m.sum(0))
    deltas = np.linspace(-1.0, 1.0, SPEC.steps) * float(PARAMS.search)
    scale = max(w.max(), wm.max())
    corr = _pairwise_correlation(d[0], w[0] / scale, h, dm, wm / scale, POSES[:, 2], deltas)
    best = deltas[np.argmax(corr)]
    assert abs(float(got.error) - (-best)) <= deltas[1] - deltas[0]
    assert abs(float(got.error) - 0.05) < np.deg2rad(1.0)  # one noisy scan: about 1 deg rms in simulation
    assert 0.2 < float(got.quality) <= 1.0  # the map holds the table's directions, which this scan misses


def test_known_heading_error_recovered_and_an_unrelated_room_rejected():
    """Map directions from five scans at their true headings; a scan from a sixth pose whose heading is off
    by e gives the error e: within 0.15 deg noise-free, and with the simulated depth noise (1 % of r^2, map
    and scan) within 1.5 deg, the error moving with e one for one; 15 deg off, outside the search, none.
    A room turned 45 deg (its walls in no mapped direction within the search) correlates at most weakly;
    an empty map gives quality 0."""
    directions, spectrum, measure = _jit()
    pose = np.array([0.5, 0.5, 0.9])
    errors = np.deg2rad([-6.0, -1.0, 2.5, 7.0])
    for noise, tol in ((0.0, 0.15), (0.01, 1.5)):
        reference = jnp.asarray(_map_spectrum(ROOM, POSES, noise=noise))
        d, w = directions(jnp.asarray(_scans(ROOM, pose[None], noise, seed=3)))
        got = [measure(spectrum(d, w, jnp.asarray([pose[2] + e], jnp.float32))[0], reference) for e in errors]
        measured = np.array([float(g.error) for g in got])
        assert np.all(np.abs(np.rad2deg(measured - errors)) < tol), (noise, np.rad2deg(measured))
        np.testing.assert_allclose(np.rad2deg(measured - errors), np.rad2deg(measured[0] - errors[0]), atol=0.1)
        assert min(float(g.quality) for g in got) > 0.5
        # 15 deg off, the walls' best alignment lies outside the +-10 deg search: no measurement (in the room
        # without the turned table, whose directions give a weaker peak inside the search).
        bare = ROOM[:-4]
        ref = jnp.asarray(_map_spectrum(bare, POSES, noise=noise))
        db, wb = directions(jnp.asarray(_scans(bare, pose[None], noise, seed=3)))
        far = measure(spectrum(db, wb, jnp.asarray([pose[2] + np.deg2rad(15.0)], jnp.float32))[0], ref)
        assert float(far.quality) == 0.0
    turned = _rotated(box(-4, -3, 4, 3), np.pi / 4)
    d, w = directions(jnp.asarray(_scans(turned, pose[None])))
    got = measure(spectrum(d, w, jnp.asarray([pose[2]], jnp.float32))[0], reference)
    assert float(got.quality) < 0.2
    empty = measure(spectrum(d, w, jnp.asarray([pose[2]], jnp.float32))[0], jnp.zeros_like(reference))
    assert float(empty.quality) == 0.0


def test_online_slam_holds_its_heading_with_wall_priors():
    """Odometry whose heading drifts 0.004 rad/s, scan-match links and loop closures switched off so the graph
    is that odometry: with `wall_heading` the nodes' headings stay near the truth, without they drift."""
    import equinox as eqx

    from jaxquad.slam import SlamParams, SlamSpec, grid_spec, run_fleet
    from jaxquad.slam.report import edge_errors, robot_slice
    from jaxquad.slam.state import EDGE_HEADING

    # Node 0 heads +y (pi/2): a prior's measurement is relative to node 0's heading (the edge scores below).
    corners = [(2.5, -1.8), (2.5, 1.8), (-2.5, 1.8), (-2.5, -1.8), (2.5, -1.8), (2.5, 1.8)]
    truth = []
    for a, b in zip(corners[:-1], corners[1:]):
        d = np.subtract(b, a)
        for s in np.arange(0.0, np.linalg.norm(d), 0.05):
            truth.append([*(a + d * s / np.linalg.norm(d)), np.arctan2(d[1], d[0])])
    truth = np.array(truth)
    S, dt = len(truth), 0.1
    odom = truth.copy()
    odom[:, 2] += 0.004 * dt * np.arange(S)  # the heading's drift; positions as the truth
    ranges = _scans(ROOM, truth, noise=0.01, seed=1)
    x = {
        "t": np.arange(S) * dt,
        "odom": odom[None],
        "lo_pose": odom[None],
        "ranges": ranges[None],
        "bearings": BEARINGS,
        "T_base_laser": np.zeros(3),
        "valid": np.ones((1, S), bool),
        "lo_twist": np.zeros((1, S, 3)),
        "lo_twist_cov": np.broadcast_to(np.diag([0.01, 0.01, 4e-4]), (1, S, 3, 3)),
        "lo_valid": np.ones((1, S), bool),
    }
    params = SlamParams(link_min_response=jnp.asarray(2.0))  # every link is the odometry step
    params = eqx.tree_at(lambda p: p.loop.fine_response, params, jnp.asarray(2.0))  # no closure
    grid = grid_spec((-5.0, -4.0, 5.0, 4.0), 0.05, 6.0)
    final = {}
    for on in (False, True):
        spec = SlamSpec(grid=grid, nodes=160, buffer=10, lo_constraints="off", wall_heading=on)
        state, out, _ = run_fleet(spec, params, x)
        n = int(state.n_nodes[0])
        assert int(state.loops[0]) == 0
        nodes = np.flatnonzero(np.asarray(out.added[0]))
        err = np.asarray(state.graph.poses[0, :n, 2]) - truth[nodes, 2]
        final[on] = np.rad2deg(np.abs((err[-20:] + np.pi) % (2 * np.pi) - np.pi)).max()
        kinds = np.asarray(state.edge_kind[0, : int(state.n_edges[0])])
        assert (kinds == EDGE_HEADING).sum() == (int(state.headings[0]) if on else 0)
        if on:
            assert int(state.headings[0]) > n // 2
            used = np.isfinite(np.asarray(out.heading_error[0]))
            assert used.sum() == int(state.headings[0])
            # Scored at the truth, a prior holds only a heading: its x, y are not scored, its chi-square has 1 dof.
            row = edge_errors(robot_slice(state, 0), robot_slice(out, 0), truth)["wall_heading"]
            assert row["n"] == int(state.headings[0]) and np.isnan(row["rms_x_m"]) and np.isnan(row["rms_y_m"])
            assert 0 < row["rms_theta_rad"] < np.deg2rad(2.0) and row["off"] == 0
    drift = np.rad2deg(0.004 * dt * S)
    assert final[False] > 0.8 * drift and final[True] < 0.3 * drift, (final, drift)

    # The map's spectrum is every node scan's at the node's heading now, also after the nodes move (as a loop
    # closure's optimization moves them): against each scan's spectrum computed afresh at that heading.
    from jaxquad.slam.heading import map_spectrum

    one = jax.tree.map(jnp.asarray, robot_slice(state, 0))
    poses = np.asarray(one.graph.poses)
    directions, spectrum, _ = _jit()
    d, w = directions(jnp.asarray(np.where(np.asarray(one.valid[:n]), np.asarray(one.ranges[:n]), 0.0)))
    for turn in (0.0, 0.07):
        moved = poses.copy()
        moved[n // 2 : n, 2] += turn
        st = eqx.tree_at(lambda s: s.graph.poses, one, jnp.asarray(moved, jnp.float32))
        want = np.asarray(spectrum(d, w, jnp.asarray(moved[:n, 2], jnp.float32))).sum(0)
        np.testing.assert_allclose(map_spectrum(spec, st), want, rtol=1e-3, atol=1e-4 * np.abs(want).max())


def test_settings_of_the_slam_file_and_of_exploration(tmp_path):
    """slam.yaml's wall_heading is 0 or 1 (one-line error otherwise) and turns the spec's edge slots to 4 per
    node; exploration gives it to the full variant's SLAM unless --wall-heading off, never to the baseline's, and
    marks obstacles under the scan plane in the full variant's costmap unless --low-obstacles off."""
    import argparse

    import pytest

    from jaxquad.explore.cli import add_loop_arguments
    from jaxquad.explore.config import ExploreConfig
    from jaxquad.slam import grid_spec, load_params, slam_config

    bad = tmp_path / "bad.yaml"
    bad.write_text("wall_heading: 2\n")
    with pytest.raises(ValueError, match="wall_heading must be 0 or 1"):
        load_params(bad)
    grid = grid_spec((0.0, 0.0, 4.0, 4.0), 0.05, 4.0)
    values = load_params() | {"occupancy_clear_range": 0.0}  # the grid's rays stop at 4 m
    assert values["wall_heading"] == 0
    off, _ = slam_config(values, grid, "preintegrated")
    on, _ = slam_config(values | {"wall_heading": 1}, grid, "preintegrated")
    assert (off.wall_heading, on.wall_heading) == (False, True) and on.edges == 4 * on.nodes == 4 * off.edges // 3

    assert ExploreConfig().slam_values()["wall_heading"] == 1
    assert ExploreConfig(variant="baseline").slam_values()["wall_heading"] == 0
    assert ExploreConfig(wall_heading=False).slam_values()["wall_heading"] == 0
    parser = argparse.ArgumentParser()
    add_loop_arguments(parser)
    assert parser.parse_args([]).wall_heading == "on"
    assert parser.parse_args(["--wall-heading", "off"]).wall_heading == "off"
    # The obstacles under the scan plane likewise: on for the full variant unless turned off, never for the baseline.
    assert [parser.parse_args(a).low_obstacles for a in ([], ["--low-obstacles"], ["--low-obstacles", "off"])] == [
        "on",
        "on",
        "off",
    ]
    assert ExploreConfig().loop_config().low_obstacles
    assert not ExploreConfig(low_obstacles=False).loop_config().low_obstacles
    assert not ExploreConfig(variant="baseline").loop_config().low_obstacles


def test_node_update_gain_gate_and_edge():
    """`jaxquad.slam.heading.update` with a laser mounted 0.1 rad off the base, node 0 at a non-zero heading and a
    known prior variance: the measured error is the node's heading error; the heading moves by P / (P + R) of it
    with R from the scan's summed weights; the variance shrinks to (1 - K) P; the prior holds the node at its
    measured heading, with information on the heading alone. An error beyond the gate (on P and the minimum std,
    not R) is not used and leaves the pose; with `heading_gate_with_r` a wide R lets that same error through."""
    import equinox as eqx

    from jaxquad.slam import SlamParams, SlamSpec, grid_spec
    from jaxquad.slam.heading import map_spectrum, update
    from jaxquad.slam.state import SlamInputs, init

    laser = 0.1
    spec = SlamSpec(grid=grid_spec((-5.0, -4.0, 5.0, 4.0), 0.05, 6.0), nodes=8, wall_heading=True)
    params = SlamParams(T_base_laser=jnp.asarray([0.2, 0.0, laser], jnp.float32))
    state = init(spec, params, jnp.asarray(BEARINGS, jnp.float32))
    x0 = np.array([0.3, -0.2, 0.25])
    reference = _map_spectrum(ROOM, POSES)
    sensor = np.array([0.5, 0.5, 0.9])  # the scan's true sensor pose
    ranges = _scans(ROOM, sensor[None])[0]
    inp = SlamInputs(
        t=jnp.asarray(0.0),
        odom=jnp.zeros(3),
        ranges=jnp.asarray(ranges),
        valid=jnp.asarray(ranges > 0),
        lo_pose=jnp.zeros(3),
        lo_twist=jnp.zeros(3),
        lo_twist_cov=jnp.zeros((3, 3)),
        lo_valid=jnp.asarray(True),
    )
    _, weight = wall_directions(SPEC, PARAMS, jnp.asarray(ranges), jnp.asarray(BEARINGS, jnp.float32), inp.valid)
    R = float(params.heading_variance_scale) / float(np.sum(weight)) + float(params.heading_min_std) ** 2
    scale_wide = np.deg2rad(3.0) ** 2 * float(np.sum(weight))  # the variance scale that makes R (3 deg)^2
    run = jax.jit(lambda s, pose, var: update(spec, params, s, pose, var, inp, jnp.asarray(False)))
    directions, spectrum, measure = _jit()
    # The map's spectrum as node 0's, kept in its frame: map_spectrum turns it by node 0's heading.
    node0 = rotate_spectrum(SPEC, jnp.asarray(reference, jnp.float32), jnp.asarray(-x0[2], jnp.float32))
    state = eqx.tree_at(
        lambda s: (s.node_directions, s.graph.poses, s.graph.node_mask),
        state,
        (
            state.node_directions.at[0].set(node0),
            state.graph.poses.at[0].set(x0),
            state.graph.node_mask.at[0].set(True),
        ),
    )
    np.testing.assert_allclose(map_spectrum(spec, state), reference, rtol=1e-4, atol=1e-3 * np.abs(reference).max())
    # The third case: a gate on P alone refuses 4 deg at P = (1 deg)^2; R as wide as 3 deg std would admit it.
    wide = eqx.tree_at(
        lambda p: (p.heading_variance_scale, p.heading_gate_with_r),
        params,
        (jnp.asarray(scale_wide, jnp.float32), jnp.asarray(True)),
    )
    P1 = np.deg2rad(1.0) ** 2
    cases = (
        (np.deg2rad(3.0), 4e-4, 1e-5, True),
        (np.deg2rad(6.0), 1e-8, 0.0, False),
        (np.deg2rad(4.0), P1, 0.0, False),
    )
    for err, P, step, expect_used in cases:
        st = eqx.tree_at(lambda s: s.node_heading_var, state, jnp.full_like(state.node_heading_var, P))  # any last node
        pose = np.array([1.0, 2.0, sensor[2] - laser + err])
        new, var, local, at, info, used, measured = (np.asarray(a, np.float64) for a in run(st, pose, step))
        assert bool(used) == expect_used
        if not expect_used:
            # a good match (quality >= 0.5) refused by the gate alone
            d, w = directions(jnp.asarray(ranges[None]))
            meas = measure(spectrum(d, w, jnp.asarray([pose[2] + laser], jnp.float32))[0], jnp.asarray(reference))
            min_var = float(params.heading_min_std) ** 2
            assert float(meas.quality) >= 0.5 and float(meas.error) ** 2 / (P + step + min_var) > 10.83
            np.testing.assert_allclose(new, pose, atol=1e-6)
            assert np.isnan(measured) and abs(var - (P + step)) <= 1e-6 * (P + step) + 1e-12
            if P == P1:  # the measurement's own variance, counted, would have let it through
                assert float(meas.error) ** 2 / (P + float(wide.heading_variance_scale) / float(np.sum(weight))) < 10.83
                assert bool(
                    update(
                        spec,
                        wide,
                        st,
                        jnp.asarray(pose, jnp.float32),
                        jnp.asarray(step, jnp.float32),
                        inp,
                        jnp.asarray(False),
                    )[5]
                )
            continue
        assert abs(measured - err) < np.deg2rad(0.15)
        K = (P + step) / (P + step + R)
        np.testing.assert_allclose(new[2], pose[2] - K * measured, atol=1e-6)
        np.testing.assert_allclose(new[:2], pose[:2])
        np.testing.assert_allclose(var, (1 - K) * (P + step), rtol=1e-4)
        np.testing.assert_allclose(at, [*pose[:2], pose[2] - measured], atol=1e-6)
        np.testing.assert_allclose(info, np.diag([0.0, 0.0, 1.0 / R]), rtol=1e-4)
        # The node keeps its scan's spectrum in the base frame: the sensor frame's turned by the laser's yaw.
        d, w = directions(jnp.asarray(ranges[None]))
        base = np.asarray(spectrum(d, w, jnp.asarray([laser], jnp.float32))[0])
        np.testing.assert_allclose(local, base, rtol=1e-4, atol=1e-4 * np.abs(base).max())


# A sensor looking into the bare room's corner, and an 0.8 m crate 1.4 m away to the left of its view axis, two faces
# in view.
CORNER_VIEW = np.array([[0.0, 0.0, np.pi / 4]])


def _crate(angle_deg: float) -> np.ndarray:
    """The crate turned by `angle_deg` off the walls."""
    centre = np.array([0.283, 1.414])
    return _rotated(box(-0.4, -0.4, 0.4, 0.4), np.deg2rad(angle_deg)) + np.tile(centre, 2)


def test_near_and_far_halves_disagree_by_a_turned_crates_angle():
    """A scan of the bare room's corner with a crate in front of it, at the true heading, against the bare room's
    directions: the near half (the crate) lines its faces up with the walls and the far half (the corner) measures
    the true heading, so the halves disagree by the crate's turn (the whole scan follows the crate, at a quality of
    0.96); a crate square to the walls, or none, gives agreement. `slam.heading.update` leaves out a scan whose
    halves disagree beyond its tolerance, and uses it without the test."""
    import equinox as eqx

    from jaxquad.kernels.wall_heading import halves_disagreement
    from jaxquad.slam import SlamParams, SlamSpec, grid_spec, load_params, slam_config
    from jaxquad.slam.heading import update
    from jaxquad.slam.state import SlamInputs, init

    directions, _, _ = _jit()
    bare = box(-4, -3, 4, 3)
    reference = jnp.asarray(_map_spectrum(bare, POSES), jnp.float32)
    heading = jnp.asarray(CORNER_VIEW[0, 2], jnp.float32)
    split = jax.jit(lambda d, w, r: halves_disagreement(SPEC, PARAMS, d, w, r, heading, reference, jnp.asarray(0.3)))
    for angle, lo, hi in ((6.6, 6.0, 7.2), (0.0, 0.0, 0.3), (None, 0.0, 0.3)):
        world = bare if angle is None else np.concatenate([bare, _crate(angle)])
        ranges = jnp.asarray(_scans(world, CORNER_VIEW)[0])
        d, w = directions(ranges[None])
        apart = np.rad2deg(float(split(d[0], w[0], ranges)))
        assert lo <= apart <= hi, (angle, apart)

    # The SLAM's node update: the turned crate's scan is used without the test and left out with a 2 deg one.
    grid = grid_spec((-5.0, -4.0, 5.0, 4.0), 0.05, 6.0)
    spec = SlamSpec(grid=grid, nodes=8, wall_heading=True)
    laser = 0.3  # the laser turned off the base: the halves are measured at the sensor's heading
    params = SlamParams(T_base_laser=jnp.asarray([0.0, 0.0, laser], jnp.float32))
    values = load_params() | {"occupancy_clear_range": 0.0}  # the grid's rays stop at 6 m
    assert float(slam_config(values, grid, "off")[1].heading_halves_tolerance) == 0.0  # slam.yaml: off
    on = slam_config(values | {"wall_heading_halves_tolerance": 0.03}, grid, "off")[1]
    assert float(on.heading_halves_tolerance) == np.float32(0.03)
    state = init(spec, params, jnp.asarray(BEARINGS, jnp.float32))
    state = eqx.tree_at(
        lambda s: (s.node_directions, s.graph.node_mask, s.node_heading_var),
        state,
        (
            state.node_directions.at[0].set(reference),
            state.graph.node_mask.at[0].set(True),
            jnp.full_like(state.node_heading_var, np.deg2rad(5.0) ** 2),  # a heading known to 5 deg: the gate passes
        ),
    )
    ranges = jnp.asarray(_scans(np.concatenate([bare, _crate(6.6)]), CORNER_VIEW)[0])
    inp = SlamInputs(
        t=jnp.asarray(0.0),
        odom=jnp.zeros(3),
        ranges=ranges,
        valid=ranges > 0,
        lo_pose=jnp.zeros(3),
        lo_twist=jnp.zeros(3),
        lo_twist_cov=jnp.zeros((3, 3)),
        lo_valid=jnp.asarray(True),
    )
    for tolerance, expect_used in ((0.0, True), (np.deg2rad(2.0), False)):
        p = eqx.tree_at(lambda q: q.heading_halves_tolerance, params, jnp.asarray(tolerance, jnp.float32))
        out = update(
            spec,
            p,
            state,
            jnp.asarray(CORNER_VIEW[0] - [0, 0, laser], jnp.float32),
            jnp.asarray(0.0),
            inp,
            jnp.asarray(False),
        )
        assert bool(out[5]) == expect_used, tolerance
