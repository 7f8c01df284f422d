"""Trajectory metrics against evo itself (the oracle), closed forms and NumPy references."""

import copy

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest
from evo.core import filters, geometry, lie_algebra, sync, transformations
from evo.core import metrics as evo_metrics
from evo.core.trajectory import PoseTrajectory3D
from evo.main_ape import ape as evo_ape
from evo.main_rpe import rpe as evo_rpe
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.spatial.transform import Rotation

from jaxquad.io.tum import TumTrajectory
from jaxquad.metrics import (
    associate,
    evaluate,
    evaluate_batch,
    pairs_by_frames,
    pairs_by_path,
    pairs_by_path_all,
    rotation_angle,
    rotation_from_quat_xyzw,
    statistics,
    umeyama,
)

STATS = ("rmse", "mean", "median", "std", "min", "max")
# evo's relative agreement; the absolute floor covers statistics that are zero in exact arithmetic
# (e.g. the first pose after origin alignment), where both sides hold rounding noise near 1e-16.
RTOL, ATOL = 1e-9, 1e-12
APE_RELATIONS = {
    "ate": evo_metrics.PoseRelation.translation_part,
    "are": evo_metrics.PoseRelation.rotation_angle_rad,
    "are_deg": evo_metrics.PoseRelation.rotation_angle_deg,
    "ape": evo_metrics.PoseRelation.full_transformation,
    "ape_rotation_part": evo_metrics.PoseRelation.rotation_part,
}


def _path(n, t0, dt, noise, rng, turns=40.0):
    """A 3-D loop with turning attitude; positions and quaternions perturbed by `noise`."""
    t = t0 + dt * np.arange(n)
    s = np.linspace(0.0, turns, n)
    p = np.stack([10 * np.cos(s / 7), 6 * np.sin(s / 5), 0.5 * np.sin(s)], 1)
    q = Rotation.from_rotvec(np.stack([0.1 * np.sin(s), 0.1 * np.cos(s / 3), s / 7], 1)).as_quat()
    p = p + noise * rng.normal(size=p.shape)
    q = q + noise * rng.normal(size=q.shape)
    return TumTrajectory(t, p, q / np.linalg.norm(q, axis=1, keepdims=True))


def _moved(tr, rotvec, t, scale):
    R = Rotation.from_rotvec(rotvec)
    return TumTrajectory(
        tr.t_s, scale * R.apply(tr.p_world_body) + t, (R * Rotation.from_quat(tr.q_world_body_xyzw)).as_quat()
    )


@pytest.fixture(scope="module")
def pair():
    """Reference at 100 Hz; estimate at ~70 Hz with a 3 ms clock offset, noise, and a similarity offset."""
    rng = np.random.default_rng(0)
    ref = _path(1000, 0.0, 0.01, 0.0, rng)
    est = _path(700, 0.003, 0.0143, 0.02, rng)
    return ref, _moved(est, [0.1, 0.2, 0.3], [1.0, 2.0, 3.0], 1.3)


def _evo(tr):
    return PoseTrajectory3D(tr.p_world_body, np.roll(tr.q_world_body_xyzw, 1, axis=1), tr.t_s)


def _evo_kwargs(mode):
    return dict(align=mode in ("se3", "sim3"), correct_scale=mode in ("sim3", "scale"), align_origin=mode == "origin")


def _evo_all(ref, est, mode, deltas, unit, all_pairs=False, max_diff=0.01):
    r, e = sync.associate_trajectories(_evo(ref), _evo(est), max_diff=max_diff)
    out = {
        key: evo_ape(copy.deepcopy(r), copy.deepcopy(e), rel, **_evo_kwargs(mode)) for key, rel in APE_RELATIONS.items()
    }
    evo_unit = evo_metrics.Unit.meters if unit == "m" else evo_metrics.Unit.frames
    for d in deltas:
        out[d] = evo_rpe(
            copy.deepcopy(r),
            copy.deepcopy(e),
            evo_metrics.PoseRelation.translation_part,
            delta=d,
            delta_unit=evo_unit,
            all_pairs=all_pairs,
            **_evo_kwargs(mode),
        )
    return out, len(r.timestamps)


def _assert_like_evo(ours, theirs, n, deltas, unit):
    d = ours.to_dict()
    assert d["n_pairs"] == n
    for key in APE_RELATIONS:
        for s in STATS:
            np.testing.assert_allclose(d[key][s], theirs[key].stats[s], rtol=RTOL, atol=ATOL, err_msg=f"{key} {s}")
    for delta in deltas:
        key = f"rpe_{delta:g}{'m' if unit == 'm' else 'frames'}"
        assert d[key]["n_pairs"] == theirs[delta].np_arrays["error_array"].size
        for s in STATS:
            np.testing.assert_allclose(d[key][s], theirs[delta].stats[s], rtol=RTOL, atol=ATOL, err_msg=f"{key} {s}")


@pytest.mark.parametrize("mode", ["se3", "sim3", "scale", "origin", "none"])
def test_matches_evo_every_alignment(pair, mode):
    ref, est = pair
    deltas = (2, 5, 10)
    theirs, n = _evo_all(ref, est, mode, deltas, "m")
    _assert_like_evo(evaluate(ref, est, align=mode, deltas=deltas).result, theirs, n, deltas, "m")


@pytest.mark.parametrize(
    ("unit", "all_pairs", "deltas"),
    [
        ("frames", False, (1, 7, 50)),
        ("frames", True, (3, 40)),
        ("m", True, (2, 5)),
    ],
)
def test_matches_evo_rpe_modes(pair, unit, all_pairs, deltas):
    ref, est = pair
    theirs, n = _evo_all(ref, est, "sim3", deltas, unit, all_pairs)
    ours = evaluate(ref, est, align="sim3", deltas=deltas, delta_unit=unit, all_pairs=all_pairs).result
    _assert_like_evo(ours, theirs, n, deltas, unit)


def test_matches_evo_with_estimate_longer_and_loose_max_diff():
    # The estimate has more poses: association starts from the reference; a 25 ms window makes
    # several reference stamps share one estimate stamp (matches are not one-to-one).
    rng = np.random.default_rng(3)
    ref = _path(300, 0.0, 0.033, 0.0, rng, turns=12)
    est = _moved(_path(1000, 0.011, 0.01, 0.01, rng, turns=40), [0.0, 0.0, 1.0], [0.5, 0.0, 0.0], 1.0)
    theirs, n = _evo_all(ref, est, "se3", (1, 3), "m", max_diff=0.025)
    _assert_like_evo(evaluate(ref, est, deltas=(1, 3), max_diff_s=0.025).result, theirs, n, (1, 3), "m")


@settings(max_examples=60, deadline=None)
@given(
    seed=st.integers(0, 2**31 - 1),
    sizes=st.tuples(st.integers(1, 30), st.integers(1, 30)),
    max_diff=st.sampled_from([0.0, 0.01, 0.05, 0.25]),
)
def test_association_is_evos(seed, sizes, max_diff):
    # Stamps on a 0.05 s grid produce exact ties and exact max_diff boundaries.
    rng = np.random.default_rng(seed)
    t_ref = np.sort(rng.choice(np.arange(60) * 0.05, sizes[0], replace=False))
    t_est = np.sort(rng.choice(np.arange(60) * 0.05 + rng.choice([0.0, 0.025, 0.01]), sizes[1], replace=False))
    est_longer = t_est.size > t_ref.size
    short, long_ = (t_ref, t_est) if est_longer else (t_est, t_ref)
    i_short, i_long = sync.matching_time_indices(short, long_, max_diff)
    expect_ref, expect_est = (i_short, i_long) if est_longer else (i_long, i_short)
    if not expect_ref:
        with pytest.raises(ValueError, match="no matching timestamps"):
            associate(t_ref, t_est, max_diff)
        return
    idx_ref, idx_est = associate(t_ref, t_est, max_diff)
    assert idx_ref.tolist() == expect_ref and idx_est.tolist() == expect_est


@pytest.fixture(scope="module")
def pairs_fns():
    return jax.jit(pairs_by_path), jax.jit(pairs_by_path_all)


def _walk(seed, n=40):
    rng = np.random.default_rng(seed)
    steps = rng.normal(size=(n - 1, 3)) * rng.uniform(0.0, 1.0, size=(n - 1, 1))
    steps[rng.uniform(size=n - 1) < 0.2] = 0.0  # standing still: runs of equal travelled distance
    return np.concatenate([np.zeros((1, 3)), np.cumsum(steps, axis=0)])


def _pairs_list(pairs):
    m = np.asarray(pairs.mask)
    return list(zip(np.asarray(pairs.i)[m].tolist(), np.asarray(pairs.j)[m].tolist()))


@settings(max_examples=40, deadline=None)
@given(seed=st.integers(0, 2**31 - 1), delta=st.sampled_from([0.3, 1.0, 2.5, 100.0]))
def test_path_pairs_are_evos(pairs_fns, seed, delta):
    p = _walk(seed)
    poses = [lie_algebra.se3(np.eye(3), x) for x in p]
    by_path, by_path_all = pairs_fns
    with jax.enable_x64(True):
        got = _pairs_list(by_path(jnp.asarray(p), jnp.asarray(delta)))
        got_all = _pairs_list(by_path_all(jnp.asarray(p), jnp.asarray(delta)))
    assert got == filters.filter_pairs_by_path(poses, delta)
    assert got_all == filters.filter_pairs_by_path(poses, delta, 0.1 * delta, all_pairs=True)


@pytest.mark.parametrize("n", [1, 2, 9, 10])
@pytest.mark.parametrize("delta", [1, 3, 9, 12])
@pytest.mark.parametrize("all_pairs", [False, True])
def test_frame_pairs_are_evos(n, delta, all_pairs):
    got = _pairs_list(pairs_by_frames(n, jnp.asarray(delta), all_pairs))
    assert got == filters.filter_pairs_by_index([np.eye(4)] * n, delta, all_pairs)


@settings(max_examples=30, deadline=None)
@given(seed=st.integers(0, 2**31 - 1), n=st.integers(1, 12), frac=st.floats(0.0, 1.0))
def test_statistics_match_numpy(seed, n, frac):
    rng = np.random.default_rng(seed)
    x = rng.exponential(size=12)
    mask = np.zeros(12, bool)
    mask[rng.permutation(12)[: max(1, int(frac * n))]] = True
    with jax.enable_x64(True):
        s = statistics(jnp.asarray(x), jnp.asarray(mask))
    v = x[mask]
    expect = dict(
        rmse=np.sqrt(np.mean(v**2)), mean=np.mean(v), median=np.median(v), std=np.std(v), min=np.min(v), max=np.max(v)
    )
    for k, e in expect.items():
        np.testing.assert_allclose(float(getattr(s, k)), e, rtol=1e-13, err_msg=k)
    assert int(s.n) == v.size


def test_statistics_of_nothing_are_zero_not_nan():
    s = statistics(jnp.arange(4.0), jnp.zeros(4, bool))
    assert int(s.n) == 0
    assert all(float(getattr(s, k)) == 0.0 for k in STATS)


def test_rotations_match_evo_and_scipy():
    rng = np.random.default_rng(5)
    q = rng.normal(size=(50, 4)) * rng.uniform(0.1, 3.0, size=(50, 1))  # not unit: both normalize
    with jax.enable_x64(True):
        R = jax.vmap(rotation_from_quat_xyzw)(jnp.asarray(q))
        expect = np.stack([transformations.quaternion_matrix(np.roll(x, 1))[:3, :3] for x in q])
        np.testing.assert_allclose(np.asarray(R), expect, atol=1e-14)
        # Angles over (0, pi], including the ends where a naive acos/asin loses accuracy.
        rv = rng.normal(size=(50, 3))
        rv *= np.concatenate([[1e-9, 1e-4, np.pi, np.pi - 1e-7], rng.uniform(0, np.pi, 46)])[:, None] / np.linalg.norm(
            rv, axis=1, keepdims=True
        )
        angles = jax.vmap(rotation_angle)(jnp.asarray(Rotation.from_rotvec(rv).as_matrix()))
        np.testing.assert_allclose(np.asarray(angles), np.linalg.norm(rv, axis=1), rtol=1e-8, atol=1e-15)
    assert float(rotation_angle(jnp.eye(3))) == 0.0


@pytest.mark.parametrize("with_scale", [False, True])
def test_umeyama_matches_evo(with_scale):
    rng = np.random.default_rng(7)
    x = rng.normal(size=(30, 3))
    y = 2.0 * Rotation.from_rotvec([0.3, -1.0, 2.0]).apply(x) + 1.0 + 0.1 * rng.normal(size=x.shape)
    R, t, c = geometry.umeyama_alignment(x.T, y.T, with_scale)
    with jax.enable_x64(True):
        a = umeyama(jnp.asarray(x), jnp.asarray(y), with_scale)
    assert bool(a.ok)
    np.testing.assert_allclose(np.asarray(a.R_ref_est), R, atol=1e-13)
    np.testing.assert_allclose(np.asarray(a.t_ref_est), t, atol=1e-13)
    np.testing.assert_allclose(float(a.scale), c, rtol=1e-13)


@pytest.mark.parametrize(("mode", "scale"), [("se3", 1.0), ("sim3", 0.37)])
def test_transformed_copy_has_zero_error(pair, mode, scale):
    _, ref = pair  # 700 poses, as in the evo comparisons: the compiled functions are reused
    est = _moved(ref, [0.4, -0.2, 2.5], [-3.0, 7.0, 0.5], scale)
    ev = evaluate(ref, est, align=mode)
    d = ev.to_dict()
    for key in ("ate", "are", "ape", "rpe_2m", "rpe_5m", "rpe_10m"):
        assert d[key]["max"] < 1e-9, key
    # The alignment found is the inverse of the transform applied.
    R = Rotation.from_rotvec([0.4, -0.2, 2.5]).as_matrix()
    np.testing.assert_allclose(np.asarray(ev.result.alignment.R_ref_est), R.T, atol=1e-12)
    np.testing.assert_allclose(float(ev.result.alignment.scale), 1.0 / scale, rtol=1e-12)
    # Without alignment the same copy is far off: the zero above is not vacuous.
    assert evaluate(ref, est, align="none").to_dict()["ate"]["rmse"] > 1.0


@pytest.fixture(scope="module")
def fleet():
    """Four associated trajectory pairs of equal length with different noise and offsets."""
    rng = np.random.default_rng(11)
    refs, ests = [], []
    for k in range(4):
        ref = _path(500, 0.0, 0.02, 0.0, rng, turns=20 + 5 * k)
        refs.append(ref)
        ests.append(
            _moved(_path(500, 0.0, 0.02, 0.01 * (k + 1), rng, turns=20 + 5 * k), [0, 0, 0.3 * k], [k, 0, 0], 1.0)
        )
    stack = lambda trs, f: np.stack([getattr(t, f) for t in trs]).astype(np.float32)
    return (
        refs,
        ests,
        [
            stack(refs, "p_world_body"),
            stack(refs, "q_world_body_xyzw"),
            stack(ests, "p_world_body"),
            stack(ests, "q_world_body_xyzw"),
        ],
    )


def test_batched_float32_matches_single_float64(fleet):
    refs, ests, arrays = fleet
    mode = "sim3"
    batch = evaluate_batch(*arrays, align=mode)
    assert batch.ate.rmse.dtype == jnp.float32 and batch.ate.rmse.shape == (4,)
    assert np.all(np.asarray(batch.ok_align)) and np.all(np.asarray(batch.ok_rpe))
    d = batch.to_dict()
    for k in range(4):
        single = evaluate(refs[k], ests[k], align=mode).to_dict()
        for key in ("ate", "are", "ape", "rpe_2m", "rpe_5m", "rpe_10m"):
            for s in STATS:
                np.testing.assert_allclose(d[key][s][k], single[key][s], rtol=2e-3, atol=2e-5, err_msg=f"{k} {key} {s}")


def test_batch_flags_bad_trajectories_without_nan(fleet):
    _, _, arrays = fleet
    p_ref, q_ref, p_est, q_est = (a.copy() for a in arrays)
    p_est[1, 17, 2] = np.nan  # one poisoned trajectory
    q_est[2, 5] = 0.0  # one zero quaternion
    p_est[3] = p_est[3, :1] + np.linspace(0, 1, 500)[:, None] * np.array([1.0, 2.0, 0.0])  # collinear
    p_ref[3] = p_est[3]
    batch = evaluate_batch(p_ref, q_ref, p_est, q_est, deltas=(2.0, 5.0, 1e4), align="sim3")
    clean = evaluate_batch(*arrays, deltas=(2.0, 5.0, 1e4), align="sim3")
    leaves = jax.tree.leaves(eqx.tree_at(lambda r: r.drift, batch, None))
    assert all(np.all(np.isfinite(np.asarray(x))) for x in leaves if np.asarray(x).dtype.kind == "f")
    # Drift alone is NaN, exactly where a path is shorter than the segment length (the 2.2 m line).
    np.testing.assert_array_equal(
        np.isnan(np.asarray(batch.drift.trans_pct_per_length)), np.asarray(batch.drift.n_segments_per_length) == 0
    )
    np.testing.assert_array_equal(np.asarray(batch.drift.n_segments_per_length)[3, 1:], 0)
    np.testing.assert_array_equal(np.asarray(batch.ok_align), [True, False, False, False])
    # A delta longer than every path: flagged per trajectory, zero statistics.
    np.testing.assert_array_equal(np.asarray(batch.ok_rpe)[:, 2], False)
    assert np.all(np.asarray(batch.rpe.rmse)[:, 2] == 0.0)
    # The healthy trajectory is untouched by its neighbours.
    np.testing.assert_array_equal(np.asarray(batch.ate.rmse)[0], np.asarray(clean.ate.rmse)[0])


def test_single_path_errors(pair):
    ref, est = pair
    with pytest.raises(ValueError, match="no matching timestamps"):
        evaluate(ref, TumTrajectory(est.t_s + 1e3, est.p_world_body, est.q_world_body_xyzw))
    short = est.subset(np.arange(2))
    with pytest.raises(ValueError, match="at least 3 associated poses"):
        evaluate(ref, short, align="sim3")
    with pytest.raises(ValueError, match="RPE delta 1000 m gives no pose pair"):
        evaluate(ref, est, deltas=(2, 1000))
    line = TumTrajectory(est.t_s, np.outer(est.t_s, [1.0, 2.0, 3.0]), est.q_world_body_xyzw)
    with pytest.raises(ValueError, match="degenerate"):
        evaluate(line, line)
    with pytest.raises(ValueError, match="unknown alignment"):
        evaluate(ref, est, align="sim2")
    with pytest.raises(ValueError, match="positive"):
        evaluate(ref, est, deltas=(0.0,))
    with pytest.raises(ValueError, match="integers"):
        evaluate(ref, est, deltas=(1.5,), delta_unit="frames")
    # Two poses are fine without a Umeyama fit.
    d = evaluate(ref, short, align="origin", deltas=(1,), delta_unit="frames").to_dict()
    assert d["n_pairs"] == 2 and all(np.isfinite(v) for v in d["ate"].values())
