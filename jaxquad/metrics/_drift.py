"""Segment drift as the KITTI odometry benchmark defines it (t_rel in %, r_rel in deg/m).

For every start index i = 0, step, 2 step, ... and every path length L, the segment ends at the first
index j whose ground-truth path length from i exceeds L. Its error is the relative pose error
E = (Q_i^-1 Q_j)^-1 (P_i^-1 P_j) (Q the reference, P the estimate): t_rel = |t(E)| / L, r_rel =
|log R(E)| / L, divided by the nominal L as KITTI does. Relative poses make the metric alignment-free
(a rigid motion of the whole estimate changes nothing), and an estimate that stands still scores about
100 % on straight segments. Scores are means over all segments of all lengths (KITTI's score) and per
length; with no segment they are NaN and the counts are 0.
"""

from __future__ import annotations

import functools
from collections.abc import Sequence

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float, Int

from jaxquad.metrics._rpe import Pairs, _step_lengths, rpe
from jaxquad.metrics._se3 import rotation_from_quat_xyzw

DRIFT_LENGTHS_M = (2.0, 5.0, 10.0)
DRIFT_STEP = 10


class Drift(eqx.Module):
    """Segment drift of one trajectory (or of a batch: every leaf gains a leading axis).

    trans_pct / rot_deg_per_m: means over all n_segments segments of all lengths; *_per_length: means
    over the n_segments_per_length segments of each length in lengths_m. NaN where a count is 0.
    """

    lengths_m: Float[Array, "*b L"]
    trans_pct: Float[Array, "*b"]
    rot_deg_per_m: Float[Array, "*b"]
    trans_pct_per_length: Float[Array, "*b L"]
    rot_deg_per_m_per_length: Float[Array, "*b L"]
    n_segments: Int[Array, "*b"]
    n_segments_per_length: Int[Array, "*b L"]
    step: int = eqx.field(static=True)

    def to_dict(self) -> dict:
        """{"drift_pct": {...}, "drift_deg_per_m": {...}}, each with mean, lengths_m, per_length,
        n_segments, n_segments_per_length, step_poses (lists for batched results; NaN stays NaN)."""
        lengths = np.asarray(self.lengths_m).reshape(-1, np.shape(self.lengths_m)[-1])[0].tolist()
        common = {
            "lengths_m": lengths,
            "n_segments": np.asarray(self.n_segments).tolist(),
            "n_segments_per_length": np.asarray(self.n_segments_per_length).tolist(),
            "step_poses": self.step,
        }

        def one(mean, per_length):
            return {
                "mean": np.asarray(mean).tolist(),
                "per_length": np.asarray(per_length).tolist(),
                **common,
            }

        return {
            "drift_pct": one(self.trans_pct, self.trans_pct_per_length),
            "drift_deg_per_m": one(self.rot_deg_per_m, self.rot_deg_per_m_per_length),
        }


def segment_pairs(dist_ref: Float[Array, "N"], length_m: Float[Array, ""], step: int) -> Pairs:
    """Segments (i, j) for starts i = 0, step, ...: j is the first index with dist_ref[j] - dist_ref[i]
    > length_m (dist_ref: non-decreasing path length from pose 0). Starts with no such j are masked."""
    n = dist_ref.shape[0]
    i = jnp.arange(0, n, step)
    j = jnp.searchsorted(dist_ref, dist_ref[i] + length_m, side="right")
    mask = j < n
    return Pairs(jnp.where(mask, i, 0), jnp.where(mask, j, 0), mask)


def segment_drift(
    p_ref: Float[Array, "N 3"],
    R_ref: Float[Array, "N 3 3"],
    p_est: Float[Array, "N 3"],
    R_est: Float[Array, "N 3 3"],
    lengths_m: Float[Array, "L"],
    step: int = DRIFT_STEP,
) -> Drift:
    """KITTI segment drift of an associated estimate (pose k belongs to reference pose k); lengths are
    traced, step (poses between segment starts) is static. Segment lengths walk the reference path."""
    lengths = jnp.asarray(lengths_m, p_ref.dtype)
    dist = jnp.concatenate([jnp.zeros(1, p_ref.dtype), jnp.cumsum(_step_lengths(p_ref))])
    pairs = jax.vmap(lambda L: segment_pairs(dist, L, step))(lengths)
    err = jax.vmap(lambda pr: rpe(p_ref, R_ref, p_est, R_est, pr))(pairs)
    t_pct = 100.0 * err.translation_m / lengths[:, None]
    r_deg_per_m = jnp.rad2deg(err.angle_rad) / lengths[:, None]
    m = pairs.mask
    n_per = jnp.sum(m, axis=-1).astype(jnp.int32)
    n = jnp.sum(n_per)

    def mean(x, count, axis):
        total = jnp.sum(jnp.where(m, x, 0.0), axis=axis)
        return jnp.where(count > 0, total / jnp.maximum(count, 1).astype(x.dtype), jnp.nan)

    return Drift(
        lengths_m=lengths,
        trans_pct=mean(t_pct, n, None),
        rot_deg_per_m=mean(r_deg_per_m, n, None),
        trans_pct_per_length=mean(t_pct, n_per, -1),
        rot_deg_per_m_per_length=mean(r_deg_per_m, n_per, -1),
        n_segments=n,
        n_segments_per_length=n_per,
        step=step,
    )


def check_drift_options(lengths_m: Sequence[float], step: int) -> np.ndarray:
    """Lengths as a float64 array; ValueError (one line) unless they are positive and finite and step >= 1."""
    lengths = np.atleast_1d(np.asarray(lengths_m, dtype=np.float64))
    if lengths.ndim != 1 or lengths.size == 0:
        raise ValueError("give at least one drift segment length")
    if not np.all(np.isfinite(lengths)) or np.any(lengths <= 0):
        raise ValueError(f"drift segment lengths must be positive and finite metres, got {lengths.tolist()}")
    if int(step) != step or step < 1:
        raise ValueError(f"drift step must be an integer >= 1 pose, got {step}")
    return lengths


@functools.cache
def _single(step: int):
    def one(p_ref, q_ref_xyzw, p_est, q_est_xyzw, lengths):
        R = jax.vmap(rotation_from_quat_xyzw)
        return segment_drift(p_ref, R(q_ref_xyzw), p_est, R(q_est_xyzw), lengths, step)

    return jax.jit(one)


def evaluate_drift(
    p_ref: np.ndarray,
    q_ref_xyzw: np.ndarray,
    p_est: np.ndarray,
    q_est_xyzw: np.ndarray,
    lengths_m: Sequence[float] = DRIFT_LENGTHS_M,
    step: int = DRIFT_STEP,
) -> Drift:
    """Segment drift of one associated trajectory pair (N, 3) / (N, 4) in float64, as NumPy leaves
    (N = 0 gives NaN and 0 segments). ValueError (one line) on mismatched shapes, non-finite values
    or bad options."""
    lengths = check_drift_options(lengths_m, step)
    arrays = [np.asarray(a, np.float64) for a in (p_ref, q_ref_xyzw, p_est, q_est_xyzw)]
    n = arrays[0].shape[0] if arrays[0].ndim == 2 else None
    if [a.shape for a in arrays] != [(n, 3), (n, 4), (n, 3), (n, 4)] or n is None:
        raise ValueError(f"drift needs (N, 3), (N, 4) arrays twice; got {[a.shape for a in arrays]}")
    for name, a in zip(
        ("reference positions", "reference quaternions", "estimate positions", "estimate quaternions"), arrays
    ):
        if not np.all(np.isfinite(a)):
            raise ValueError(f"drift: {name} have NaN or infinite values")
        if a.shape[1] == 4 and np.any(np.all(a == 0, axis=1)):
            raise ValueError(f"drift: {name} include a zero quaternion")
    if n == 0:  # no pose, no segment: one identity pose gives that answer without empty gathers
        arrays = [np.eye(4)[[3], : a.shape[1]] if a.shape[1] == 4 else np.zeros((1, 3)) for a in arrays]
    with jax.enable_x64(True):
        out = _single(int(step))(*(jnp.asarray(a) for a in arrays), jnp.asarray(lengths))
        return jax.tree.map(np.asarray, out)
