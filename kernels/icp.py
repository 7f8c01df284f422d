"""Projective point-to-plane ICP between depth images, coarse to fine, with pose priors.

A depth frame is a pyramid of back-projected points and normals (`depth_frame`); level l keeps every
2^l-th pixel of the image, so its intrinsics are K scaled by 2^-l (`level_intrinsics`) and the
depths are exact (no averaging across depth edges). `align` estimates T_ref_cur, the current
camera in the reference camera's frame, by Gauss-Newton on

    sum_i rho(n_i . (T p_i - q_i)) + w_r |log(R R_g^T)|^2 + w_t |t - t_g|^2 + w_u |R u_cur - u_ref|^2

where p_i are the current points, q_i / n_i the reference point / normal at the pixel p_i projects
to (projective association), rho a Huber loss (iteratively reweighted), (R_g, t_g) a motion
guess: the rotation prior carries the gyro's integrated rotation, the translation prior the leg
odometry's motion where it is used; u_ref / u_cur are world up in the reference and current frames
(the latter from a gravity-referenced attitude), a prior on tilt alone that keeps chained relative
rotations from drifting in roll and pitch. The depth is first averaged (`smooth_depth`): a stereo
camera's depth noise (~2 % at 2 m) is larger than the pixel spacing, so normals from single pixels
point anywhere. Pose updates are left-multiplied: T <- exp(xi) T with
xi = (v, omega), so a residual's Jacobian is n^T [I, -[T p]_x] = [n, (T p) x n].

Static shapes everywhere (masks, never boolean indexing) and a fixed unrolled iteration count per
level, so one robot's alignment jits once and vmaps over a fleet.
"""

from __future__ import annotations

import functools

import equinox as eqx
import jax
import jax.numpy as jnp
from jaxtyping import Array, Bool, Float

from jaxquad.kernels import icp_pass
from jaxquad.kernels._small_linalg import spd_solve
from jaxquad.kernels.lie import SO3, se3_exp, skew

# Cosine of the largest angle between a pixel's two one-sided normals (about 18 deg).
NORMAL_AGREEMENT_COS = 0.95


class IcpParams(eqx.Module):
    """Tunable numbers of the alignment (traced leaves)."""

    max_dist: Float[Array, ""]  # association gate on |T p - q|, m
    huber_k: Float[Array, ""]  # Huber threshold on the point-to-plane residual, m
    # Prior weights are relative to point residuals in m^2 of weight 1 (~10,000 inliers at 160 x 120 after
    # smoothing). Chosen on simulated 20 s aggressive walks (Go2 and Badger, house and warehouse, 2 robots
    # each, true and estimated contacts): rotation 1e3 (1e4 changed nothing, 1e6-1e8 let the gyro's bias
    # through), translation 300 (0: the VO slides on open floor, 30: 3.7 % drift, 300: 3.2 %), tilt 1e3
    # (0: 3.2 %, 1e2: 3.1 %, 1e3: 2.8 %).
    rot_prior_weight: Float[Array, ""]  # 1/rad^2
    trans_prior_weight: Float[Array, ""]  # 1/m^2
    tilt_prior_weight: Float[Array, ""]  # of the world-up direction's error (unit vectors)
    damping: Float[Array, ""]  # Levenberg damping added to the normal matrix's diagonal
    # depth jump to a neighbour that invalidates a normal, relative to z per radian of pixel angle
    # (so the same number fits every pyramid level; grazing floors legitimately jump by ~ d / height)
    max_normal_jump: Float[Array, ""]
    # radius (px) of the edge-aware inverse-depth mean applied before the pyramid; 0: raw depth
    smooth_radius: int = eqx.field(static=True, default=2)

    @classmethod
    def default(cls) -> IcpParams:
        return cls(
            max_dist=jnp.asarray(0.15),
            huber_k=jnp.asarray(0.02),
            rot_prior_weight=jnp.asarray(1e3),
            trans_prior_weight=jnp.asarray(300.0),
            tilt_prior_weight=jnp.asarray(1e3),
            damping=jnp.asarray(1e-6),
            max_normal_jump=jnp.asarray(12.0),
        )


class DepthLevel(eqx.Module):
    """One pyramid level of a depth image, one row per pixel: the point (camera frame, m), the unit normal
    facing the camera, point valid (finite depth > 0) and normal valid (its neighbours valid and on the
    same surface) as 0 / 1. One row, so that the projective association fetches a reference pixel's
    point, normal and flag in one gather."""

    rows: Float[Array, "h w 8"]

    @property
    def points(self) -> Float[Array, "h w 3"]:
        return self.rows[..., 0:3]

    @property
    def normals(self) -> Float[Array, "h w 3"]:
        return self.rows[..., 3:6]

    @property
    def valid(self) -> Bool[Array, "h w"]:
        return self.rows[..., 6] > 0.0

    @property
    def normal_ok(self) -> Bool[Array, "h w"]:
        return self.rows[..., 7] > 0.0


class NormalEquations(eqx.Module):
    """The point-to-plane terms of one linearization (prior terms not included)."""

    H: Float[Array, "6 6"]  # sum w J^T J
    b: Float[Array, 6]  # sum w J^T r
    n_inliers: Float[Array, ""]
    sq_residual: Float[Array, ""]  # sum of the inliers' squared residuals, m^2


def level_intrinsics(K: Float[Array, "3 3"], level: int) -> Float[Array, "3 3"]:
    """Intrinsics of the image subsampled by 2^level (pixel u' = u / 2^level)."""
    s = 1.0 / (2**level)
    return K * jnp.array([[s, 1.0, s], [1.0, s, s], [1.0, 1.0, 1.0]], K.dtype)


def backproject(depth: Float[Array, "h w"], K: Float[Array, "3 3"]) -> tuple[Float[Array, "3 h w"], Bool[Array, "h w"]]:
    """Camera-frame points (x, y, z planes) of a z-depth image (0, negative or non-finite = invalid; points
    there are 0)."""
    h, w = depth.shape
    valid = jnp.isfinite(depth) & (depth > 0.0)
    z = jnp.where(valid, depth, 0.0)
    u = jnp.arange(w, dtype=depth.dtype)[None, :]
    v = jnp.arange(h, dtype=depth.dtype)[:, None]
    x = (u - K[0, 2]) / K[0, 0] * z
    y = (v - K[1, 2]) / K[1, 1] * z
    return jnp.stack([x, y, z]), valid


_NEIGHBOURS = (("right", 0, 1), ("left", 0, -1), ("down", 1, 0), ("up", -1, 0))  # name, row and column offset


def _neighbours_by_roll(P, valid, gate):
    """Neighbour minus centre per component and the pixels whose four neighbours are valid and within
    `gate` in depth, the border excluded; images shifted by `jnp.roll` (fast on CPUs)."""
    ok = valid
    diff = {}
    for name, dr, dc in _NEIGHBOURS:
        diff[name] = tuple(jnp.roll(c, (-dr, -dc), axis=(0, 1)) - c for c in P)
        ok &= jnp.roll(valid, (-dr, -dc), axis=(0, 1)) & (jnp.abs(diff[name][2]) < gate)
    return diff, ok.at[:, 0].set(False).at[:, -1].set(False).at[0, :].set(False).at[-1, :].set(False)


def _neighbours_by_slices(P, valid, gate):
    """The same from slices of the zero-padded images and a border mask from indices: XLA fuses these into
    one pass on GPUs (4x faster than `_neighbours_by_roll` on an H200, 4x slower on a CPU)."""
    h, w = valid.shape
    padded, valid_padded = tuple(jnp.pad(c, 1) for c in P), jnp.pad(valid, 1)
    row, col = jnp.arange(h)[:, None], jnp.arange(w)[None, :]
    ok = valid & (row > 0) & (row < h - 1) & (col > 0) & (col < w - 1)
    diff = {}
    for name, dr, dc in _NEIGHBOURS:
        at = (slice(1 + dr, 1 + dr + h), slice(1 + dc, 1 + dc + w))
        diff[name] = tuple(c[at] - centre for c, centre in zip(padded, P))
        ok &= valid_padded[at] & (jnp.abs(diff[name][2]) < gate)
    return diff, ok


def image_normals(
    points: Float[Array, "3 h w"], valid: Bool[Array, "h w"], max_jump: Float[Array, ""]
) -> tuple[Float[Array, "3 h w"], Bool[Array, "h w"]]:
    """Normals (x, y, z planes) from the four neighbours, oriented towards the camera.

    Two one-sided normals, cross(right - p, down - p) and cross(left - p, up - p), must agree within
    `NORMAL_AGREEMENT_COS` (a pixel on a crease such as a wall-floor corner has no normal), and every
    neighbour must be valid and within `max_jump` * z in depth (not across a depth edge); the
    border has no normal. `depth_frame` passes IcpParams.max_normal_jump / f_x as `max_jump`."""
    P = tuple(points)
    z = P[2]
    gate = max_jump * jnp.maximum(z, 1e-3)
    diff, ok = jax.lax.platform_dependent(P, valid, gate, cpu=_neighbours_by_roll, default=_neighbours_by_slices)

    def cross(a, b):
        return (a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0])

    def unit(n):
        norm = jnp.sqrt(n[0] * n[0] + n[1] * n[1] + n[2] * n[2])
        inv = 1.0 / jnp.where(norm > 0.0, norm, 1.0)
        return tuple(c * inv for c in n), norm > 0.0

    dot = lambda a, b: a[0] * b[0] + a[1] * b[1] + a[2] * b[2]  # noqa: E731
    n1, ok1 = unit(cross(diff["right"], diff["down"]))
    n2, ok2 = unit(cross(diff["left"], diff["up"]))
    n, ok3 = unit(tuple(a + b for a, b in zip(n1, n2)))
    ok &= ok1 & ok2 & ok3 & (dot(n1, n2) > NORMAL_AGREEMENT_COS)
    sign = jnp.where(dot(n, P) > 0.0, -1.0, 1.0)  # face the camera
    return jnp.stack([jnp.where(ok, sign * c, 0.0) for c in n]), ok


def smooth_depth(depth: Float[Array, "h w"], radius: int, max_jump: Float[Array, ""]) -> Float[Array, "h w"]:
    """Edge-aware local plane fit of the inverse depth over a (2 radius + 1)^2 window (invalid pixels stay 0).

    A neighbour d pixels away (Chebyshev) joins the fit if valid and within `max_jump` * z * d of the
    centre's depth (same surface); the centre's value of the least-squares affine fit rho = a + b du + c dv
    is kept. Inverse depth is affine in the pixel coordinates on a plane, so planes stay where they are
    whatever the window's shape (a plain mean would move a plane's border pixels off it), and a stereo
    camera's inverse-depth noise (std k, for a depth std k z^2) is the same at every range. With a full
    window the fit is the mean: (2 radius + 1)^2 pixels, 1 / (2 radius + 1) of the noise. Where the
    neighbours do not fix a plane (fewer than three, or on a line) the depth is kept."""
    h, w = depth.shape
    valid = jnp.isfinite(depth) & (depth > 0.0)
    z = jnp.where(valid, depth, 0.0)
    zp = jnp.pad(z, radius)
    rho_p = jnp.pad(1.0 / jnp.where(valid, depth, 1.0), radius)  # one division per pixel, not per window tap
    gate = max_jump * z
    zero = jnp.zeros_like(z)
    # sums of 1, du, dv, du^2, du dv, dv^2, rho, rho du, rho dv over the window's members
    s0, su, sv, suu, suv, svv, sr, sru, srv = (zero,) * 9
    for dv in range(-radius, radius + 1):
        for du in range(-radius, radius + 1):
            at = (slice(radius + dv, radius + dv + h), slice(radius + du, radius + du + w))
            zn = zp[at]
            take = (zn > 0.0) & (jnp.abs(zn - z) <= gate * max(abs(du), abs(dv)))
            m = take.astype(z.dtype)
            r = jnp.where(take, rho_p[at], 0.0)
            s0, su, sv = s0 + m, su + du * m, sv + dv * m
            suu, suv, svv = suu + du * du * m, suv + du * dv * m, svv + dv * dv * m
            sr, sru, srv = sr + r, sru + du * r, srv + dv * r
    # a by Cramer's rule on the 3 x 3 normal equations
    det = s0 * (suu * svv - suv**2) - su * (su * svv - suv * sv) + sv * (su * suv - suu * sv)
    det_a = sr * (suu * svv - suv**2) - su * (sru * svv - suv * srv) + sv * (sru * suv - suu * srv)
    ok = valid & (det > 1e-6 * jnp.maximum(s0, 1.0) ** 3)
    rho = jnp.where(ok, det_a / jnp.where(ok, det, 1.0), 0.0)
    ok &= rho > 0.0
    return jnp.where(ok, 1.0 / jnp.where(ok, rho, 1.0), z)


def depth_frame(
    depth: Float[Array, "H W"],
    K: Float[Array, "3 3"],
    levels: int,
    params: IcpParams,
) -> tuple[DepthLevel, ...]:
    """The pyramid of a depth image, finest level first. The image is first smoothed by `smooth_depth`
    (radius `params.smooth_radius`, 0: not), so the points and normals of every level see the mean
    depth; normals use `params.max_normal_jump`."""
    max_jump = params.max_normal_jump
    if params.smooth_radius > 0:
        depth = smooth_depth(depth, params.smooth_radius, max_jump / K[0, 0])
    out = []
    for level in range(levels):
        s = 2**level
        pts, valid = backproject(depth[::s, ::s], level_intrinsics(K, level))
        n, n_ok = image_normals(pts, valid, max_jump / level_intrinsics(K, level)[0, 0])
        planes = (*pts, *n, valid.astype(pts.dtype), n_ok.astype(pts.dtype))
        # Materialized as planes first: fused into the interleaving, XLA on GPUs recomputes a pixel's
        # normal for each of its row's eight numbers.
        out.append(DepthLevel(rows=jnp.stack(jax.lax.optimization_barrier(planes), -1)))
    return tuple(out)


def point_to_plane(
    T_ref_cur: Float[Array, "4 4"],
    cur: DepthLevel,
    ref: DepthLevel,
    K: Float[Array, "3 3"],
    params: IcpParams,
) -> NormalEquations:
    """Projective association of the current points into the reference image and the weighted
    point-to-plane normal equations at T_ref_cur (`icp_pass`: a matrix product on CPUs, one Pallas kernel
    on CUDA GPUs)."""
    h, w = ref.rows.shape[:2]
    sums = jax.lax.platform_dependent(
        icp_pass.pass_numbers(T_ref_cur, K, params.max_dist, params.huber_k),
        cur.rows.reshape(-1, 8),
        ref.rows.reshape(-1, 8),
        cuda=functools.partial(icp_pass.sums_by_kernel, h=h, w=w),
        default=functools.partial(icp_pass.sums_by_product, h=h, w=w),
    )
    H, b, n_inliers, sq_residual = icp_pass.normal_equations(sums)
    return NormalEquations(H=H, b=b, n_inliers=n_inliers, sq_residual=sq_residual)


def prior_terms(
    T_ref_cur: Float[Array, "4 4"],
    T_guess: Float[Array, "4 4"],
    params: IcpParams,
    up: Float[Array, "2 3"] | None = None,
) -> tuple[Float[Array, "6 6"], Float[Array, 6]]:
    """Normal-equation terms of the motion priors, linearized for a left update exp(xi) T:
    e_t = t - t_g with de_t/dxi = [I, -[t]_x]; e_r = log(R R_g^T) with de_r/dxi ~ [0, I]; with `up`
    (world up in the reference frame, and in the current frame by an attitude estimate) the tilt
    prior e_u = R up_cur - up_ref with de_u/dxi = [0, -[R up_cur]_x] (blind to rotation about up)."""
    t, R = T_ref_cur[:3, 3], T_ref_cur[:3, :3]
    e_t = t - T_guess[:3, 3]
    e_r = SO3.from_matrix(R @ T_guess[:3, :3].T).log()
    eye, zero = jnp.eye(3, dtype=t.dtype), jnp.zeros((3, 3), t.dtype)
    J_t = jnp.concatenate([eye, -skew(t)], 1)
    J_r = jnp.concatenate([zero, eye], 1)
    H = params.trans_prior_weight * J_t.T @ J_t + params.rot_prior_weight * J_r.T @ J_r
    b = params.trans_prior_weight * J_t.T @ e_t + params.rot_prior_weight * J_r.T @ e_r
    if up is not None:
        u = R @ up[1]
        J_u = jnp.concatenate([zero, -skew(u)], 1)
        H = H + params.tilt_prior_weight * J_u.T @ J_u
        b = b + params.tilt_prior_weight * J_u.T @ (u - up[0])
    return H, b


def gauss_newton_step(
    T_ref_cur: Float[Array, "4 4"],
    T_guess: Float[Array, "4 4"],
    cur: DepthLevel,
    ref: DepthLevel,
    K: Float[Array, "3 3"],
    params: IcpParams,
    up: Float[Array, "2 3"] | None = None,
) -> tuple[Float[Array, "4 4"], NormalEquations]:
    """One Gauss-Newton update: xi = -(H + H_prior + damping I)^-1 (b + b_prior), T <- exp(xi) T.
    Returns the new pose and the point-to-plane equations at the old one."""
    ne = point_to_plane(T_ref_cur, cur, ref, K, params)
    H_p, b_p = prior_terms(T_ref_cur, T_guess, params, up)
    A = ne.H + H_p + params.damping * jnp.eye(6, dtype=ne.H.dtype)
    xi = -spd_solve(A, ne.b + b_p)
    return se3_exp(xi[:3], xi[3:]).as_matrix() @ T_ref_cur, ne


class Alignment(eqx.Module):
    """Result of `align`: the pose and the statistics of the finest level's last linearization."""

    T_ref_cur: Float[Array, "4 4"]
    H: Float[Array, "6 6"]  # point-to-plane normal matrix (priors not included)
    H_total: Float[Array, "6 6"]  # with the priors
    n_inliers: Float[Array, ""]
    n_valid: Float[Array, ""]  # valid current points at the finest level
    rmse: Float[Array, ""]  # inliers' point-to-plane RMS residual, m
    min_eig: Float[Array, ""]  # smallest eigenvalue of H / n_inliers (1 for translation along a normal)


def align(
    ref: tuple[DepthLevel, ...],
    cur: tuple[DepthLevel, ...],
    K: Float[Array, "3 3"],
    T_init: Float[Array, "4 4"],
    T_guess: Float[Array, "4 4"],
    params: IcpParams,
    iterations: tuple[int, ...],
    up: Float[Array, "2 3"] | None = None,
) -> Alignment:
    """Coarse-to-fine alignment; `iterations[l]` Gauss-Newton steps on level l, coarsest first.

    The statistics are those of the finest level's last linearization, at the pose before the last
    update (with no step there, at the final pose): by then Gauss-Newton moves the pose by far less
    than the depth noise, and a pass of its own over the finest level would cost a third of the
    alignment. `up`: see `prior_terms`."""
    T = T_lin = T_init
    ne = None
    for level in reversed(range(len(iterations))):
        K_l = level_intrinsics(K, level)
        for _ in range(iterations[level]):
            T_lin = T
            T, ne = gauss_newton_step(T, T_guess, cur[level], ref[level], K_l, params, up)
    if iterations[0] == 0:
        T_lin, ne = T, point_to_plane(T, cur[0], ref[0], K, params)
    H_p, _ = prior_terms(T_lin, T_guess, params, up)
    n = jnp.maximum(ne.n_inliers, 1.0)
    return Alignment(
        T_ref_cur=T,
        H=ne.H,
        H_total=ne.H + H_p,
        n_inliers=ne.n_inliers,
        n_valid=jnp.sum(cur[0].valid.astype(T.dtype)),
        rmse=jnp.sqrt(ne.sq_residual / n),
        min_eig=jnp.linalg.eigvalsh(ne.H / n)[0],
    )
