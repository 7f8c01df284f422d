"""Particle filter (AMCL) kernels against independent references: NumPy loops, closed forms, a Kalman
filter, and a NumPy ray caster for global localization on a small asymmetric map."""

from __future__ import annotations

import functools

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from jaxquad.kernels import (
    AmclInputs,
    AmclParams,
    amcl_init,
    amcl_step,
    likelihood_field,
    measurement_update,
    omni_motion,
    pose_estimate,
    scan_likelihood,
    systematic_resample,
)

RES = 0.05


def _room() -> np.ndarray:
    """6 m x 4 m room (rows = y) with outer walls, an L-shaped block and a pillar: no symmetry."""
    g = np.zeros((80, 120), np.int8)
    g[:2, :] = g[-2:, :] = g[:, :2] = g[:, -2:] = 100
    g[50:78, 30:36] = 100  # wall stub from the top
    g[50:56, 30:60] = 100  # its foot: an L
    g[15:25, 85:95] = 100  # pillar
    g[2:10, 2:10] = -1  # an unknown corner
    return g


GRID = _room()
FIELD = likelihood_field(GRID, RES, (0.0, 0.0), max_dist=2.0)


def _np_distance(grid: np.ndarray, xy: np.ndarray, max_dist: float) -> float:
    """Brute force: distance from the cell holding xy to the nearest occupied cell centre, clipped."""
    c, r = np.floor(xy / RES).astype(int)
    if not (0 <= r < grid.shape[0] and 0 <= c < grid.shape[1]):
        return max_dist
    occ = np.argwhere(grid > 65)
    return min(max_dist, float(np.min(np.hypot(occ[:, 0] - r, occ[:, 1] - c))) * RES)


def test_likelihood_matches_numpy_loop():
    rng = np.random.default_rng(0)
    poses = np.column_stack([rng.uniform(0.5, 5.5, 6), rng.uniform(0.5, 3.5, 6), rng.uniform(-np.pi, np.pi, 6)])
    bearings = np.linspace(-1.2, 1.2, 9)
    ranges = rng.uniform(0.3, 4.0, 9)
    ranges[[1, 4, 7]] = [np.inf, 0.1, 9.0]  # no reading, below range_min, beyond range_max
    laser = np.array([0.2, -0.05, 0.1])
    z_hit, z_rand, sigma, rmin, rmax = 0.6, 0.4, 0.25, 0.2, 8.0
    f = jax.jit(scan_likelihood)
    got = f(
        FIELD,
        jnp.asarray(poses, jnp.float32),
        jnp.asarray(laser, jnp.float32),
        jnp.asarray(ranges, jnp.float32),
        jnp.asarray(bearings, jnp.float32),
        z_hit,
        z_rand,
        sigma,
        rmin,
        rmax,
    )
    for i, (x, y, th) in enumerate(poses):
        p = 1.0
        for r, b in zip(ranges, bearings):
            if not (np.isfinite(r) and rmin <= r < rmax):
                continue
            lx, ly = (
                x + np.cos(th) * laser[0] - np.sin(th) * laser[1],
                y + np.sin(th) * laser[0] + np.cos(th) * laser[1],
            )
            end = np.array([lx + r * np.cos(th + laser[2] + b), ly + r * np.sin(th + laser[2] + b)])
            d = _np_distance(GRID, end, 2.0)
            p += (z_hit * np.exp(-(d**2) / (2 * sigma**2)) + z_rand / rmax) ** 3
        np.testing.assert_allclose(float(got[i]), p, rtol=1e-5)


def _np_low_variance(w: np.ndarray, u: float) -> np.ndarray:
    """Probabilistic Robotics' low-variance sampler (Table 4.4) with r = u / n."""
    n = w.size
    w = w / w.sum()
    out, c, i = [], w[0], 0
    for m in range(n):
        target = (u + m) / n
        while target > c:
            i += 1
            c += w[i]
        out.append(i)
    return np.array(out)


_resample = jax.jit(systematic_resample)
# One compiled step (and one vmapped) shared by the tests below: 128 particles, 30-column scans.
_step = jax.jit(amcl_step)
_step_fleet = jax.jit(jax.vmap(amcl_step, in_axes=(None, None, 0, 0)))


def test_systematic_resample_matches_numpy():
    rng = np.random.default_rng(1)
    w = rng.exponential(size=50) ** 3
    for u in (0.0, 0.37, 0.999):
        got = _resample(jnp.log(jnp.asarray(w / w.sum(), jnp.float32)), jnp.ones(50, bool), jnp.float32(u))
        np.testing.assert_array_equal(np.asarray(got), _np_low_variance(w, u))


def test_resample_never_picks_inactive_slots():
    rng = np.random.default_rng(2)
    mask = rng.uniform(size=64) < 0.5
    # Inactive slots hold large finite log weights: the mask alone must keep them out.
    log_w = jnp.asarray(np.where(mask, rng.normal(size=64), 5.0), jnp.float32)
    active = np.flatnonzero(mask)
    w = np.exp(np.asarray(log_w)[active])
    for u in (0.05, 0.5, 0.95):
        got = np.asarray(_resample(log_w, jnp.asarray(mask), jnp.float32(u)))
        assert set(got[mask]) <= set(active)
        np.testing.assert_array_equal(got[mask], active[_np_low_variance(w, u)])
        np.testing.assert_array_equal(got[~mask], np.flatnonzero(~mask))


def test_omni_motion_moments_match_closed_form():
    alpha = jnp.asarray([0.01, 0.02, 0.03, 0.04, 0.05], jnp.float32)
    odom_old, odom_new = np.array([1.0, 2.0, 0.3]), np.array([1.3, 2.1, 0.5])
    pose0 = np.array([-2.0, 0.5, 2.0])  # particle heading differs from the odometry heading
    n = 200_000
    f32 = lambda a: jnp.asarray(a, jnp.float32)  # noqa: E731
    out = jax.jit(omni_motion)(jax.random.PRNGKey(0), jnp.tile(f32(pose0), (n, 1)), f32(odom_old), f32(odom_new), alpha)
    out = np.asarray(out, np.float64)
    # Closed form: a translation t along bearing b (relative to the particle's heading), strafe s across.
    d = odom_new - odom_old
    t, r = np.hypot(d[0], d[1]), d[2]
    a = np.asarray(alpha, np.float64)
    sd_t, sd_r, sd_s = (
        np.sqrt(a[2] * t**2 + a[3] * r**2),
        np.sqrt(a[0] * r**2 + a[1] * t**2),
        np.sqrt(a[3] * r**2 + a[4] * t**2),
    )
    b = np.arctan2(d[1], d[0]) - odom_old[2] + pose0[2]
    rot = np.array([[np.cos(b), np.sin(b)], [np.sin(b), -np.cos(b)]])  # (t, s) -> (x, y)
    mean = np.array([pose0[0] + t * np.cos(b), pose0[1] + t * np.sin(b), pose0[2] + r])
    cov = np.zeros((3, 3))
    cov[:2, :2] = rot @ np.diag([sd_t**2, sd_s**2]) @ rot.T
    cov[2, 2] = sd_r**2
    np.testing.assert_allclose(out.mean(0), mean, atol=4 * np.sqrt(np.diag(cov).max() / n) + 1e-6)
    np.testing.assert_allclose(np.cov(out.T), cov, atol=0.02 * np.abs(cov).max())


def test_particle_filter_matches_kalman_filter():
    """Heading fixed (alpha1 = alpha2 = 0), straight odometry steps and a Gaussian position measurement:
    a linear-Gaussian problem whose exact posterior is the Kalman filter's."""
    a3, a5 = 0.05, 0.02
    params = AmclParams.paper(alpha=[0.0, 0.0, a3, 0.0, a5], alpha_slow=0.0, alpha_fast=0.0, init_std=[0.4, 0.3, 0.0])
    m0 = np.array([1.0, 2.0])
    state = amcl_init(params, FIELD, jnp.array([1.0, 2.0, 0.0]), jax.random.PRNGKey(3), 20_000)
    R_meas = np.array([[0.09, 0.02], [0.02, 0.04]])
    steps = [np.array([0.5, 0.2]), np.array([0.3, -0.4]), np.array([0.6, 0.0])]
    meas = [np.array([1.6, 2.1]), np.array([1.8, 1.9]), np.array([2.5, 1.8])]

    @jax.jit
    def pf_step(state, odom_old, odom_new, z, key):
        k1, k2 = jax.random.split(key)
        state = eqx.tree_at(lambda s: s.poses, state, omni_motion(k1, state.poses, odom_old, odom_new, params.alpha))
        e = state.poses[:, :2] - z
        log_lik = -0.5 * jnp.einsum("pi,ij,pj->p", e, jnp.linalg.inv(jnp.asarray(R_meas, jnp.float32)), e)
        return measurement_update(params, state, log_lik, state.poses, k2)[0]

    mean, P = m0.copy(), np.diag([0.16, 0.09])
    odom = np.zeros(3)
    for k, (d, z) in enumerate(zip(steps, meas)):
        t = np.hypot(*d)
        b = np.arctan2(d[1], d[0])
        rot = np.array([[np.cos(b), np.sin(b)], [np.sin(b), -np.cos(b)]])
        mean, P = mean + d, P + rot @ np.diag([a3 * t**2, a5 * t**2]) @ rot.T
        K = P @ np.linalg.inv(P + R_meas)
        mean, P = mean + K @ (z - mean), (np.eye(2) - K) @ P
        new = odom + np.array([d[0], d[1], 0.0])
        f32 = lambda a: jnp.asarray(a, jnp.float32)  # noqa: E731
        state = pf_step(state, f32(odom), f32(new), f32(z), jax.random.PRNGKey(10 + k))
        odom = new
    est, cov = pose_estimate(state.poses, state.log_w, state.mask)
    np.testing.assert_allclose(np.asarray(est[:2]), mean, atol=0.015)
    np.testing.assert_allclose(np.asarray(cov[:2, :2]), P, atol=0.1 * np.abs(P).max())


def _cast(grid: np.ndarray, pose: np.ndarray, bearings: np.ndarray, range_max: float) -> np.ndarray:
    """NumPy ray marching (RES / 10 steps) to the first occupied cell; inf when none within range_max."""
    steps = np.arange(1, int(range_max / (RES / 10))) * (RES / 10)
    out = np.full(bearings.shape, np.inf)
    for k, b in enumerate(bearings):
        a = pose[2] + b
        c = np.floor((pose[0] + steps * np.cos(a)) / RES).astype(int)
        r = np.floor((pose[1] + steps * np.sin(a)) / RES).astype(int)
        ok = (r >= 0) & (r < grid.shape[0]) & (c >= 0) & (c < grid.shape[1])
        hit = np.flatnonzero(ok & (grid[np.clip(r, 0, grid.shape[0] - 1), np.clip(c, 0, grid.shape[1] - 1)] > 65))
        if hit.size:
            out[k] = steps[hit[0]]
    return out


@functools.cache
def _global_run():
    """Global localization along a path through the room, 2000 particles, 60 of 120 beams over 270 deg,
    an update at every scan (the travel threshold has its own test)."""
    params = AmclParams.paper(update_min_d=0.0, update_min_a=0.0)
    bearings = np.linspace(-0.75 * np.pi, 0.75 * np.pi, 120)
    s = np.linspace(0.0, 1.0, 40)
    truth = np.column_stack([1.2 + 3.0 * s, 1.0 + 0.8 * np.sin(3 * s), 0.4 * np.cos(4 * s)])
    odom = truth + np.column_stack([0.05 * s, -0.04 * s, 0.03 * s])  # slowly drifting odometry
    rng = np.random.default_rng(4)
    ranges = np.stack([_cast(GRID, p, bearings, 8.0) for p in truth])
    ranges = ranges + 0.01 * rng.normal(size=ranges.shape)
    keys = jax.random.split(jax.random.PRNGKey(5), len(truth) + 1)
    state = amcl_init(params, FIELD, None, keys[0], 2000)
    inputs = AmclInputs(
        jnp.asarray(odom, jnp.float32),
        jnp.asarray(ranges, jnp.float32),
        jnp.tile(jnp.asarray(bearings, jnp.float32), (len(truth), 1)),
        keys[1:],
    )
    scan = jax.jit(lambda st, inp: jax.lax.scan(lambda c, x: amcl_step(params, FIELD, c, x), st, inp))
    _, out = scan(state, inputs)
    return truth, jax.tree.map(np.asarray, out)


def test_global_localization_converges():
    truth, out = _global_run()
    err = np.hypot(*(out.pose[:, :2] - truth[:, :2]).T)
    yaw_err = np.abs((out.pose[:, 2] - truth[:, 2] + np.pi) % (2 * np.pi) - np.pi)
    assert err[0] > 0.5  # the first estimate is the mean of a uniform cloud: far from the truth
    assert np.all(err[-10:] < 0.15), err
    assert np.all(yaw_err[-10:] < 0.1), yaw_err
    assert np.sqrt(np.trace(out.cov[-1][:2, :2])) < 0.3


def test_update_only_after_travel_or_rotation():
    params = AmclParams.paper()
    state = amcl_init(params, FIELD, jnp.array([3.0, 2.0, 0.0]), jax.random.PRNGKey(0), 128)
    step = functools.partial(_step, params, FIELD)
    scan = dict(ranges=jnp.full(30, 2.0), bearings=jnp.linspace(-1.0, 1.0, 30))
    odoms = [[0.0, 0.0, 0.0], [0.2, 0.0, 0.0], [0.26, 0.0, 0.0], [0.26, 0.0, 0.15], [0.26, 0.0, 0.25], [np.nan, 0, 0]]
    expect = [True, False, True, False, True, False]
    for k, (o, e) in enumerate(zip(odoms, expect)):
        new, out = step(state, AmclInputs(odom=jnp.asarray(o, jnp.float32), key=jax.random.PRNGKey(k), **scan))
        assert bool(out.updated) == e, (k, o)
        if not e:
            assert all(
                bool(jnp.array_equal(a, b, equal_nan=True))
                for a, b in zip(jax.tree.leaves(new), jax.tree.leaves(state))
            )
        state = new


def test_masked_slots_stay_out_and_vmap_matches_single():
    params = AmclParams.paper()
    bearings = jnp.linspace(-1.0, 1.0, 30)
    counts = jnp.array([40, 128, 77])
    keys = jax.random.split(jax.random.PRNGKey(7), 3)
    states = jax.vmap(lambda k, n: amcl_init(params, FIELD, jnp.array([3.0, 1.5, 0.2]), k, 128, n))(keys, counts)
    single = amcl_init(params, FIELD, jnp.array([3.0, 1.5, 0.2]), keys[2], 128, counts[2])
    step = functools.partial(_step, params, FIELD)
    step_fleet = functools.partial(_step_fleet, params, FIELD)
    poses0 = np.asarray(states.poses)
    for k in range(4):
        odom = jnp.tile(jnp.array([0.3 * k, 0.0, 0.1 * k]), (3, 1))
        ranges = jnp.asarray(np.random.default_rng(k).uniform(0.5, 3.0, (3, 30)), jnp.float32)
        inputs = AmclInputs(odom, ranges, jnp.tile(bearings, (3, 1)), jax.random.split(jax.random.PRNGKey(k), 3))
        states, outs = step_fleet(states, inputs)
        single, out = step(single, jax.tree.map(lambda x: x[2], inputs))
        assert bool(outs.updated.all())
        np.testing.assert_allclose(np.asarray(outs.pose[2]), np.asarray(out.pose), atol=1e-5)
    np.testing.assert_allclose(np.asarray(states.poses[2]), np.asarray(single.poses), atol=1e-5)
    mask = np.asarray(states.mask)
    assert mask.sum(1).tolist() == [40, 128, 77]
    # Inactive slots keep their initial poses and weight zero; the active weights sum to 1.
    np.testing.assert_array_equal(np.asarray(states.poses)[~mask], poses0[~mask])
    assert np.all(np.isneginf(np.asarray(states.log_w)[~mask]))
    np.testing.assert_allclose(np.exp(np.asarray(states.log_w)).sum(1), 1.0, rtol=1e-5)
