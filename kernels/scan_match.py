"""Correlative scan matching (Karto/slam_toolbox style) with an exact multi-resolution search.

The score of a sensor pose (x, y, theta) is the integer sum, over the valid beams (finite, within
[range_min, range_max] and within the grid's `reach`), of the `LikelihoodGrid` values at the cells
their end points fall in; the response is that sum divided by 100 times the number of valid beams
(in [0, 1]: the fraction of beams that land on reference structure, smear-weighted). Poses
searched: the prior's x and y plus whole cells within +-`window_cells` (the grid step), and the
prior's theta plus whole `angle_step_deg` within +-`angle_window_deg`. End points are rotated once
per angle into cells (Karto's lookup arrays), so a translation is an integer shift of the cells.

Stage 1 (exact, multi-resolution): every coarse block (`block` x `block` translations at one angle)
is scored on the max-pooled grid, which bounds every pose of the block from above. Blocks are
expanded (all their poses scored on the fine grid) in order of decreasing bound, `candidates` at a
time, until the next bound is no larger than the best score found: every pose left unexpanded then
scores at most the best, so the result attains the exhaustive maximum (ties may resolve to a
different maximiser). A `lax.while_loop` does the rounds, usually one to three. Under `vmap` every
item runs as many rounds as the batch's slowest; `max_rounds` caps them (the result then carries
`exact = False` where the cap cut the search short).

Stage 2 (refinement): angles at `fine_angle_step_deg` within +-`angle_step_deg` of the stage-1
angle, translations within +-`refine_cells`; the pose returned is the mean of the poses that
share the best refined score (Karto averages its ties too).

Covariance (Karto-like, from the response distribution): responses on a lattice spanning the
translation window around the refined pose at the refined angle, and over the refinement angles at
the refined translation; poses whose response is within `cov_response_drop` of the best weigh
their response, the others nothing; the weighted second moments about the weighted mean plus the
lattice's quantization variance (step^2 / 12) are the x-y block and the theta variance (x-theta
terms are zero).
"""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
from jaxtyping import Array, Bool, Float, Int

from jaxquad.kernels.scan_grid import (
    GRID_MAX,
    LikelihoodGrid,
    MatchParams,
    MatchSpec,
    cell_of,
    scan_points,
)


class MatchResult(eqx.Module):
    pose: Float[Array, "3"]  # refined sensor pose x, y (m), theta (rad), world frame
    response: Float[Array, ""]  # refined response, [0, 1]
    coarse_response: Float[Array, ""]  # stage-1 (exact search) response, [0, 1]
    covariance: Float[Array, "3 3"]  # of (x, y, theta), m^2 and rad^2
    score: Int[Array, ""]  # stage-1 integer score (the exhaustive maximum over the search grid)
    n_valid: Int[Array, ""]  # beams that count in the response
    expanded: Int[Array, ""]  # coarse blocks scored on the fine grid
    exact: Bool[Array, ""]  # stage 1 provably reached the exhaustive maximum (False only when max_rounds cut it)


def search_angles(spec: MatchSpec, theta0: Float[Array, ""]) -> Float[Array, " a"]:
    """Stage-1 angles (rad): theta0 + i * angle_step for i in -n..n."""
    n = spec.n_angles // 2
    return theta0 + jnp.deg2rad(spec.angle_step_deg) * jnp.arange(-n, n + 1, dtype=jnp.float32)


def scan_lookup(
    spec: MatchSpec,
    grid: LikelihoodGrid,
    prior_xy: Float[Array, "2"],
    angles: Float[Array, " a"],
    p_sensor: Float[Array, "b 2"],
    ok: Bool[Array, " b"],
) -> tuple[Int[Array, "a b 2"], Bool[Array, "a b"]]:
    """Unpadded (row, col) cells of the end points at each angle and zero shift, and which count
    (valid and inside the grid; a point outside scores nothing at every shift)."""
    # Written out, not a matmul (GPUs would round float32 matmuls to TF32, cm at 4 m) nor a sum over
    # an axis (XLA on CPUs runs that as a reduction, ten times slower here).
    c, s = jnp.cos(angles)[:, None], jnp.sin(angles)[:, None]
    px, py = p_sensor[None, :, 0], p_sensor[None, :, 1]
    p_world = jnp.stack([c * px - s * py, s * px + c * py], -1) + prior_xy
    rc = cell_of(spec, grid.center_xy, p_world)
    # Finite check first: NaN casts to an arbitrary integer (0 on GPUs, a valid cell).
    inside = ok & jnp.all(jnp.isfinite(p_world), axis=-1) & jnp.all((rc >= 0) & (rc < spec.cells), axis=-1)
    return rc, inside


def _flat(spec: MatchSpec, rc: Array, inside: Array) -> Array:
    """Flat index into the padded grid at zero shift (0, a zero padding cell, where not counted)."""
    m = spec.margin
    return jnp.where(inside, (rc[..., 0] + m) * spec.padded + rc[..., 1] + m, 0)


def _scores(table: Array, flat: Array, shift: Array, inside: Array) -> Array:
    """Integer scores: table[flat + shift] summed over beams (last axis of flat / inside)."""
    v = table.reshape(-1)[flat + shift[..., None]].astype(jnp.int32)
    return jnp.sum(jnp.where(inside, v, 0), axis=-1)


def _exact_search(spec, grid, flat, inside, exclude_rc, exclude_r2):
    """Stage 1: (score, angle index, row shift, col shift, blocks expanded, exact) of the best pose among
    those not within sqrt(exclude_r2) cells of exclude_rc."""
    W, s, nb, P, K = spec.window_cells, spec.block, spec.n_blocks, spec.padded, spec.candidates
    A = flat.shape[0]
    start = -W + s * jnp.arange(nb)
    block_shift = (start[:, None] * P + start[None, :]).reshape(-1)  # (nb^2,)
    bounds = _scores(grid.pooled, flat[:, None, :], block_shift[None, :], inside[:, None, :]).reshape(-1)
    n = A * nb * nb
    n_rounds = -(-n // K)
    order = jnp.argsort(-bounds)
    order = jnp.concatenate([order, jnp.zeros(n_rounds * K - n, order.dtype)])
    sorted_bounds = jnp.concatenate([bounds[order[:n]], jnp.full(n_rounds * K - n, -1, bounds.dtype)])
    d = jnp.arange(s)

    def expand(state):
        i, best, best_a, best_r, best_c = state
        cand = jax.lax.dynamic_slice_in_dim(order, i * K, K)
        live = jax.lax.dynamic_slice_in_dim(sorted_bounds, i * K, K) >= 0
        a, b = cand // (nb * nb), cand % (nb * nb)
        kr = (start[b // nb][:, None] + d)[:, :, None]  # (K, s, 1)
        kc = (start[b % nb][:, None] + d)[:, None, :]  # (K, 1, s)
        sc = _scores(
            grid.values,
            flat[a][:, None, None, :],
            kr * P + kc,
            inside[a][:, None, None, :],
        )
        kr_f, kc_f = kr.astype(exclude_rc.dtype), kc.astype(exclude_rc.dtype)
        far = (kr_f - exclude_rc[0]) ** 2 + (kc_f - exclude_rc[1]) ** 2 >= exclude_r2
        ok = live[:, None, None] & (kr <= W) & (kc <= W) & far
        sc = jnp.where(ok, sc, -1).reshape(-1)
        j = jnp.argmax(sc)
        k, r, c = j // (s * s), (j // s) % s, j % s
        better = sc[j] > best
        pick = lambda new, old: jnp.where(better, new, old)
        return (
            i + 1,
            pick(sc[j], best),
            pick(a[k], best_a),
            pick(start[b[k] // nb] + r, best_r),
            pick(start[b[k] % nb] + c, best_c),
        )

    cap = n_rounds if spec.max_rounds is None else min(n_rounds, spec.max_rounds)

    def unfinished(state):
        i, best = state[0], state[1]
        return (i < n_rounds) & (sorted_bounds[jnp.minimum(i * K, n_rounds * K - 1)] > best)

    zero = jnp.int32(0)
    state = jax.lax.while_loop(
        lambda st: unfinished(st) & (st[0] < cap), expand, (zero, jnp.int32(-1), zero, zero, zero)
    )
    i, best, a, r, c = state
    return best, a, r, c, jnp.minimum(i * K, n), ~unfinished(state)


def _response_moments(resp: Array, best: Array, drop: Array, x: Array) -> tuple[Array, Array]:
    """Weighted mean and covariance of rows of x (n, d): weight = response where within `drop` of the best,
    else 0 (a floor of 1e-6 keeps an all-zero response, no information, as uniform weights)."""
    w = jnp.where(resp >= best - drop, jnp.maximum(resp, 1e-6), 0.0)
    w = w / jnp.sum(w)
    mean = jnp.sum(w[:, None] * x, axis=0)
    dx = x - mean
    return mean, jnp.sum(w[:, None, None] * dx[:, :, None] * dx[:, None, :], axis=0)


def match_scan(
    spec: MatchSpec,
    params: MatchParams,
    grid: LikelihoodGrid,
    prior: Float[Array, "3"],
    ranges: Float[Array, " b"],
    bearings: Float[Array, " b"],
    valid: Bool[Array, " b"],
    exclude_xy: Float[Array, "2"] | None = None,
    exclude_radius: Float[Array, ""] | float = 0.0,
) -> MatchResult:
    """Best sensor pose of one scan against `grid` within the search window around `prior` (x, y, theta).

    `exclude_xy`/`exclude_radius` (world, m) leave out stage-1 translations within that distance of
    a point (used to find the second-best distinct peak); by default nothing is excluded. A
    non-finite prior or grid centre scores no beam: response 0 (the pose is then not finite).
    """
    p_sensor, ok = scan_points(params, ranges, bearings, valid & (ranges <= spec.reach))
    n_valid = jnp.sum(ok).astype(jnp.int32)
    denom = GRID_MAX * jnp.maximum(n_valid, 1).astype(jnp.float32)
    prior_xy, res, P = prior[:2], spec.resolution, spec.padded

    angles = search_angles(spec, prior[2])
    rc, inside = scan_lookup(spec, grid, prior_xy, angles, p_sensor, ok)
    flat = _flat(spec, rc, inside)
    ex = jnp.zeros(2) if exclude_xy is None else (exclude_xy - prior_xy)[::-1] / res
    ex_r2 = (jnp.asarray(exclude_radius, jnp.float32) / res) ** 2
    score, a, r0, c0, expanded, exact = _exact_search(spec, grid, flat, inside, ex, ex_r2)

    # Stage 2: fine angles around the stage-1 angle, +-refine_cells around its translation.
    J, R = spec.n_fine, spec.refine_cells
    fine = angles[a] + jnp.deg2rad(spec.fine_angle_step_deg) * jnp.arange(-J, J + 1, dtype=jnp.float32)
    rc_f, in_f = scan_lookup(spec, grid, prior_xy, fine, p_sensor, ok)
    flat_f = _flat(spec, rc_f, in_f)
    d = jnp.arange(-R, R + 1)
    shift = ((r0 + d)[:, None] * P + (c0 + d)[None, :]).reshape(-1)  # (n_shift,)
    sc_f = _scores(grid.values, flat_f[:, None, :], shift[None, :], in_f[:, None, :])  # (2J+1, n_shift)
    centre = J * sc_f.shape[1] + sc_f.shape[1] // 2
    j = jnp.argmax(sc_f.reshape(-1))
    j = jnp.where(sc_f.reshape(-1)[j] > sc_f.reshape(-1)[centre], j, centre)
    ja, js = j // sc_f.shape[1], j % sc_f.shape[1]
    r1, c1 = r0 + d[js // (2 * R + 1)], c0 + d[js % (2 * R + 1)]
    theta = fine[ja]
    response = sc_f.reshape(-1)[j].astype(jnp.float32) / denom

    # Covariance from the response distribution around the refined pose.
    n, st = spec.cov_points, spec.cov_stride
    lat = st * jnp.arange(-n, n + 1)
    lr, lc = jnp.meshgrid(lat, lat, indexing="ij")
    lat_shift = ((r1 + lr) * P + (c1 + lc)).reshape(-1)
    resp_xy = _scores(grid.values, flat_f[ja][None, :], lat_shift, in_f[ja][None, :]).astype(jnp.float32) / denom
    xy = jnp.stack([lc.reshape(-1), lr.reshape(-1)], -1).astype(jnp.float32) * res
    _, cov_xy = _response_moments(resp_xy, response, params.cov_response_drop, xy)
    cov_xy = cov_xy + jnp.eye(2) * (st * res) ** 2 / 12.0
    resp_t = sc_f[:, js].astype(jnp.float32) / denom
    _, var_t = _response_moments(resp_t, response, params.cov_response_drop, fine[:, None] - theta)
    var_t = var_t[0, 0] + jnp.deg2rad(spec.fine_angle_step_deg) ** 2 / 12.0
    cov = jnp.zeros((3, 3)).at[:2, :2].set(cov_xy).at[2, 2].set(var_t)

    # The pose: the mean of the refinement poses that share the best score (as Karto averages its
    # ties), which removes the bias of picking one corner of a plateau one cell or step wide.
    tie = (sc_f == sc_f.reshape(-1)[j]).astype(jnp.float32)
    tie = tie / jnp.sum(tie)
    dd = d.astype(jnp.float32)
    mean_r = r0.astype(jnp.float32) + jnp.sum(tie.sum(0).reshape(2 * R + 1, 2 * R + 1).sum(1) * dd)
    mean_c = c0.astype(jnp.float32) + jnp.sum(tie.sum(0).reshape(2 * R + 1, 2 * R + 1).sum(0) * dd)
    pose = jnp.stack([prior[0] + mean_c * res, prior[1] + mean_r * res, jnp.sum(tie.sum(1) * fine)])
    return MatchResult(pose, response, score.astype(jnp.float32) / denom, cov, score, n_valid, expanded, exact)
