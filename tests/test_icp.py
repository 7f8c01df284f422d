"""Point-to-plane ICP (kernels.icp) against depth rendered by the project's caster and a NumPy loop."""

from __future__ import annotations

import dataclasses
import functools

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy.linalg import expm
from scipy.spatial.transform import Rotation

from jaxquad.kernels import icp, icp_pass
from jaxquad.kernels.raycast import Boxes, cast_depth, pinhole_rays

H, W, LEVELS, ITERS = 30, 40, 2, (4, 6)
K = np.array([[21.0, 0.0, 19.5], [0.0, 21.0, 14.5], [0.0, 0.0, 1.0]])  # ~87 deg horizontal FOV
R_WORLD_CAM0 = np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]])  # optical axis along world +x


def _boxes(spec) -> Boxes:
    a = np.asarray(spec, np.float32)
    return Boxes(
        center=jnp.asarray(a[:, 0:3]),
        half=jnp.asarray(a[:, 3:6]),
        yaw=jnp.asarray(a[:, 6]),
    )


# A room 6 x 5 m with two boxes and a slanted one: constrains all six degrees of freedom.
ROOM = _boxes(
    [
        [3.0, 0, 1, 0.1, 2.5, 1, 0],
        [0.5, 2.5, 1, 3, 0.1, 1, 0],
        [0.5, -2.5, 1, 3, 0.1, 1, 0],
        [2.0, 0.8, 0.3, 0.3, 0.3, 0.3, 0.4],
        [1.8, -1.0, 0.5, 0.2, 0.4, 0.5, -0.3],
    ]
)
# A long corridor along x (walls at y = +-1, no end within range) without a floor: sliding along x is free.
CORRIDOR = _boxes([[0.0, 1.1, 1, 50, 0.1, 1, 0], [0.0, -1.1, 1, 50, 0.1, 1, 0]])


def _render(T_world_cam: np.ndarray, boxes: Boxes, floor_z: float) -> jnp.ndarray:
    rays = jnp.asarray(pinhole_rays(K, H, W))
    d = cast_depth(
        jnp.asarray(T_world_cam[:3, 3], jnp.float32),
        jnp.asarray(T_world_cam[:3, :3], jnp.float32),
        rays,
        boxes,
        floor_z,
    )
    return jnp.where(jnp.isfinite(d) & (d < 8.0), d, 0.0)


def _pose(rotvec, t) -> np.ndarray:
    T = np.eye(4)
    T[:3, :3] = Rotation.from_rotvec(rotvec).as_matrix()
    T[:3, 3] = t
    return T


# Noise-free 40 x 30 images (pixels 4x the size of the 160 x 120 camera's): no smoothing, whose 5 x 5
# window would here span whole box faces and round their creases.
RAW = dataclasses.replace(icp.IcpParams.default(), smooth_radius=0)

T_WORLD_CAM0 = _pose(Rotation.from_matrix(R_WORLD_CAM0).as_rotvec(), [0.0, 0.0, 0.35])


@functools.cache
def _align_fn():
    def run(ref_depth, cur_depth, T_init, T_guess, params):
        ref = icp.depth_frame(ref_depth, jnp.asarray(K, jnp.float32), LEVELS, params)
        cur = icp.depth_frame(cur_depth, jnp.asarray(K, jnp.float32), LEVELS, params)
        return icp.align(ref, cur, jnp.asarray(K, jnp.float32), T_init, T_guess, params, ITERS)

    return jax.jit(run)


def _f32(x):
    return jnp.asarray(x, jnp.float32)


def test_recovers_known_motion_in_a_room():
    T_delta = _pose([0.01, -0.03, 0.02], [0.04, -0.02, 0.06])  # cam0 -> cam1, in cam0's frame
    ref = _render(T_WORLD_CAM0, ROOM, 0.0)
    cur = _render(T_WORLD_CAM0 @ T_delta, ROOM, 0.0)
    params = eqx.tree_at(lambda p: (p.rot_prior_weight, p.trans_prior_weight), RAW, (_f32(0.0),) * 2)
    out = _align_fn()(ref, cur, _f32(np.eye(4)), _f32(np.eye(4)), params)
    T = np.asarray(out.T_ref_cur, np.float64)
    assert np.linalg.norm(T[:3, 3] - T_delta[:3, 3]) < 5e-3
    assert np.linalg.norm(Rotation.from_matrix(T[:3, :3].T @ T_delta[:3, :3]).as_rotvec()) < 2e-3
    assert out.n_inliers > 0.6 * out.n_valid and out.rmse < 2e-3 and out.min_eig > 1e-3
    # Under vmap: the same result for a batch of two.
    batched = jax.vmap(_align_fn(), in_axes=(None, 0, None, None, None))(
        ref, jnp.stack([cur, cur]), _f32(np.eye(4)), _f32(np.eye(4)), params
    )
    np.testing.assert_allclose(np.asarray(batched.T_ref_cur[1]), np.asarray(out.T_ref_cur), atol=1e-5)


def test_rotation_prior_pulls_towards_the_gyro():
    # With a huge prior weight the rotation is the prior's, whatever the geometry says.
    T_delta = _pose([0.0, 0.02, 0.0], [0.05, 0.0, 0.0])
    ref, cur = (
        _render(T_WORLD_CAM0, ROOM, 0.0),
        _render(T_WORLD_CAM0 @ T_delta, ROOM, 0.0),
    )
    T_guess = _pose([0.0, 0.05, 0.0], [0.0, 0.0, 0.0])
    params = eqx.tree_at(lambda p: p.rot_prior_weight, RAW, _f32(1e9))
    out = _align_fn()(ref, cur, _f32(np.eye(4)), _f32(T_guess), params)
    R = np.asarray(out.T_ref_cur[:3, :3], np.float64)
    assert np.linalg.norm(Rotation.from_matrix(R.T @ T_guess[:3, :3]).as_rotvec()) < 1e-3


@pytest.mark.parametrize("scene", ["plane", "corridor"])
def test_degenerate_scenes_have_a_small_eigenvalue(scene):
    if scene == "plane":  # looking down at an open floor: only 3 of 6 directions constrained
        T, boxes, floor = (
            T_WORLD_CAM0 @ _pose([-0.6, 0, 0], [0, 0, 0]),
            _boxes([[0, 0, -9, 0.1, 0.1, 0.1, 0]]),
            0.0,
        )
    else:
        T, boxes, floor = T_WORLD_CAM0, CORRIDOR, -100.0
    ref = _render(T, boxes, floor)
    good = _align_fn()(
        _render(T_WORLD_CAM0, ROOM, 0.0),
        _render(T_WORLD_CAM0, ROOM, 0.0),
        _f32(np.eye(4)),
        _f32(np.eye(4)),
        RAW,
    )
    out = _align_fn()(ref, ref, _f32(np.eye(4)), _f32(np.eye(4)), RAW)
    assert out.n_inliers > 100
    assert out.min_eig < 1e-4 * good.min_eig
    if scene == "corridor":  # translation along the corridor (camera z) is unconstrained
        H_ = np.asarray(out.H, np.float64)
        assert H_[2, 2] < 1e-4 * np.trace(H_)


def _normals_ref(P, valid, max_jump, fx):
    h, w, _ = P.shape
    N, ok = np.zeros_like(P), np.zeros((h, w), bool)
    for v in range(1, h - 1):
        for u in range(1, w - 1):
            nb = [
                (v, u + 1),
                (v, u - 1),
                (v + 1, u),
                (v - 1, u),
            ]  # right, left, down, up
            z, gate = P[v, u, 2], max_jump / fx * max(P[v, u, 2], 1e-3)
            if not valid[v, u] or not all(valid[a] and abs(P[a][2] - z) < gate for a in nb):
                continue
            n1 = np.cross(P[nb[0]] - P[v, u], P[nb[2]] - P[v, u])
            n2 = np.cross(P[nb[1]] - P[v, u], P[nb[3]] - P[v, u])
            n1, n2 = n1 / np.linalg.norm(n1), n2 / np.linalg.norm(n2)
            if n1 @ n2 <= icp.NORMAL_AGREEMENT_COS:
                continue
            n = (n1 + n2) / np.linalg.norm(n1 + n2)
            N[v, u], ok[v, u] = (-n if n @ P[v, u] > 0 else n), True
    return N, ok


def _smooth_ref(depth, radius, gate):
    """Edge-aware local plane fit of inverse depth: a loop over pixels, numpy.linalg.lstsq per window."""
    h, w = depth.shape
    out = depth.copy()
    for v in range(h):
        for u in range(w):
            z = depth[v, u]
            if not z > 0:
                continue
            rows, rhs = [], []
            for dv in range(-radius, radius + 1):
                for du in range(-radius, radius + 1):
                    a, c = v + dv, u + du
                    if not (0 <= a < h and 0 <= c < w) or not depth[a, c] > 0:
                        continue
                    if abs(depth[a, c] - z) <= gate * z * max(abs(dv), abs(du)):
                        rows.append([1.0, du, dv])
                        rhs.append(1.0 / depth[a, c])
            A = np.asarray(rows)
            if len(rows) >= 3 and np.linalg.matrix_rank(A) == 3:
                out[v, u] = 1.0 / np.linalg.lstsq(A, np.asarray(rhs), rcond=None)[0][0]
    return out


def _gn_step_ref(T, T_g, cur_depth, ref_depth, Kl, p, radius, up):
    """One Gauss-Newton step written as loops over pixels, from the module docstring's formulas."""

    def points(depth):
        depth = _smooth_ref(depth, radius, p["max_normal_jump"] / Kl[0, 0])
        h, w = depth.shape
        P = np.zeros((h, w, 3))
        for v in range(h):
            for u in range(w):
                z = depth[v, u]
                P[v, u] = [
                    (u - Kl[0, 2]) / Kl[0, 0] * z,
                    (v - Kl[1, 2]) / Kl[1, 1] * z,
                    z,
                ]
        return P, depth > 0

    Pc, vc = points(cur_depth)
    Pr, vr = points(ref_depth)
    Nr, okr = _normals_ref(Pr, vr, p["max_normal_jump"], Kl[0, 0])
    h, w = ref_depth.shape
    A, b = np.zeros((6, 6)), np.zeros(6)
    for v in range(h):
        for u in range(w):
            if not vc[v, u]:
                continue
            q = T[:3, :3] @ Pc[v, u] + T[:3, 3]
            if q[2] <= 1e-3:
                continue
            uu, vv = (
                np.round(Kl[0, 0] * q[0] / q[2] + Kl[0, 2]),
                np.round(Kl[1, 1] * q[1] / q[2] + Kl[1, 2]),
            )
            if not (0 <= uu <= w - 1 and 0 <= vv <= h - 1) or not okr[int(vv), int(uu)]:
                continue
            d = q - Pr[int(vv), int(uu)]
            if d @ d >= p["max_dist"] ** 2:
                continue
            n = Nr[int(vv), int(uu)]
            r = n @ d
            wt = 1.0 if abs(r) <= p["huber_k"] else p["huber_k"] / abs(r)
            J = np.concatenate([n, np.cross(q, n)])
            A += wt * np.outer(J, J)
            b += wt * J * r
    t = T[:3, 3]
    S = np.array([[0, -t[2], t[1]], [t[2], 0, -t[0]], [-t[1], t[0], 0]])
    J_t = np.hstack([np.eye(3), -S])
    J_r = np.hstack([np.zeros((3, 3)), np.eye(3)])
    e_r = Rotation.from_matrix(T[:3, :3] @ T_g[:3, :3].T).as_rotvec()
    A += p["trans_prior_weight"] * J_t.T @ J_t + p["rot_prior_weight"] * J_r.T @ J_r + p["damping"] * np.eye(6)
    b += p["trans_prior_weight"] * J_t.T @ (t - T_g[:3, 3]) + p["rot_prior_weight"] * J_r.T @ e_r
    u = T[:3, :3] @ up[1]  # tilt prior: d(exp(w) u)/dw = -[u]_x
    J_u = np.hstack([np.zeros((3, 3)), -np.array([[0, -u[2], u[1]], [u[2], 0, -u[0]], [-u[1], u[0], 0]])])
    A += p["tilt_prior_weight"] * J_u.T @ J_u
    b += p["tilt_prior_weight"] * J_u.T @ (u - up[0])
    xi = -np.linalg.solve(A, b)
    X = np.zeros((4, 4))
    X[:3, :3] = np.array([[0, -xi[5], xi[4]], [xi[5], 0, -xi[3]], [-xi[4], xi[3], 0]])
    X[:3, 3] = xi[:3]
    return expm(X) @ T


def test_gauss_newton_step_equals_numpy_loop():
    rng = np.random.default_rng(3)
    h, w = 12, 16
    Kl = np.array([[10.0, 0, 7.3], [0, 10.5, 5.6], [0, 0, 1]])
    uu, vv = np.meshgrid(np.arange(w), np.arange(h))
    ref_depth = 2.0 + 0.3 * np.sin(0.4 * uu) + 0.2 * np.cos(0.5 * vv) + 0.0005 * rng.standard_normal((h, w))
    cur_depth = ref_depth + 0.02 * rng.standard_normal((h, w))
    ref_depth[rng.random((h, w)) < 0.03] = 0.0
    cur_depth[rng.random((h, w)) < 0.1] = 0.0
    T = _pose(rng.normal(0, 0.02, 3), rng.normal(0, 0.03, 3))
    T_g = _pose(rng.normal(0, 0.02, 3), rng.normal(0, 0.03, 3))
    p = {
        "max_dist": 0.3,
        "huber_k": 0.015,
        "rot_prior_weight": 50.0,
        "trans_prior_weight": 20.0,
        "tilt_prior_weight": 30.0,
        "damping": 1e-3,
        "max_normal_jump": 2.0,
    }
    up = np.stack([Rotation.from_rotvec(rng.normal(0, 0.1, 3)).as_matrix()[:, 1] for _ in range(2)])
    expected = _gn_step_ref(T, T_g, cur_depth, ref_depth, Kl, p, 1, up)
    with jax.enable_x64(True):
        params = icp.IcpParams(**{k: jnp.asarray(v, jnp.float64) for k, v in p.items()}, smooth_radius=1)
        cur = icp.depth_frame(jnp.asarray(cur_depth), jnp.asarray(Kl), 1, params)[0]
        ref = icp.depth_frame(jnp.asarray(ref_depth), jnp.asarray(Kl), 1, params)[0]
        got, ne = jax.jit(icp.gauss_newton_step)(
            jnp.asarray(T), jnp.asarray(T_g), cur, ref, jnp.asarray(Kl), params, jnp.asarray(up)
        )
        assert ne.n_inliers > 50
        np.testing.assert_allclose(np.asarray(got), expected, atol=1e-9)


def test_smooth_depth_equals_numpy_loop_keeps_planes_and_averages_noise():
    rng = np.random.default_rng(4)
    # A loop over pixels on a random image with holes and depth edges.
    depth = rng.uniform(1.0, 3.0, (9, 11))
    depth[rng.random(depth.shape) < 0.1] = 0.0
    with jax.enable_x64(True):
        got = jax.jit(icp.smooth_depth, static_argnums=1)(jnp.asarray(depth), 2, jnp.asarray(0.2))
        np.testing.assert_allclose(np.asarray(got), _smooth_ref(depth, 2, 0.2), rtol=1e-12)
    # A slanted wall rendered by the caster: inverse depth is affine on a plane, so the mean keeps it.
    T = T_WORLD_CAM0 @ _pose([0.0, 0.5, 0.0], [0.0, 0.0, 0.0])
    wall = np.asarray(_render(T, _boxes([[3.0, 0, 1, 0.1, 9, 9, 0]]), -100.0), np.float64)
    fx = float(icp.IcpParams.default().max_normal_jump) / K[0, 0]
    with jax.enable_x64(True):
        smooth = np.asarray(jax.jit(icp.smooth_depth, static_argnums=1)(jnp.asarray(wall), 2, fx))
    assert np.all(wall > 0)
    np.testing.assert_allclose(smooth, wall, rtol=1e-6)  # borders included (a fit, not a mean); float32 render
    inner = (slice(2, -2), slice(2, -2))
    # With noise of std k z^2 (inverse-depth std k), the mean of 25 pixels has 1/5 of the noise.
    noisy = wall + 0.01 * wall**2 * rng.standard_normal(wall.shape)
    smooth = np.asarray(jax.jit(icp.smooth_depth, static_argnums=1)(jnp.asarray(noisy, jnp.float32), 2, _f32(fx)))
    ratio = np.std((smooth - wall)[inner] / wall[inner] ** 2) / np.std((noisy - wall)[inner] / wall[inner] ** 2)
    assert 0.15 < ratio < 0.3, ratio


def test_tilt_prior_gradient_matches_finite_differences():
    rng = np.random.default_rng(5)
    R = Rotation.from_rotvec(rng.normal(0, 0.3, 3)).as_matrix()
    up = np.stack([Rotation.from_rotvec(rng.normal(0, 0.3, 3)).as_matrix()[:, 2] for _ in range(2)])
    T = np.eye(4)
    T[:3, :3] = R
    params = eqx.tree_at(
        lambda p: (p.rot_prior_weight, p.trans_prior_weight, p.tilt_prior_weight),
        icp.IcpParams.default(),
        (jnp.asarray(0.0), jnp.asarray(0.0), jnp.asarray(7.0)),
    )
    with jax.enable_x64(True):
        H, b = jax.jit(icp.prior_terms)(jnp.asarray(T), jnp.asarray(T), params, jnp.asarray(up))

    def cost(w):  # 0.5 w_u |exp(w) R u_cur - u_ref|^2 under a left rotation w
        return 0.5 * 7.0 * np.sum((expm(np.cross(np.eye(3), w)) @ R @ up[1] - up[0]) ** 2)

    eps = 1e-6
    grad = np.array([(cost(eps * e) - cost(-eps * e)) / (2 * eps) for e in np.eye(3)])
    np.testing.assert_allclose(np.asarray(b)[3:], grad, atol=1e-8)
    assert np.all(np.asarray(b)[:3] == 0.0) and np.all(np.asarray(H)[:3] == 0.0)
    # Blind to rotation about up: at a tilt-consistent pose, rotating about up changes nothing.
    T[:3, :3] = Rotation.align_vectors([up[0]], [up[1]])[0].as_matrix()
    with jax.enable_x64(True):
        H, b = jax.jit(icp.prior_terms)(jnp.asarray(T), jnp.asarray(T), params, jnp.asarray(up))
    np.testing.assert_allclose(np.asarray(b), 0.0, atol=1e-12)
    np.testing.assert_allclose(np.asarray(H)[3:, 3:] @ up[0], 0.0, atol=1e-12)


def test_gradients_wrt_thresholds_and_weights_are_finite():
    T_delta = _pose([0.0, 0.02, 0.0], [0.05, 0.0, 0.02])
    ref, cur = (
        _render(T_WORLD_CAM0, ROOM, 0.0),
        _render(T_WORLD_CAM0 @ T_delta, ROOM, 0.0),
    )
    Kj = _f32(K)

    def loss(params):
        r = icp.depth_frame(ref, Kj, 1, params)[0]
        c = icp.depth_frame(cur, Kj, 1, params)[0]
        T, ne = icp.gauss_newton_step(_f32(np.eye(4)), _f32(np.eye(4)), c, r, Kj, params)
        return jnp.sum((T[:3, 3] - _f32(T_delta[:3, 3])) ** 2) + 1e-3 * ne.sq_residual

    params = eqx.tree_at(lambda p: p.trans_prior_weight, icp.IcpParams.default(), _f32(1.0))
    g = jax.jit(jax.grad(loss))(params)
    leaves = jax.tree.leaves(g)
    assert all(np.all(np.isfinite(np.asarray(x))) for x in leaves)
    assert float(jnp.abs(g.huber_k)) > 0 and float(jnp.abs(g.rot_prior_weight)) > 0


def test_smoothing_recovers_motion_from_noisy_depth():
    # The simulated camera's resolution and noise (std 0.01 z^2, as a D435 at 2 m): single-pixel normals
    # are noise, and the smoothed pyramid recovers the motion several times better (here 18 -> 5 mm of 75 mm).
    w, h = 160, 120
    K160 = np.array([[87.0, 0.0, 79.5], [0.0, 87.0, 59.5], [0.0, 0.0, 1.0]])
    rays = jnp.asarray(pinhole_rays(K160, h, w))
    T_delta = _pose([0.01, -0.03, 0.02], [0.04, -0.02, 0.06])
    rng = np.random.default_rng(6)
    depth = []
    for T in (T_WORLD_CAM0, T_WORLD_CAM0 @ T_delta):
        d = np.asarray(cast_depth(_f32(T[:3, 3]), _f32(T[:3, :3]), rays, ROOM, 0.0), np.float64)
        d = np.where(np.isfinite(d) & (d < 8.0), d, 0.0)
        depth.append(_f32(np.where(d > 0, d + 0.01 * d**2 * rng.standard_normal(d.shape), 0.0)))
    Kj = _f32(K160)

    @jax.jit
    def run(params):
        ref, cur = (icp.depth_frame(d, Kj, 2, params) for d in depth)
        return icp.align(ref, cur, Kj, _f32(np.eye(4)), _f32(np.eye(4)), params, (2, 4)).T_ref_cur

    free = eqx.tree_at(lambda p: (p.rot_prior_weight, p.trans_prior_weight), icp.IcpParams.default(), (_f32(0.0),) * 2)
    err = {}
    for radius in (0, 2):
        T = np.asarray(run(dataclasses.replace(free, smooth_radius=radius)), np.float64)
        err[radius] = np.linalg.norm(T[:3, 3] - T_delta[:3, 3])
    assert err[2] < 5e-3 and err[2] < 0.5 * err[0], err


def test_gpu_and_cpu_forms_agree():
    """The per-platform forms (`jax.lax.platform_dependent`): neighbours by slices of padded images
    against `jnp.roll` (exact); the point-to-plane pass's GPU kernel, run in Pallas's interpreter,
    against the CPU's matrix products (which `test_gauss_newton_step_equals_numpy_loop` checks), batched
    over poses, and its derivatives."""
    rng = np.random.default_rng(3)
    P = tuple(jnp.asarray(rng.normal(size=(12, 17)), jnp.float32) for _ in range(3))
    valid = jnp.asarray(rng.random((12, 17)) < 0.8)
    gate = jnp.asarray(rng.uniform(0.5, 2.0, (12, 17)), jnp.float32)
    d_roll, ok_roll = jax.jit(icp._neighbours_by_roll)(P, valid, gate)
    d_slice, ok_slice = jax.jit(icp._neighbours_by_slices)(P, valid, gate)
    np.testing.assert_array_equal(np.asarray(ok_slice), np.asarray(ok_roll))
    assert 0 < int(ok_roll.sum()) < ok_roll.size
    inner = (slice(1, -1), slice(1, -1))  # the border wraps around in one form and meets zeros in the other
    for name in d_roll:
        for a, b in zip(d_roll[name], d_slice[name]):
            np.testing.assert_array_equal(np.asarray(a)[inner], np.asarray(b)[inner])

    # 1,517 points: one full block of the kernel and a partial one.
    h, w = 37, 41
    uu, vv = np.meshgrid(np.arange(w), np.arange(h))
    ref_depth = 2.0 + 0.3 * np.sin(0.2 * uu) + 0.2 * np.cos(0.25 * vv)
    cur_depth = ref_depth + 0.01 * rng.standard_normal((h, w))
    cur_depth[rng.random((h, w)) < 0.1] = 0.0
    Kl = _f32([[30.0, 0, 19.3], [0, 31.5, 17.6], [0, 0, 1]])
    ref, cur = (icp.depth_frame(_f32(d), Kl, 1, RAW)[0].rows.reshape(-1, 8) for d in (ref_depth, cur_depth))

    poses = jnp.stack([_f32(_pose(rng.normal(0, 0.02, 3), rng.normal(0, 0.02, 3))) for _ in range(2)])
    by_kernel = jax.vmap(lambda s: icp_pass.sums_by_kernel(s, cur, ref, h, w, interpret=True))
    by_product = jax.vmap(lambda s: icp_pass.sums_by_product(s, cur, ref, h, w))
    s = jax.vmap(lambda T: icp_pass.pass_numbers(T, Kl, RAW.max_dist, RAW.huber_k))(poses)
    want = np.asarray(by_product(s))
    assert np.all(want[:, 27] > 500)  # inliers
    np.testing.assert_allclose(np.asarray(by_kernel(s)), want, rtol=1e-4, atol=1e-4 * np.abs(want).max())
    tangent = jnp.asarray(rng.normal(size=s.shape), jnp.float32)
    _, d_kernel = jax.jvp(by_kernel, (s,), (tangent,))
    _, d_product = jax.jvp(by_product, (s,), (tangent,))
    np.testing.assert_array_equal(np.asarray(d_kernel), np.asarray(d_product))
