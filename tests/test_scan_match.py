"""Correlative scan matcher against NumPy references: the smeared grid and its max-pool by loops, the
exact multi-resolution search by exhaustive search over the same poses, and known transforms between
scans cast (by an independent NumPy caster) in box worlds."""

import functools

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from _laser2d import box, cast

from jaxquad.kernels.scan_grid import (
    MatchParams,
    MatchSpec,
    likelihood_grid,
    world_points,
)
from jaxquad.kernels.scan_match import match_scan, scan_lookup, search_angles

PARAMS = MatchParams()
BEARINGS = np.linspace(-np.pi, np.pi, 360, endpoint=False)
# One spec for most tests (each spec compiles once): +-0.2 m at 0.01 m, the default angles.
SPEC = MatchSpec(cells=640, window_cells=20, block=4)
ROOM = np.concatenate([box(-2.0, -1.5, 2.5, 1.8), box(0.5, 0.4, 1.1, 0.9), box(-1.4, -1.0, -1.0, 0.2)])


@functools.partial(jax.jit, static_argnums=0)
def _grid(spec, center, poses, ranges, valid):
    pts, mask = world_points(PARAMS, poses, ranges, jnp.asarray(BEARINGS, jnp.float32), valid)
    return likelihood_grid(spec, PARAMS, center, pts, mask)


_match = jax.jit(match_scan, static_argnums=0)


def _f32(x):
    return jnp.asarray(x, jnp.float32)


def _reference(spec, pose, segments=ROOM, max_range=6.0):
    r = cast(segments, np.asarray(pose, float), BEARINGS, max_range)
    return _grid(
        spec,
        _f32(pose[:2]),
        _f32([pose]),
        _f32([np.where(np.isfinite(r), r, 0)]),
        jnp.isfinite(_f32([r])),
    )


def _scan(pose, segments=ROOM, max_range=6.0):
    r = cast(segments, np.asarray(pose, float), BEARINGS, max_range)
    return (
        _f32(np.where(np.isfinite(r), r, 0.0)),
        _f32(BEARINGS),
        jnp.asarray(np.isfinite(r)),
    )


# (block, window, smear reach): the last one's margin is set by the smear and the block, not the window.
@pytest.mark.parametrize("block, window, half", [(4, 6, 3), (5, 6, 3), (8, 1, 6)])
def test_grid_matches_numpy_smear_and_max_pool(block, window, half):
    spec = MatchSpec(cells=96, resolution=0.02, window_cells=window, block=block, smear_half_cells=half)
    rng = np.random.default_rng(0)
    center = np.array([0.3, -0.2])
    pts = center + rng.uniform(-1.1, 1.1, (40, 2))  # some fall outside the 1.92 m grid
    mask = rng.random(40) > 0.2
    g = jax.jit(likelihood_grid, static_argnums=0)(spec, PARAMS, _f32(center), _f32(pts), jnp.asarray(mask))
    # NumPy loop: every kept point's cell, then the max of the rounded Gaussian over its square.
    m, h, res, sig = (
        spec.margin,
        spec.smear_half_cells,
        spec.resolution,
        float(PARAMS.smear_sigma),
    )
    ref = np.zeros((spec.padded, spec.padded), int)
    for p, keep in zip(pts, mask):
        col, row = np.floor((p - center) / res).astype(int) + spec.cells // 2
        if not keep or not (0 <= row < spec.cells and 0 <= col < spec.cells):
            continue
        for dr in range(-h, h + 1):
            for dc in range(-h, h + 1):
                v = int(np.floor(100 * np.exp(-((dr * res) ** 2 + (dc * res) ** 2) / (2 * sig**2)) + 0.5))
                ref[row + dr + m, col + dc + m] = max(ref[row + dr + m, col + dc + m], v)
    got = np.asarray(g.values, int)
    assert np.abs(got - ref).max() <= 1 and np.mean(got == ref) > 0.999
    assert ref.max() == 100
    b = spec.block
    pad = np.pad(got, ((0, b), (0, b)))
    pooled = np.max(
        [pad[i : i + spec.padded, j : j + spec.padded] for i in range(b) for j in range(b)],
        axis=0,
    )
    np.testing.assert_array_equal(np.asarray(g.pooled), pooled)


def test_lookup_cells_match_numpy():
    spec = SPEC
    g = _reference(spec, (0.0, 0.0, 0.0))
    r, _, v = _scan((0.2, -0.1, 0.3))
    prior = np.array([0.05, 0.02, 0.25])
    angles = search_angles(spec, _f32(prior[2]))
    np.testing.assert_allclose(np.asarray(angles), prior[2] + np.deg2rad(np.arange(-20, 21, 2)), atol=1e-6)
    p = np.stack([np.asarray(r) * np.cos(BEARINGS), np.asarray(r) * np.sin(BEARINGS)], -1)
    rc, inside = scan_lookup(spec, g, _f32(prior[:2]), angles, _f32(p), v)
    a = np.asarray(angles, float)[:, None]
    world = np.stack(
        [
            np.cos(a) * p[:, 0] - np.sin(a) * p[:, 1],
            np.sin(a) * p[:, 0] + np.cos(a) * p[:, 1],
        ],
        -1,
    )
    cells = (world + prior[:2]) / spec.resolution + spec.cells // 2  # the grid is centred on (0, 0)
    expect = np.floor(cells[..., ::-1]).astype(int)
    near_edge = np.abs(cells[..., ::-1] - np.round(cells[..., ::-1])) < 1e-3
    ok = (np.asarray(rc) == expect) | near_edge
    assert ok.all() and np.asarray(inside).sum() == np.asarray(v).sum() * len(a)


def _exhaustive(spec, g, rc, inside):
    """NumPy: the score of every (angle, row shift, col shift) on the padded grid, by explicit indexing."""
    values = np.asarray(g.values, int)
    W, m = spec.window_cells, spec.margin
    k = np.arange(-W, W + 1)
    rc, inside = np.asarray(rc), np.asarray(inside)
    out = np.zeros((rc.shape[0], k.size, k.size), int)
    for a in range(rc.shape[0]):
        rows = rc[a, inside[a], 0][None, None, :] + m + k[:, None, None]
        cols = rc[a, inside[a], 1][None, None, :] + m + k[None, :, None]
        out[a] = values[rows, cols].sum(-1)
    return out


@pytest.mark.parametrize("seed,candidates", [(0, 16), (1, 1)])
def test_multiresolution_equals_exhaustive(seed, candidates):
    spec = SPEC if candidates == 16 else MatchSpec(cells=640, window_cells=20, block=4, candidates=candidates)
    rng = np.random.default_rng(seed)
    g = _reference(spec, (0.0, 0.0, 0.0))
    true = np.array([rng.uniform(-0.15, 0.15), rng.uniform(-0.15, 0.15), rng.uniform(-0.2, 0.2)])
    r, b, v = _scan(true)
    v = v & jnp.asarray(rng.random(v.shape[0]) > 0.3)  # drop beams so that the optimum is not obvious
    prior = _f32(true + rng.uniform(-0.1, 0.1, 3))
    out = _match(spec, PARAMS, g, prior, r, b, v)
    p = np.stack([r * np.cos(BEARINGS), r * np.sin(BEARINGS)], -1)
    ok = np.asarray(v) & (np.asarray(r) <= spec.reach)  # longer beams leave the grid: not used
    rc, inside = scan_lookup(spec, g, prior[:2], search_angles(spec, prior[2]), _f32(p), jnp.asarray(ok))
    scores = _exhaustive(spec, g, rc, inside)
    assert int(out.score) == scores.max() and bool(out.exact)
    assert int(out.expanded) < scores.size // spec.block**2  # the bound prunes most blocks
    # Excluding a disc around the optimum: the best score outside it, exhaustively.
    ex = np.asarray(out.pose[:2])
    exc = _match(spec, PARAMS, g, prior, r, b, v, _f32(ex), 0.1)
    k = np.arange(-20, 21) * spec.resolution
    dy, dx = np.meshgrid(k + float(prior[1]) - ex[1], k + float(prior[0]) - ex[0], indexing="ij")
    far = (dx**2 + dy**2) / spec.resolution**2 >= (0.1 / spec.resolution) ** 2 - 1e-3
    assert int(exc.score) == scores[:, far].max() < scores.max()
    if candidates == 1:  # one block per round: capped at one round, the search says it may not be exact
        capped = MatchSpec(cells=640, window_cells=20, block=4, candidates=1, max_rounds=1)
        cut = _match(capped, PARAMS, g, prior, r, b, v)
        assert int(out.expanded) > 1 and not bool(cut.exact) and int(cut.score) <= int(out.score)


def test_recovers_known_transform_and_vmaps():
    spec = SPEC
    g = _reference(spec, (0.0, 0.0, 0.0))
    truths = np.array(
        [
            [0.13, -0.17, 0.15],
            [-0.16, 0.12, -0.28],
            [0.08, 0.16, 0.05],
            [0.18, -0.15, 0.33],
        ]
    )
    scans = [_scan(t) for t in truths]
    r, b, v = (jnp.stack(x) for x in zip(*scans))
    batched = jax.jit(
        jax.vmap(match_scan, in_axes=(None, None, None, None, 0, 0, 0)),
        static_argnums=0,
    )
    out = batched(spec, PARAMS, g, jnp.zeros(3), r, b, v)
    err_xy = np.linalg.norm(np.asarray(out.pose[:, :2]) - truths[:, :2], axis=1)
    err_t = np.abs(np.asarray(out.pose[:, 2]) - truths[:, 2])
    assert err_xy.max() < 0.015 and np.rad2deg(err_t).max() < 0.35
    assert np.all(np.asarray(out.response) >= np.asarray(out.coarse_response))
    assert np.all((np.asarray(out.response) > 0.5) & (np.asarray(out.response) <= 1.0))
    single = _match(spec, PARAMS, g, jnp.zeros(3), *scans[1])
    np.testing.assert_allclose(np.asarray(single.pose), np.asarray(out.pose[1]), atol=1e-6)
    # A scan of the reference pose itself matches every beam at the cell it came from.
    own = _match(spec, PARAMS, g, _f32([0.02, -0.03, 0.0]), *_scan((0.0, 0.0, 0.0)))
    np.testing.assert_allclose(np.asarray(own.pose), 0.0, atol=1e-5)
    assert float(own.response) > 0.99  # a beam on a cell edge may round either way


def test_invalid_beams_ignored():
    spec = SPEC
    g = _reference(spec, (0.0, 0.0, 0.0))
    r, b, v = _scan((0.1, 0.05, 0.1))
    bad = r.at[::3].set(jnp.nan).at[1::7].set(-1.0)
    out = _match(spec, PARAMS, g, jnp.zeros(3), bad, b, v)
    clean = _match(spec, PARAMS, g, jnp.zeros(3), r, b, v & jnp.isfinite(bad) & (bad > 0))
    assert int(out.n_valid) == int(clean.n_valid) < int(v.sum())
    np.testing.assert_array_equal(np.asarray(out.pose), np.asarray(clean.pose))
    none = _match(spec, PARAMS, g, jnp.zeros(3), r, b, jnp.zeros_like(v))
    assert float(none.response) == 0.0 and np.all(np.isfinite(np.asarray(none.covariance)))
    lost = _match(spec, PARAMS, g, _f32([np.nan, 0.0, 0.0]), r, b, v)
    assert float(lost.response) == 0.0 and int(lost.score) == 0
    pts = _f32([[0.1, 0.2], [np.nan, 0.0], [np.inf, 1.0]])
    nan_grid = jax.jit(likelihood_grid, static_argnums=0)(spec, PARAMS, _f32([0.0, 0.0]), pts, jnp.ones(3, bool))
    assert int(np.sum(np.asarray(nan_grid.values) == 100)) == 1  # only the finite point


def test_covariance_larger_along_corridor():
    # A 20 m corridor along x, 1.6 m wide: featureless along its axis within the 6 m range.
    corridor = np.array([[-10.0, -0.8, 10.0, -0.8], [-10.0, 0.8, 10.0, 0.8]])
    spec = SPEC
    g = _reference(spec, (0.0, 0.0, 0.0), corridor, max_range=2.5)
    out = _match(spec, PARAMS, g, jnp.zeros(3), *_scan((0.1, 0.05, 0.0), corridor, max_range=2.5))
    cov = np.asarray(out.covariance)
    assert cov[0, 0] > 20 * cov[1, 1]
    assert abs(float(out.pose[1]) - 0.05) < 0.015
    room = _match(
        spec,
        PARAMS,
        _reference(spec, (0.0, 0.0, 0.0)),
        jnp.zeros(3),
        *_scan((0.1, 0.05, 0.0)),
    )
    assert np.asarray(room.covariance)[0, 0] < cov[0, 0] / 20
