"""One evaluation path for one trajectory in float64 (files) and for batches in float32 (fleets).

`evaluate_poses` is the pure single-trajectory function on associated, equal-length arrays.
`evaluate` runs it jitted on a pair of TUM trajectories after association, with float64 enabled
only for that call; `evaluate_batch` vmaps it over trajectories in the default precision.
"""

from __future__ import annotations

import dataclasses
import functools
from collections.abc import Sequence

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike, Bool, Float

from jaxquad.io.tum import TumTrajectory
from jaxquad.metrics._align import ALIGN_MODES
from jaxquad.metrics._align import align as align_poses
from jaxquad.metrics._ape import PoseErrors, ape
from jaxquad.metrics._associate import associate
from jaxquad.metrics._drift import DRIFT_LENGTHS_M, DRIFT_STEP, check_drift_options, segment_drift
from jaxquad.metrics._result import EvalResult
from jaxquad.metrics._rpe import pairs_for, rpe
from jaxquad.metrics._se3 import rotation_from_quat_xyzw
from jaxquad.metrics._stats import statistics

DELTA_UNITS = ("m", "frames")


class AlignedTrack(eqx.Module):
    """Per-pose view of one evaluation: the aligned estimate and its APE per pose."""

    p_est_aligned: Float[Array, "N 3"]
    ape: PoseErrors
    ok_input: Bool[Array, ""]


def evaluate_poses(
    p_ref: Float[Array, "N 3"],
    q_ref_xyzw: Float[Array, "N 4"],
    p_est: Float[Array, "N 3"],
    q_est_xyzw: Float[Array, "N 4"],
    deltas: Float[Array, "D"],
    drift_lengths_m: Float[Array, "L"] = DRIFT_LENGTHS_M,
    *,
    align: str = "se3",
    delta_unit: str = "m",
    all_pairs: bool = False,
    rel_tol: float = 0.1,
    drift_step: int = DRIFT_STEP,
) -> tuple[EvalResult, AlignedTrack]:
    """Paper metrics of one associated trajectory pair (pose k of the estimate belongs to pose k of
    the reference), plus KITTI segment drift of the unaligned estimate. Non-finite positions or
    zero/non-finite quaternions are replaced by the origin and identity and clear `ok_align`, so one
    bad trajectory of a batch gives a flagged result. Static: align, delta_unit, all_pairs, rel_tol,
    drift_step; deltas and drift lengths are traced."""
    dtype = p_ref.dtype

    def sanitize(p, q):
        p_ok = jnp.all(jnp.isfinite(p), axis=-1)
        q_ok = jnp.all(jnp.isfinite(q), axis=-1) & jnp.any(q != 0, axis=-1)
        p = jnp.where(p_ok[:, None], p, 0.0)
        q = jnp.where(q_ok[:, None], q, jnp.array([0.0, 0.0, 0.0, 1.0], dtype))
        return p, q, jnp.all(p_ok & q_ok)

    p_ref, q_ref_xyzw, ok_ref = sanitize(p_ref, q_ref_xyzw)
    p_est, q_est_xyzw, ok_est = sanitize(p_est, q_est_xyzw)
    ok_input = ok_ref & ok_est
    R_ref = jax.vmap(rotation_from_quat_xyzw)(q_ref_xyzw)
    R_est = jax.vmap(rotation_from_quat_xyzw)(q_est_xyzw)

    p_al, R_al, alignment = align_poses(p_ref, R_ref, p_est, R_est, align)
    errors = ape(p_ref, R_ref, p_al, R_al)

    # Pairs walk the aligned estimate (evo's default); one scan over all deltas at once.
    pairs = jax.vmap(lambda d: pairs_for(p_al, d, delta_unit, all_pairs, rel_tol))(deltas)
    rpe_trans = jax.vmap(lambda pr: rpe(p_ref, R_ref, p_al, R_al, pr).translation_m)(pairs)
    rpe_stats = jax.vmap(statistics)(rpe_trans, pairs.mask)
    # Drift compares relative poses, so it needs no alignment (and must not see a sim3 scale).
    drift = segment_drift(p_ref, R_ref, p_est, R_est, drift_lengths_m, drift_step)

    ok_align = alignment.ok & ok_input
    result = EvalResult(
        ate=statistics(errors.translation_m),
        are=statistics(errors.angle_rad),
        are_deg=statistics(jnp.rad2deg(errors.angle_rad)),
        ape=statistics(errors.full),
        ape_rotation_part=statistics(errors.rotation_part),
        rpe=rpe_stats,
        deltas=jnp.asarray(deltas, dtype),
        n_poses=jnp.asarray(p_ref.shape[0], jnp.int32),
        alignment=alignment,
        ok_align=ok_align,
        ok_rpe=rpe_stats.n > 0,
        drift=drift,
        align_mode=align,
        delta_unit=delta_unit,
    )
    return result, AlignedTrack(p_al, errors, ok_input)


def _check_options(align: str, deltas: Sequence[float], delta_unit: str) -> np.ndarray:
    if align not in ALIGN_MODES:
        raise ValueError(f"unknown alignment {align!r}; expected one of {', '.join(ALIGN_MODES)}")
    if delta_unit not in DELTA_UNITS:
        raise ValueError(f"unknown RPE delta unit {delta_unit!r}; expected 'm' or 'frames'")
    d = np.atleast_1d(np.asarray(deltas, dtype=np.float64))
    if d.ndim != 1 or d.size == 0:
        raise ValueError("give at least one RPE delta")
    if not np.all(np.isfinite(d)) or np.any(d <= 0):
        raise ValueError(f"RPE deltas must be positive and finite, got {d.tolist()}")
    if delta_unit == "frames" and np.any(d != np.round(d)):
        raise ValueError(f"RPE deltas in frames must be integers, got {d.tolist()}")
    return d


@functools.cache
def _single(align: str, delta_unit: str, all_pairs: bool, rel_tol: float, drift_step: int = DRIFT_STEP):
    return jax.jit(
        functools.partial(
            evaluate_poses,
            align=align,
            delta_unit=delta_unit,
            all_pairs=all_pairs,
            rel_tol=rel_tol,
            drift_step=drift_step,
        )
    )


@functools.cache
def _batched(align: str, delta_unit: str, all_pairs: bool, rel_tol: float, drift_step: int = DRIFT_STEP):
    one = functools.partial(
        evaluate_poses,
        align=align,
        delta_unit=delta_unit,
        all_pairs=all_pairs,
        rel_tol=rel_tol,
        drift_step=drift_step,
    )
    # Only the statistics leave the jitted function; per-pose arrays are dropped inside it.
    return jax.jit(
        jax.vmap(
            lambda pr, qr, pe, qe, d, lengths: one(pr, qr, pe, qe, d, lengths)[0], in_axes=(0, 0, 0, 0, None, None)
        )
    )


@dataclasses.dataclass(frozen=True)
class Evaluation:
    """`evaluate`'s answer: the metrics plus the associated poses for plots and reports."""

    result: EvalResult
    t_s: np.ndarray  # (N,) estimate stamps of the associated poses
    p_ref: np.ndarray  # (N, 3)
    p_est_aligned: np.ndarray  # (N, 3)
    ape_translation_m: np.ndarray  # (N,)

    def to_dict(self) -> dict:
        return self.result.to_dict()


def evaluate(
    ref: TumTrajectory,
    est: TumTrajectory,
    *,
    align: str = "se3",
    deltas: Sequence[float] = (2.0, 5.0, 10.0),
    delta_unit: str = "m",
    all_pairs: bool = False,
    max_diff_s: float = 0.01,
    rel_tol: float = 0.1,
    drift_lengths_m: Sequence[float] = DRIFT_LENGTHS_M,
    drift_step: int = DRIFT_STEP,
) -> Evaluation:
    """Associate, align and evaluate an estimate against a reference in float64, as evo does
    (evo_ape / evo_rpe with the same options), plus KITTI segment drift (alignment-free; NaN with 0
    segments when the reference path is shorter than every length). ValueError (one line) when no
    stamps match, the alignment is impossible (fewer than 3 poses, degenerate positions) or a delta
    gives no pair."""
    d = _check_options(align, deltas, delta_unit)
    lengths = check_drift_options(drift_lengths_m, drift_step)
    for name, tr in (("reference", ref), ("estimate", est)):
        q = tr.q_world_body_xyzw
        if not (np.all(np.isfinite(tr.p_world_body)) and np.all(np.isfinite(q))):
            raise ValueError(f"{name} trajectory has NaN or infinite values")
        if np.any(np.all(q == 0, axis=1)):
            raise ValueError(f"{name} trajectory has a zero quaternion")
    idx_ref, idx_est = associate(ref.t_s, est.t_s, max_diff_s)
    n = idx_ref.size
    if align in ("se3", "sim3", "scale") and n < 3:
        raise ValueError(f"{align} alignment needs at least 3 associated poses, got {n}")
    ref_a, est_a = ref.subset(idx_ref), est.subset(idx_est)
    with jax.enable_x64(True):
        res, track = _single(align, delta_unit, bool(all_pairs), float(rel_tol), int(drift_step))(
            jnp.asarray(ref_a.p_world_body, jnp.float64),
            jnp.asarray(ref_a.q_world_body_xyzw, jnp.float64),
            jnp.asarray(est_a.p_world_body, jnp.float64),
            jnp.asarray(est_a.q_world_body_xyzw, jnp.float64),
            jnp.asarray(d, jnp.float64),
            jnp.asarray(lengths, jnp.float64),
        )
        res, track = jax.tree.map(np.asarray, (res, track))
    if not res.ok_align:
        raise ValueError(
            f"{align} alignment is degenerate: the {n} associated estimate positions are (nearly) collinear or constant"
        )
    for k in np.flatnonzero(~res.ok_rpe):
        unit = "m" if delta_unit == "m" else "frames"
        length = float(np.sum(np.linalg.norm(np.diff(track.p_est_aligned, axis=0), axis=1)))
        raise ValueError(
            f"RPE delta {d[k]:g} {unit} gives no pose pair (aligned estimate: {n} poses, {length:.3f} m path)"
        )
    return Evaluation(res, est_a.t_s, ref_a.p_world_body, track.p_est_aligned, track.ape.translation_m)


def evaluate_batch(
    p_ref: Float[ArrayLike, "B N 3"],
    q_ref_xyzw: Float[ArrayLike, "B N 4"],
    p_est: Float[ArrayLike, "B N 3"],
    q_est_xyzw: Float[ArrayLike, "B N 4"],
    deltas: Sequence[float] = (2.0, 5.0, 10.0),
    *,
    align: str = "se3",
    delta_unit: str = "m",
    all_pairs: bool = False,
    rel_tol: float = 0.1,
    drift_lengths_m: Sequence[float] = DRIFT_LENGTHS_M,
    drift_step: int = DRIFT_STEP,
) -> EvalResult:
    """Metrics of B associated trajectory pairs of N poses each, jitted and vmapped (float32 unless
    the caller enabled float64). Never raises on data: check `ok_align` / `ok_rpe` per trajectory and
    `drift.n_segments` (drift is NaN where it is 0)."""
    d = _check_options(align, deltas, delta_unit)
    lengths = check_drift_options(drift_lengths_m, drift_step)
    shapes = [np.shape(a) for a in (p_ref, q_ref_xyzw, p_est, q_est_xyzw)]
    b, n = shapes[0][:2] if len(shapes[0]) == 3 else (None, None)
    if shapes != [(b, n, 3), (b, n, 4), (b, n, 3), (b, n, 4)] or b is None:
        raise ValueError(f"batched trajectories must have shapes (B, N, 3), (B, N, 4) twice; got {shapes}")
    fn = _batched(align, delta_unit, bool(all_pairs), float(rel_tol), int(drift_step))
    arrays = [jnp.asarray(a) for a in (p_ref, q_ref_xyzw, p_est, q_est_xyzw)]
    return fn(*arrays, jnp.asarray(d, arrays[0].dtype), jnp.asarray(lengths, arrays[0].dtype))
