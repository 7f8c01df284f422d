"""One point-to-plane pass of `icp.point_to_plane`: projective association of the current points into
the reference image and the 29 sums of the weighted normal equations (H's upper triangle, b, the
inlier count, the inliers' squared residual), in a form per platform.

- CPUs: the normal matrix as a product J W J^T (twice as fast there as separate sums).
- CUDA GPUs: one Pallas (Triton) kernel. XLA compiles the pass into about ten kernels there: the
  Jacobian and other per-point intermediates go to memory and come back for several reductions.
  Here one program per block of `BLOCK` current points associates them, gathers their reference rows
  and reduces the 29 sums in registers; only the blocks' partial sums reach memory. Its derivatives
  are the XLA form's (a custom JVP), so tuning through the odometry sees the same function.

Depth levels are rows of eight numbers per pixel (see `icp.DepthLevel`); `scal` packs the pose and
the numbers of the pass: R (row major), t, fx, fy, cx, cy, max_dist^2, huber_k.
"""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp
from jax.experimental import pallas as pl
from jax.experimental.pallas import triton as plgpu
from jaxtyping import Array, Float

from jaxquad.kernels.robust_twist import robust_weight

BLOCK = 1024  # current points per GPU program (a power of two, as Triton's tensors need)
N_SUMS = 29
_LANES = 32  # a program's sums, padded to a power of two
_UPPER = tuple((i, k) for i in range(6) for k in range(i, 6))  # H's upper triangle, the sums' order


def _upper_index() -> tuple[Array, Array]:
    """(rows, cols) of `_UPPER`, in the integer width of the caller's precision (x64 or not)."""
    return tuple(jnp.asarray(ix) for ix in zip(*_UPPER))


def pass_numbers(
    T_ref_cur: Float[Array, "4 4"], K: Float[Array, "3 3"], max_dist: Float[Array, ""], huber_k: Float[Array, ""]
) -> Float[Array, "18"]:
    """`scal` of a pass: R (row major), t, fx, fy, cx, cy, max_dist^2, huber_k."""
    numbers = jnp.stack([K[0, 0], K[1, 1], K[0, 2], K[1, 2], max_dist**2, huber_k]).astype(T_ref_cur.dtype)
    return jnp.concatenate([T_ref_cur[:3, :3].reshape(-1), T_ref_cur[:3, 3], numbers])


def normal_equations(sums: Float[Array, "29"]):
    """(H (6, 6), b (6,), inlier count, squared residual) of a pass's sums."""
    H = jnp.zeros((6, 6), sums.dtype).at[_upper_index()].set(sums[:21])
    return H + jnp.triu(H, 1).T, sums[21:27], sums[27], sums[28]


def associate(x, y, z, ok, ref_row, scal, h: int, w: int):
    """Current points (x, y, z, ok > 0 where valid) to their reference pixels; `ref_row(j)`: the eight
    numbers of the reference row at flat pixel j. Returns the Jacobian rows [n, p x n] (6 arrays), the
    Huber weight (0 off the inliers), the point-to-plane residual and the inlier flag, per point."""
    R, t = scal[0:9], scal[9:12]
    fx, fy, cx, cy, max_dist2, huber_k = (scal[k] for k in range(12, 18))
    px, py, pz = (R[3 * i] * x + R[3 * i + 1] * y + R[3 * i + 2] * z + t[i] for i in range(3))
    in_front = (ok > 0.0) & (pz > 1e-3)
    z_safe = jnp.where(in_front, pz, 1.0)
    u = jnp.floor(fx * px / z_safe + cx + 0.5)  # nearest pixel (Triton has no round)
    v = jnp.floor(fy * py / z_safe + cy + 0.5)
    inside = in_front & (u >= 0) & (u <= w - 1) & (v >= 0) & (v <= h - 1)
    j = jnp.where(inside, v.astype(jnp.int32) * w + u.astype(jnp.int32), 0)
    qx, qy, qz, nx, ny, nz, _, normal_ok = ref_row(j)
    dx, dy, dz = px - qx, py - qy, pz - qz
    r = nx * dx + ny * dy + nz * dz
    inlier = inside & (normal_ok > 0.0) & (dx * dx + dy * dy + dz * dz < max_dist2)
    wgt = jnp.where(inlier, robust_weight(jnp.abs(r), huber_k, "huber"), 0.0)
    J = (nx, ny, nz, py * nz - pz * ny, pz * nx - px * nz, px * ny - py * nx)
    return J, wgt, r, inlier


def _inlier_terms(r, inlier):
    """Per point: inlier (1 / 0) and its squared residual, the last two sums."""
    return inlier.astype(r.dtype), jnp.where(inlier, r * r, 0.0)


def _terms(J, wgt, r, inlier):
    Jw = tuple(wgt * c for c in J)
    return (*(Jw[i] * J[k] for i, k in _UPPER), *(c * r for c in Jw), *_inlier_terms(r, inlier))


def _kernel(scal_ref, cur_ref, ref_ref, out_ref, *, n: int, h: int, w: int):
    scal = [scal_ref[k] for k in range(18)]
    rows = pl.program_id(0) * BLOCK + jnp.arange(BLOCK, dtype=jnp.int32)
    in_range = rows < n
    x, y, z, ok = (plgpu.load(cur_ref.at[rows, k], mask=in_range, other=0.0) for k in (0, 1, 2, 6))
    terms = _terms(*associate(x, y, z, ok, lambda j: [plgpu.load(ref_ref.at[j, k]) for k in range(8)], scal, h, w))
    lane = jnp.arange(_LANES, dtype=jnp.int32)
    sums = jnp.zeros((_LANES,), x.dtype)
    for k, term in enumerate(terms):
        sums = jnp.where(lane == k, jnp.sum(term), sums)
    out_ref[0, :] = sums


def _sums_kernel(scal, cur_rows, ref_rows, h: int, w: int, interpret: bool):
    n = cur_rows.shape[0]
    blocks = pl.cdiv(n, BLOCK)
    out = pl.pallas_call(
        functools.partial(_kernel, n=n, h=h, w=w),
        grid=(blocks,),
        in_specs=[pl.no_block_spec] * 3,
        out_specs=pl.BlockSpec((1, _LANES), lambda i: (i, 0)),
        out_shape=jax.ShapeDtypeStruct((blocks, _LANES), cur_rows.dtype),
        compiler_params=plgpu.CompilerParams(num_warps=4),
        interpret=interpret,
    )(scal, cur_rows, ref_rows)
    return jnp.sum(out, 0)[:N_SUMS]


def sums_by_product(
    scal: Float[Array, "18"], cur_rows: Float[Array, "n 8"], ref_rows: Float[Array, "m 8"], h: int, w: int
) -> Float[Array, "29"]:
    """The pass's sums, the normal matrix as J W J^T (the CPU form)."""
    x, y, z, _, _, _, ok, _ = cur_rows.T
    J, wgt, r, inlier = associate(x, y, z, ok, lambda j: ref_rows[j].T, scal, h, w)
    J = jnp.stack(J)
    Jw = J * wgt
    H = Jw @ J.T
    counts = jnp.stack([jnp.sum(t) for t in _inlier_terms(r, inlier)])
    return jnp.concatenate([H[_upper_index()], Jw @ r, counts])


@functools.partial(jax.custom_jvp, nondiff_argnums=(3, 4, 5))
def sums_by_kernel(
    scal: Float[Array, "18"],
    cur_rows: Float[Array, "n 8"],
    ref_rows: Float[Array, "m 8"],
    h: int,
    w: int,
    interpret: bool = False,
) -> Float[Array, "29"]:
    """The pass's sums by the GPU kernel (`interpret`: in Pallas's interpreter, to test it on a CPU)."""
    return _sums_kernel(scal, cur_rows, ref_rows, h, w, interpret)


@sums_by_kernel.defjvp
def _sums_by_kernel_jvp(h, w, interpret, primals, tangents):
    return jax.jvp(lambda *a: sums_by_product(*a, h, w), primals, tangents)
