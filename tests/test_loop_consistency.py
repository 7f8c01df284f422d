"""The online SLAM's loop-closure consistency test: the chain covariance against a NumPy Monte-Carlo
compounding of the links, and a confident but wrong closure (one scan cast from a displaced pose, as a
scan matched to the wrong place) rejected where it used to drag the graph."""

from __future__ import annotations

import functools

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from _laser2d import cast
from test_slam_online import BEARINGS, LOOP, WORLD, _ate, _drifted, _inputs, _spec

from jaxquad.slam import SlamParams, consistency, final_poses, run_fleet
from jaxquad.slam import init as slam_init


def _exp(xi):
    """NumPy SE(2) exponential of (vx, vy, w) rows -> (x, y, theta) rows (closed form)."""
    vx, vy, w = xi[..., 0], xi[..., 1], xi[..., 2]
    small = np.abs(w) < 1e-9
    ws = np.where(small, 1.0, w)
    a = np.where(small, 1.0 - w**2 / 6, np.sin(ws) / ws)
    b = np.where(small, w / 2, (1 - np.cos(ws)) / ws)
    return np.stack([a * vx - b * vy, b * vx + a * vy, w], -1)


def _compose(p, d):
    c, s = np.cos(p[..., 2]), np.sin(p[..., 2])
    return np.stack(
        [p[..., 0] + c * d[..., 0] - s * d[..., 1], p[..., 1] + s * d[..., 0] + c * d[..., 1], p[..., 2] + d[..., 2]],
        -1,
    )


def _between(a, b):
    c, s = np.cos(a[..., 2]), np.sin(a[..., 2])
    d = b[..., :2] - a[..., :2]
    yaw = (b[..., 2] - a[..., 2] + np.pi) % (2 * np.pi) - np.pi
    return np.stack([c * d[..., 0] + s * d[..., 1], -s * d[..., 0] + c * d[..., 1], yaw], -1)


def test_chain_covariance_matches_monte_carlo():
    rng = np.random.default_rng(0)
    n, i, j = 8, 1, 6
    links = np.c_[rng.uniform(0.2, 0.6, n), rng.uniform(-0.2, 0.2, n), rng.uniform(-0.5, 0.5, n)]
    links[0] = [0.3, -0.2, 0.4]  # node 0's pose
    covs = []
    for _ in range(n):
        L = rng.normal(size=(3, 3)) * [0.01, 0.01, 0.004]
        covs.append(L @ L.T + np.diag([1e-5, 1e-5, 1e-6]))
    covs = np.array(covs)
    poses = [links[0]]
    for k in range(1, n):
        poses.append(_compose(poses[-1], links[k]))
    poses = np.array(poses)
    state = slam_init(_spec("preintegrated"), SlamParams(), jnp.asarray(BEARINGS))
    cap = state.graph.poses.shape[0]
    pad = lambda x: jnp.asarray(np.concatenate([x, np.zeros((cap - n, *x.shape[1:]))]), jnp.float32)  # noqa: E731
    state = eqx.tree_at(
        lambda s: (s.graph.poses, s.graph.node_mask, s.node_cov),
        state,
        (pad(poses), jnp.arange(cap) < n, pad(covs)),
    )
    got = np.asarray(jax.jit(consistency.chain_covariance)(state, jnp.asarray(i), jnp.asarray(j)))
    # Monte Carlo: links i+1..j each perturbed on the right by a draw of its covariance, composed in NumPy.
    m = 200_000
    T = np.broadcast_to(np.zeros(3), (m, 3))
    for k in range(i + 1, j + 1):
        xi = rng.multivariate_normal(np.zeros(3), covs[k], size=m)
        T = _compose(_compose(T, links[k]), _exp(xi))
    nominal = _between(poses[i], poses[j])
    err = _between(np.broadcast_to(nominal, (m, 3)), T)  # right perturbation of T_i_j, first order
    want = np.cov(err.T)
    np.testing.assert_allclose(got, want, rtol=0.05, atol=2e-3 * np.sqrt(np.outer(np.diag(want), np.diag(want))).max())


def _adjoint(p):
    """NumPy SE(2) adjoint of pose (x, y, theta): [[R, (y, -x)^T], [0, 0, 1]]."""
    c, s = np.cos(p[2]), np.sin(p[2])
    return np.array([[c, -s, p[1]], [s, c, -p[0]], [0.0, 0.0, 1.0]])


def test_chain_covariance_with_priors_matches_gaussian_conditioning():
    """The filtered chain against the batch answer: xi_j = sum_k Ad(T_k_j^-1) w_k and the priors' readings
    y_m = phi + sum_(k <= m) w_k,theta + v_m, jointly Gaussian; Cov(xi_j | y) by the Schur complement."""
    rng = np.random.default_rng(1)
    n, i, j = 12, 2, 10
    links = np.c_[rng.uniform(0.3, 0.6, n), rng.uniform(-0.1, 0.1, n), rng.uniform(-0.4, 0.4, n)]
    poses = [links[0]]
    for k in range(1, n):
        poses.append(_compose(poses[-1], links[k]))
    poses = np.array(poses)
    covs = np.array([np.diag([4e-4, 1e-4, np.deg2rad(1.0) ** 2])] * n)
    P_i = np.deg2rad(0.7) ** 2
    info = np.where(np.arange(n) % 3 == 0, 1.0 / np.deg2rad(0.8) ** 2, 0.0)  # priors at nodes 3, 6, 9 (and 0)
    state = slam_init(_spec("preintegrated"), SlamParams(), jnp.asarray(BEARINGS))
    cap = state.graph.poses.shape[0]
    pad = lambda x: jnp.asarray(np.concatenate([x, np.zeros((cap - n, *x.shape[1:]))]), jnp.float32)  # noqa: E731
    state = eqx.tree_at(
        lambda s: (s.graph.poses, s.graph.node_mask, s.node_cov, s.node_heading_var, s.node_heading_info),
        state,
        (pad(poses), jnp.arange(cap) < n, pad(covs), pad(np.full(n, P_i)), pad(info)),
    )
    run = jax.jit(consistency.chain_covariance_with_priors)
    got = np.asarray(run(state, jnp.asarray(i), jnp.asarray(j)), np.float64)
    # Unknowns u = (phi, w_i+1 .. w_j), independent; xi_j = G u, y = M u + v.
    steps = list(range(i + 1, j + 1))
    cov_u = np.zeros((1 + 3 * len(steps),) * 2)
    cov_u[0, 0] = P_i
    G = np.zeros((3, cov_u.shape[0]))
    for a, k in enumerate(steps):
        cov_u[1 + 3 * a : 4 + 3 * a, 1 + 3 * a : 4 + 3 * a] = covs[k]
        G[:, 1 + 3 * a : 4 + 3 * a] = _adjoint(_between(poses[j], poses[k]))
    measured = [k for k in steps if info[k] > 0]
    M = np.zeros((len(measured), cov_u.shape[0]))
    for r, m in enumerate(measured):
        M[r, 0] = 1.0
        for a, k in enumerate(steps):
            if k <= m:
                M[r, 3 + 3 * a] = 1.0
    S_yy = M @ cov_u @ M.T + np.diag(1.0 / info[measured])
    S_xy = G @ cov_u @ M.T
    want = G @ cov_u @ G.T - S_xy @ np.linalg.solve(S_yy, S_xy.T)
    scale = np.sqrt(np.outer(np.diag(want), np.diag(want)))
    assert np.all(np.abs(got - want) <= 1e-3 * scale), (got, want)
    # The chain's own compounding, with no prior counted, is the unconditioned G cov_u G^T without phi.
    plain = np.asarray(consistency.chain_covariance(state, jnp.asarray(i), jnp.asarray(j)), np.float64)
    np.testing.assert_allclose(plain, G[:, 1:] @ cov_u[1:, 1:] @ G[:, 1:].T, rtol=1e-4, atol=1e-9)
    assert want[2, 2] < 0.5 * plain[2, 2]  # the priors hold the heading: this case tests something
    no_priors = eqx.tree_at(lambda s: s.node_heading_info, state, jnp.zeros_like(state.node_heading_info))
    np.testing.assert_allclose(run(no_priors, jnp.asarray(i), jnp.asarray(j)), plain, rtol=1e-4, atol=1e-9)
    off = run(state, jnp.asarray(i), jnp.asarray(j), jnp.asarray(False))  # the priors switched off
    np.testing.assert_allclose(off, plain, rtol=1e-4, atol=1e-9)


@functools.cache
def _corrupted_inputs():
    """The loop of test_slam_online with the first closing node's scan cast 1.3 m and 15 deg off."""
    odom = _drifted(LOOP, 0.05, 0.04)
    lo = _drifted(LOOP, 0.01, 0.005)
    ranges = np.stack([cast(WORLD, p, BEARINGS, 6.0) for p in LOOP])
    x = _inputs(LOOP, odom, lo, ranges)
    _, out, _ = run_fleet(_spec("preintegrated"), SlamParams(), x)
    k = int(np.flatnonzero(out.loop_closed[0])[0])  # the scan whose node closes the loop first
    x["ranges"] = x["ranges"].copy()
    x["ranges"][0, k] = cast(WORLD, LOOP[k] + [0.9, 0.9, np.deg2rad(15.0)], BEARINGS, 6.0)
    return k, x


def _corrupted_run(loop_max_chi2: float, graph_covariance: bool = False):
    k, x = _corrupted_inputs()
    params = eqx.tree_at(
        lambda p: (p.loop_max_chi2, p.loop_graph_covariance),
        SlamParams(),
        (jnp.asarray(loop_max_chi2, jnp.float32), jnp.asarray(graph_covariance)),
    )
    state, out, online_state = run_fleet(_spec("preintegrated"), params, x)
    return k, x, state, out, online_state


def test_wrong_loop_closure_rejected_by_consistency():
    k, x, state, out, online_state = _corrupted_run(float(SlamParams().loop_max_chi2))
    _, _, state_off, out_off, _ = _corrupted_run(1e9)  # no consistency test: the old behaviour
    assert out.added[0, k] and np.isfinite(out.loop_chi2[0, k])
    # The wrong closure passes the match tests; without the consistency test it is taken and drags the path.
    assert out_off.loop_closed[0, k]
    ate_off = _ate(final_poses(state_off, out_off)[0], LOOP)
    ate = _ate(final_poses(state, out)[0], LOOP)
    chi2 = float(out.loop_chi2[0, k])
    assert not out.loop_closed[0, k] and chi2 > float(SlamParams().loop_max_chi2), (chi2, ate, ate_off)
    assert ate < 0.1 < ate_off, (ate, ate_off)
    assert int(state.loops[0]) >= 1  # the honest closures of the next nodes are still taken


def test_the_whole_graphs_covariance_also_rejects_the_wrong_closure():
    """`loop_graph_covariance`: the test's covariance from the whole graph (`kernels.posegraph.relative_covariance`)
    rejects the same wrong closure and takes the honest ones; its chi-squares differ from the chain's."""
    limit = float(SlamParams().loop_max_chi2)
    k, x, state, out, _ = _corrupted_run(limit, graph_covariance=True)
    assert out.added[0, k] and not out.loop_closed[0, k] and float(out.loop_chi2[0, k]) > limit
    assert int(state.loops[0]) >= 1 and _ate(final_poses(state, out)[0], LOOP) < 0.1
    _, _, _, chain_out, _ = _corrupted_run(limit)
    tested = np.isfinite(out.loop_chi2[0]) & np.isfinite(chain_out.loop_chi2[0])
    assert tested.sum() >= 2 and not np.allclose(out.loop_chi2[0, tested], chain_out.loop_chi2[0, tested])
