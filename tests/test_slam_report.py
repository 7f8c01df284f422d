"""`jaxquad.slam.report`: edge errors of measurements perturbed by known amounts, against closed forms; trajectory
scores of a log with scans that have no truth."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np

from jaxquad.slam.online import EDGE_LEG, EDGE_LOOP, EDGE_MATCH
from jaxquad.slam.report import _trajectory_scores, edge_errors


def _se2(p):
    c, s = np.cos(p[2]), np.sin(p[2])
    return np.array([[c, -s, p[0]], [s, c, p[1]], [0.0, 0.0, 1.0]])


def _xyt(T):
    return np.array([T[0, 2], T[1, 2], np.arctan2(T[1, 0], T[0, 0])])


def _state(truth, edges, n_slots=6):
    """A one-robot SLAM state and output: nodes at scans 1, 3, 4 of 6 (truth NaN at the others)."""
    m = len(edges) + 1  # and one masked slot
    z = [_xyt(np.linalg.inv(_se2(truth[i])) @ _se2(truth[j]) @ _se2(d)) for i, j, d, _, _ in edges]
    graph = SimpleNamespace(
        edge_i=np.array([e[0] for e in edges] + [0]),
        edge_j=np.array([e[1] for e in edges] + [1]),
        measurement=np.array(z + [np.zeros(3)], np.float32),
        information=np.array([e[3] for e in edges] + [np.eye(3)]),
        edge_mask=np.array([True] * len(edges) + [False]),
    )
    state = SimpleNamespace(graph=graph, n_nodes=3, n_edges=m, edge_kind=np.array([e[4] for e in edges] + [EDGE_LOOP]))
    added = np.zeros(n_slots, bool)
    added[[1, 3, 4]] = True
    gt = np.full((n_slots, 3), np.nan)
    gt[[1, 3, 4]] = truth
    return state, SimpleNamespace(added=added), gt


TRUTH = np.array([[0.0, 0.0, 0.3], [1.0, 0.5, 0.9], [2.0, -0.5, -2.8]])
INFO = np.diag([100.0, 25.0, 400.0])


def test_perturbed_measurements_give_their_errors_and_chi_square():
    # Z = T_ij D gives the error Z^-1 T_ij = D^-1: a translation D gives -D, a rotation -angle.
    edges = [
        (0, 1, np.array([0.1, 0.0, 0.0]), INFO, EDGE_MATCH),  # chi2 0.01 * 100 = 1
        (1, 2, np.array([0.0, 0.0, 0.05]), INFO, EDGE_MATCH),  # chi2 0.0025 * 400 = 1
        (0, 1, np.zeros(3), INFO, EDGE_LEG),
        (1, 2, np.zeros(3), INFO, EDGE_LEG),
        (0, 2, np.array([0.0, 0.4, 0.0]), INFO, EDGE_LOOP),  # chi2 0.16 * 25 = 4, off by 0.4 m
    ]
    rows = edge_errors(*_state(TRUTH, edges))
    assert set(rows) == {"match", "leg_odometry", "loop"}  # the masked slot is not counted
    match, leg, loop = rows["match"], rows["leg_odometry"], rows["loop"]
    assert match["n"] == 2 and leg["n"] == 2 and loop["n"] == 1
    np.testing.assert_allclose([match["rms_x_m"], match["rms_y_m"], match["rms_theta_rad"]],
                               [0.1 / np.sqrt(2), 0.0, 0.05 / np.sqrt(2)], atol=2e-6)  # fmt: skip
    np.testing.assert_allclose(match["chi2_mean"], 1.0, rtol=1e-4)
    np.testing.assert_allclose([leg["rms_x_m"], leg["rms_y_m"], leg["rms_theta_rad"], leg["chi2_mean"]], 0, atol=2e-6)
    np.testing.assert_allclose([loop["rms_y_m"], loop["chi2_mean"]], [0.4, 4.0], rtol=1e-4)
    assert (match["off"], leg["off"], loop["off"]) == (0, 0, 1)


def test_no_scores_without_truth_at_every_node():
    state, out, gt = _state(TRUTH, [(0, 1, np.zeros(3), INFO, EDGE_MATCH)])
    gt[3] = np.nan
    assert edge_errors(state, out, gt) is None
    gt = _state(TRUTH, [])[2]
    gt[5] = 0.0  # finite truth at every scan, but more node scans than nodes: the nodes cannot be placed
    out.added[5] = True
    assert edge_errors(state, out, gt) is None


def test_scans_without_truth_are_left_out_of_the_scores():
    t = np.arange(60) * 0.1
    gt = np.stack([np.cos(0.3 * t), np.sin(0.3 * t), 0.3 * t + np.pi / 2], 1)
    pose = gt + np.array([0.05, 0.0, 0.0])  # a constant offset: aligned away, ATE ~ 0
    gt[[10, 11]] = np.nan
    scores = _trajectory_scores(t, pose, gt, np.ones(60, bool))
    assert scores["scans_scored"] == 58 and scores["ate"]["rmse"] < 1e-3
