"""SE(2) pose-graph optimization against GTSAM's Levenberg-Marquardt and scipy's least_squares.

Everything runs in float64 (`jax.enable_x64`, local to each test). GTSAM's BetweenFactorPose2 error
is Logmap(Z^-1 X_i^-1 X_j), which differs from g2o's [t, angle] away from the optimum (the Logmap's
translation is rotated by the half-angle Jacobian); both vanish and share their minimizer when
the errors are small, so the comparisons are at the optimum: poses to 1e-5 and our chi2 evaluated
at GTSAM's poses equal to ours to 1e-7 relative (both are stationary points of nearly the same cost).
"""

import gtsam
import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy.optimize import least_squares

from jaxquad.kernels import chain_precond
from jaxquad.kernels.posegraph import ROBUST_CAUCHY, ROBUST_HUBER, _rho_and_weight, relative_covariance
from jaxquad.slam import SolverParams, build_graph, chi2, edge_error, manhattan_graph, optimize, stack_graphs

_optimize = jax.jit(optimize)


def _mat(p):
    c, s = np.cos(p[2]), np.sin(p[2])
    return np.array([[c, -s, p[0]], [s, c, p[1]], [0.0, 0.0, 1.0]])


def _pose_of(T):
    return np.array([T[0, 2], T[1, 2], np.arctan2(T[1, 0], T[0, 0])])


def _g2o_error_np(xi, xj, z):
    return _pose_of(np.linalg.inv(_mat(z)) @ np.linalg.inv(_mat(xi)) @ _mat(xj))


def _gtsam_solve(poses, ei, ej, meas, info, fixed, robust=None):
    graph, values = gtsam.NonlinearFactorGraph(), gtsam.Values()
    for k, x in enumerate(poses):
        values.insert(k, gtsam.Pose2(*x))
    for k in np.flatnonzero(fixed):
        graph.add(gtsam.NonlinearEqualityPose2(int(k), gtsam.Pose2(*poses[k])))
    for n, (i, j, z, omega) in enumerate(zip(ei, ej, meas, info)):
        noise = gtsam.noiseModel.Gaussian.Information(omega)
        if robust is not None and robust[n] is not None:
            noise = gtsam.noiseModel.Robust.Create(robust[n], noise)
        graph.add(gtsam.BetweenFactorPose2(int(i), int(j), gtsam.Pose2(*z), noise))
    params = gtsam.LevenbergMarquardtParams()
    params.setRelativeErrorTol(1e-10)
    params.setAbsoluteErrorTol(1e-12)
    params.setMaxIterations(200)
    result = gtsam.LevenbergMarquardtOptimizer(graph, values, params).optimize()
    return np.array(
        [[result.atPose2(k).x(), result.atPose2(k).y(), result.atPose2(k).theta()] for k in range(len(poses))]
    )


def _pose_diff(a, b):
    d = np.asarray(a) - np.asarray(b)
    d[..., 2] = np.angle(np.exp(1j * d[..., 2]))
    return np.abs(d).max()


def test_edge_error_matches_matrix_form():
    rng = np.random.default_rng(0)
    x = rng.normal(size=(20, 3, 3)) * [2.0, 2.0, 3.0]
    ours = jax.jit(jax.vmap(edge_error))(*(jnp.asarray(x[:, k]) for k in range(3)))
    ref = np.array([_g2o_error_np(*row) for row in x])
    np.testing.assert_allclose(ours, ref, atol=2e-5)


@pytest.mark.parametrize("kind", [ROBUST_HUBER, ROBUST_CAUCHY])
def test_robust_weight_is_derivative_of_rho(kind):
    with jax.enable_x64(True):
        s = jnp.linspace(0.01, 30.0, 50)
        k = jnp.full(50, kind)
        rho, w = _rho_and_weight(s, k, 2.0)
        h = 1e-6
        fd = (_rho_and_weight(s + h, k, 2.0)[0] - _rho_and_weight(s - h, k, 2.0)[0]) / (2 * h)
        np.testing.assert_allclose(w, fd, rtol=1e-6)
        assert np.all(rho <= s + 1e-12)


def test_matches_gtsam_on_manhattan_graph():
    sg = manhattan_graph(400, seed=5)
    fixed = np.arange(400) == 0
    with jax.enable_x64(True):
        g = build_graph(sg.initial, sg.edge_i, sg.edge_j, sg.measurement, sg.information)
        out, info = _optimize(g, SolverParams(relative_tol=jnp.asarray(1e-10)))
        ref = _gtsam_solve(sg.initial, sg.edge_i, sg.edge_j, sg.measurement, sg.information, fixed)
        assert bool(info.converged) and float(info.final_chi2) < 1e-2 * float(info.initial_chi2)
        assert _pose_diff(out.poses, ref) < 1e-5
        np.testing.assert_allclose(float(info.final_chi2), float(chi2(g, jnp.asarray(ref))), rtol=1e-7)
        # An independent chi2: the NumPy error at our poses.
        p = np.asarray(out.poses)
        e = np.array([_g2o_error_np(p[i], p[j], z) for i, j, z in zip(sg.edge_i, sg.edge_j, sg.measurement)])
        np.testing.assert_allclose(float(info.final_chi2), np.einsum("ma,mab,mb", e, sg.information, e), rtol=1e-9)


def test_matches_scipy_least_squares_with_two_fixed_nodes():
    # A noisy 6 x 6 grid: every node joined to its right and upper neighbour, correlated information.
    rng = np.random.default_rng(1)
    xy = np.stack(np.meshgrid(np.arange(6.0), np.arange(6.0)), -1).reshape(-1, 2)
    truth = np.concatenate([xy, rng.uniform(-np.pi, np.pi, (36, 1))], 1)
    pairs = [(k, k + 1) for k in range(36) if k % 6 < 5] + [(k, k + 6) for k in range(30)]
    ei, ej = np.array(pairs).T
    L = np.array([[10.0, 0, 0], [2.0, 8.0, 0], [1.0, -1.0, 30.0]])
    info = np.broadcast_to(L @ L.T, (len(ei), 3, 3))
    meas = np.array([_g2o_error_np(np.zeros(3), np.zeros(3), np.zeros(3)) for _ in ei])  # placeholder zeros
    meas = np.array([np.linalg.inv(_mat(truth[i])) @ _mat(truth[j]) for i, j in pairs])
    meas = np.stack([meas[:, 0, 2], meas[:, 1, 2], np.arctan2(meas[:, 1, 0], meas[:, 0, 0])], 1)
    meas = meas + rng.normal(size=meas.shape) * [0.1, 0.1, 0.05]
    init = truth + rng.normal(size=truth.shape) * [0.2, 0.2, 0.1]
    fixed = np.isin(np.arange(36), [0, 35])
    sqrt_info = np.linalg.cholesky(info[0]).T  # sqrt_info^T sqrt_info = Omega

    free = np.flatnonzero(~fixed)

    def residuals(v):
        p = init.copy()
        p[free] = v.reshape(-1, 3)
        return np.concatenate([sqrt_info @ _g2o_error_np(p[i], p[j], z) for i, j, z in zip(ei, ej, meas)])

    ref = least_squares(residuals, init[free].ravel(), xtol=1e-14, ftol=1e-14, gtol=1e-14)
    with jax.enable_x64(True):
        g = build_graph(init, ei, ej, meas, info, fixed=fixed)
        out, info_ = _optimize(g, SolverParams(relative_tol=jnp.asarray(1e-12)))
        p = np.asarray(out.poses)
        assert np.array_equal(p[fixed], init[fixed])
        assert _pose_diff(p[free], ref.x.reshape(-1, 3)) < 1e-6
        np.testing.assert_allclose(float(info_.final_chi2), 2 * ref.cost, rtol=1e-8)


def test_robust_kernels_reject_wrong_loop_closures():
    sg = manhattan_graph(200, seed=3, n_outliers=10)
    closure = np.abs(sg.edge_j - sg.edge_i) != 1
    keep = ~sg.outlier
    with jax.enable_x64(True):
        clean = _optimize(
            build_graph(sg.initial, sg.edge_i[keep], sg.edge_j[keep], sg.measurement[keep], sg.information[keep]),
            SolverParams(),
        )[0].poses
        plain = _optimize(
            build_graph(sg.initial, sg.edge_i, sg.edge_j, sg.measurement, sg.information), SolverParams()
        )[0].poses
        kinds = np.where(closure, "cauchy", "none")
        g = build_graph(sg.initial, sg.edge_i, sg.edge_j, sg.measurement, sg.information, robust=kinds)
        robust, _ = _optimize(g, SolverParams(robust_width=jnp.asarray(3.0), relative_tol=jnp.asarray(1e-10)))
        assert _pose_diff(plain, clean) > 3.0  # wrong closures pull the plain solution far off
        # Cauchy keeps a small pull (weight d^2 / s) from the wrong closures: near, not equal to, clean.
        assert _pose_diff(robust.poses, clean) < 0.15
        # GTSAM with the same Cauchy kernel (its rho is half of g2o's: the same minimizer) agrees up to the
        # wrong closures' large errors, where GTSAM's Logmap error and g2o's differ (1 cm measured).
        cauchy = gtsam.noiseModel.mEstimator.Cauchy.Create(3.0)
        ref = _gtsam_solve(
            sg.initial,
            sg.edge_i,
            sg.edge_j,
            sg.measurement,
            sg.information,
            np.arange(200) == 0,
            robust=[cauchy if c else None for c in closure],
        )
        assert _pose_diff(robust.poses, ref) < 0.03


def test_vmap_over_padded_graphs_equals_each_alone():
    sizes = [(60, 1), (90, 2), (120, 3)]
    graphs = [manhattan_graph(n, seed=s) for n, s in sizes]
    n_cap, m_cap = 128, max(len(g.edge_i) for g in graphs) + 5
    with jax.enable_x64(True):
        padded = [
            build_graph(
                g.initial, g.edge_i, g.edge_j, g.measurement, g.information, node_capacity=n_cap, edge_capacity=m_cap
            )
            for g in graphs
        ]
        params = SolverParams(relative_tol=jnp.asarray(1e-10))
        batch, infos = jax.jit(jax.vmap(optimize, in_axes=(0, None)))(stack_graphs(padded), params)
        for k, (g, (n, _)) in enumerate(zip(graphs, sizes)):
            alone, info = _optimize(build_graph(g.initial, g.edge_i, g.edge_j, g.measurement, g.information), params)
            assert _pose_diff(batch.poses[k, :n], alone.poses) < 1e-7
            np.testing.assert_allclose(float(infos.final_chi2[k]), float(info.final_chi2), rtol=1e-9)
            assert bool(infos.converged[k])
            assert np.all(np.asarray(batch.poses[k, n:]) == 0.0)  # padded slots stay untouched


def test_tridiagonal_preconditioner_solves_exactly():
    rng = np.random.default_rng(2)
    n = 9
    U = rng.normal(size=(n, 3, 3))
    U[0] = 0.0
    U[4] = 0.0  # a chain break
    T = np.zeros((3 * n, 3 * n))
    for k in range(1, n):
        T[3 * (k - 1) : 3 * k, 3 * k : 3 * k + 3] = U[k]
        T[3 * k : 3 * k + 3, 3 * (k - 1) : 3 * k] = U[k].T
    G = rng.normal(size=(n, 3, 3))
    D = G @ np.swapaxes(G, 1, 2) + 8.0 * np.eye(3)  # diagonally dominant: T is positive definite
    for k in range(n):
        T[3 * k : 3 * k + 3, 3 * k : 3 * k + 3] = D[k]
    r = rng.normal(size=(n, 3))
    with jax.enable_x64(True):
        z = jax.jit(lambda D, U, r: chain_precond.solve(chain_precond.factor(D, U), r))(D, U, r)
    np.testing.assert_allclose(np.asarray(z).ravel(), np.linalg.solve(T, r.ravel()), rtol=1e-10, atol=1e-12)


def test_tridiagonal_factor_calls_no_linear_algebra_library():
    # Each scan step is elementwise arithmetic: a LAPACK / cuSolver call per step (as jnp.linalg.inv makes) was
    # a kernel launch per step and made the factor ~25 x slower for 100 robots on a GPU.
    D = jnp.tile(4.0 * jnp.eye(3), (16, 1, 1))
    hlo = jax.jit(chain_precond.factor).lower(D, 0.5 * D).as_text()
    assert "custom_call" not in hlo
    assert "custom_call" in jax.jit(jnp.linalg.inv).lower(D[0]).as_text()  # the check sees library calls


def test_preconditioners_reach_the_same_optimum():
    sg = manhattan_graph(150, seed=8)
    with jax.enable_x64(True):
        g = build_graph(sg.initial, sg.edge_i, sg.edge_j, sg.measurement, sg.information)
        outs = [
            jax.jit(optimize)(
                g, SolverParams(relative_tol=jnp.asarray(1e-10), cg_tol=jnp.asarray(1e-8), preconditioner=pc)
            )
            for pc in ("chain", "block_jacobi")
        ]
        assert _pose_diff(outs[0][0].poses, outs[1][0].poses) < 1e-7
        assert int(outs[0][1].cg_iterations) < int(outs[1][1].cg_iterations)


def _dense_relative_covariance(poses, ei, ej, info, fixed, i, j, meas=None, h=1e-6):
    """J H^-1 J^T by NumPy: central finite differences of the g2o errors (default measurements: the poses' own
    relative poses, so every error is zero) in additive perturbations of the free nodes, and a dense inverse."""
    free = np.flatnonzero(~fixed)
    col = {k: n for n, k in enumerate(free)}
    if meas is None:
        meas = [_pose_of(np.linalg.inv(_mat(poses[a])) @ _mat(poses[b])) for a, b in zip(ei, ej)]

    def jac(f, x):
        out = []
        for d in range(3):
            step = np.zeros(3)
            step[d] = h
            out.append((f(x + step) - f(x - step)) / (2 * h))
        return np.stack(out, 1)

    H = np.zeros((3 * len(free), 3 * len(free)))
    for a, b, z, omega in zip(ei, ej, meas, info):
        blocks = {}
        if a in col:
            blocks[a] = jac(lambda x, b=b, z=z: _g2o_error_np(x, poses[b], z), poses[a])
        if b in col:
            blocks[b] = jac(lambda x, a=a, z=z: _g2o_error_np(poses[a], x, z), poses[b])
        for p, Jp in blocks.items():
            for q, Jq in blocks.items():
                H[3 * col[p] : 3 * col[p] + 3, 3 * col[q] : 3 * col[q] + 3] += Jp.T @ omega @ Jq
    z_ij = _pose_of(np.linalg.inv(_mat(poses[i])) @ _mat(poses[j]))
    J = np.zeros((3, 3 * len(free)))
    if i in col:
        J[:, 3 * col[i] : 3 * col[i] + 3] = jac(lambda x: _g2o_error_np(x, poses[j], z_ij), poses[i])
    if j in col:
        J[:, 3 * col[j] : 3 * col[j] + 3] = jac(lambda x: _g2o_error_np(poses[i], x, z_ij), poses[j])
    return J @ np.linalg.solve(H, J.T)


def test_relative_covariance_equals_a_dense_inverse_and_the_chain_without_loops():
    """The whole graph's covariance of node j in node i's frame against NumPy's dense J H^-1 J^T; on a chain alone it
    is the links' covariances compounded (`slam.consistency.chain_covariance`'s closed form); a loop edge between the
    two nodes narrows it; `when` false gives zeros."""
    rng = np.random.default_rng(3)
    n = 30
    T = [np.eye(3)]
    for _ in range(n - 1):
        T.append(T[-1] @ _mat([rng.uniform(0.2, 0.5), rng.uniform(-0.1, 0.1), rng.uniform(-0.4, 0.4)]))
    poses = np.array([_pose_of(t) for t in T])
    chain_i, chain_j = np.arange(n - 1), np.arange(1, n)
    loops_i, loops_j = np.array([2, 5, 12]), np.array([20, 27, 25])

    def spd(k):
        A = rng.normal(size=(k, 3, 3)) * 0.3
        return A @ np.swapaxes(A, 1, 2) + np.diag([4.0, 4.0, 20.0])

    chain_info, loop_info = spd(n - 1), spd(3)
    fixed = np.arange(n) == 0
    params = SolverParams(cg_tol=jnp.asarray(1e-12))
    cov = jax.jit(relative_covariance)
    with jax.enable_x64(True):
        for ei, ej, info in (
            (chain_i, chain_j, chain_info),
            (np.r_[chain_i, loops_i], np.r_[chain_j, loops_j], np.r_[chain_info, loop_info]),
        ):
            meas = np.array([_pose_of(np.linalg.inv(T[a]) @ T[b]) for a, b in zip(ei, ej)])
            g = build_graph(poses, ei, ej, meas, info, fixed=fixed, edge_capacity=len(ei) + 4)
            for i, j in ((0, 9), (3, 24), (21, 6)):
                ours = np.asarray(cov(g, jnp.asarray(i), jnp.asarray(j), params))
                ref = _dense_relative_covariance(poses, ei, ej, info, fixed, i, j)
                np.testing.assert_allclose(ours, ref, rtol=1e-5, atol=1e-9)
            assert not np.any(np.asarray(cov(g, jnp.asarray(3), jnp.asarray(24), params, jnp.asarray(False))))
        # Chain alone: the links' covariances moved into node j's frame and summed (node i's own link left out).
        with_loops = np.asarray(cov(g, jnp.asarray(3), jnp.asarray(24), params))
        i, j = 3, 24
        compounded = np.zeros((3, 3))
        for k in range(i + 1, j + 1):
            T_j_k = np.linalg.inv(T[j]) @ T[k]
            R, t = T_j_k[:2, :2], T_j_k[:2, 2]
            Ad = np.eye(3)
            Ad[:2, :2], Ad[:2, 2] = R, [t[1], -t[0]]
            compounded += Ad @ np.linalg.inv(chain_info[k - 1]) @ Ad.T
        meas = np.array([_pose_of(np.linalg.inv(T[a]) @ T[b]) for a, b in zip(chain_i, chain_j)])
        g = build_graph(poses, chain_i, chain_j, meas, chain_info, fixed=fixed)
        chain_only = np.asarray(cov(g, jnp.asarray(i), jnp.asarray(j), params))
        np.testing.assert_allclose(chain_only, compounded, rtol=1e-5, atol=1e-9)
        assert np.all(np.linalg.eigvalsh(chain_only - with_loops) > 0)  # the loops tie the two nodes tighter
        # Errors off zero, and robust (Cauchy) edges counted at their full information, as a chain's links are.
        ei, ej = np.r_[chain_i, loops_i], np.r_[chain_j, loops_j]
        info = np.r_[chain_info, loop_info]
        meas = np.array([_pose_of(np.linalg.inv(T[a]) @ T[b]) for a, b in zip(ei, ej)]) + rng.normal(0, 0.05, (32, 3))
        g = build_graph(poses, ei, ej, meas, info, fixed=fixed, robust="cauchy")
        ref = _dense_relative_covariance(poses, ei, ej, info, fixed, 3, 24, meas)
        np.testing.assert_allclose(np.asarray(cov(g, jnp.asarray(3), jnp.asarray(24), params)), ref, rtol=1e-5)
    # float32 with the solver's defaults (the online SLAM's): within 2 % of the dense float64 reference.
    g = build_graph(poses, ei, ej, meas, info, fixed=fixed, dtype=jnp.float32)
    ref = _dense_relative_covariance(poses, ei, ej, info, fixed, 3, 24)
    got = np.asarray(cov(g, jnp.asarray(3), jnp.asarray(24), SolverParams()), np.float64)
    assert np.all(np.abs(got - ref) <= 0.02 * np.sqrt(np.outer(np.diag(ref), np.diag(ref)))), (got, ref)
