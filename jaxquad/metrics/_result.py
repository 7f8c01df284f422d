"""The result of evaluating an estimate against a reference: statistics, alignment, validity flags."""

from __future__ import annotations

import equinox as eqx
import jax
import numpy as np
from jaxtyping import Array, Bool, Float, Int

from jaxquad.metrics._align import Alignment
from jaxquad.metrics._drift import Drift
from jaxquad.metrics._stats import Stats


def delta_key(delta: float, unit: str) -> str:
    """JSON key of the RPE for one delta: rpe_2m, rpe_2.5m, rpe_10frames."""
    return f"rpe_{float(delta):g}{'m' if unit == 'm' else 'frames'}"


class EvalResult(eqx.Module):
    """Paper metrics of one trajectory (or of a batch: every leaf gains a leading axis).

    ate: APE translation (m). are / are_deg: APE rotation angle (rad / deg). ape: APE full
    transformation (dimensionless). ape_rotation_part: ||R(E) - I||_F. rpe: RPE translation (m) with
    a leading axis over `deltas` (metres or frames, see `delta_unit`). n_poses: associated poses.
    `ok` is False when the alignment was degenerate or a delta produced no pose pair; the statistics
    concerned are then zero, never NaN. drift: KITTI segment drift of the unaligned estimate, NaN
    where its segment count is 0 (a path shorter than the segment length); `ok` does not cover it.
    """

    ate: Stats
    are: Stats
    are_deg: Stats
    ape: Stats
    ape_rotation_part: Stats
    rpe: Stats
    deltas: Float[Array, "*b D"]
    n_poses: Int[Array, "*b"]
    alignment: Alignment
    ok_align: Bool[Array, "*b"]
    ok_rpe: Bool[Array, "*b D"]
    drift: Drift
    align_mode: str = eqx.field(static=True)
    delta_unit: str = eqx.field(static=True)

    @property
    def ok(self) -> np.ndarray:
        return np.asarray(np.asarray(self.ok_align) & np.all(np.asarray(self.ok_rpe), axis=-1))

    def rpe_at(self, k: int) -> Stats:
        """RPE statistics of the k-th delta."""
        return jax.tree.map(lambda a: a[..., k], self.rpe)

    def to_dict(self) -> dict:
        """Dict of keys ate, are, are_deg, ape, ape_rotation_part, rpe_<delta><unit>, drift_pct,
        drift_deg_per_m, n_pairs, alignment (mode, rotation, translation, scale), ok. Batched results
        give lists. Drift may hold NaN: write it with `jaxquad.io.to_json` (NaN -> null)."""
        out = {
            "ate": self.ate.to_dict(),
            "are": self.are.to_dict(),
            "are_deg": self.are_deg.to_dict(),
            "ape": self.ape.to_dict(),
            "ape_rotation_part": self.ape_rotation_part.to_dict(),
        }
        deltas = np.asarray(self.deltas).reshape(-1, np.shape(self.deltas)[-1])[0]
        for k, d in enumerate(deltas):
            out[delta_key(float(d), self.delta_unit)] = {
                **self.rpe_at(k).to_dict(),
                "n_pairs": np.asarray(self.rpe.n)[..., k].tolist(),
            }
        out.update(self.drift.to_dict())
        out["n_pairs"] = np.asarray(self.n_poses).tolist()
        out["alignment"] = {
            "mode": self.align_mode,
            "rotation": np.asarray(self.alignment.R_ref_est).tolist(),
            "translation": np.asarray(self.alignment.t_ref_est).tolist(),
            "scale": np.asarray(self.alignment.scale).tolist(),
        }
        out["ok"] = self.ok.tolist()
        return out
