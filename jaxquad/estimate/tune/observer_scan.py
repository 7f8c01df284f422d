"""The contact observer over one robot's tuning inputs, and its scores.

Scores (`fleet_scores`) are pooled over robots, feet and valid samples: contact precision, recall
and F1 from the summed counts; touchdown and lift-off delays (ms, scores.detection_delays per robot)
averaged over all matched events; force RMSE (N) of the filtered force against gt_force z.
"""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Bool, Float, Int

from jaxquad.estimate import scores
from jaxquad.estimate.pipeline import observer_params_for_axes, vertical_estimate
from jaxquad.estimate.tune.observer_inputs import ContactTruth, ObserverInputs
from jaxquad.kernels import ContactEstimate, ContactObserver, ObserverParams


class Counts(eqx.Module):
    """Per-foot sums over valid samples: contact confusion counts and squared force error (N^2)."""

    tp: Int[Array, "F"]
    fp: Int[Array, "F"]
    fn: Int[Array, "F"]
    force_sq: Float[Array, "F"]
    samples: Int[Array, ""]


def _observer_scan(
    params: ObserverParams,
    inputs: ObserverInputs,
    carry0,
    reduce,
    truth: tuple[Bool[Array, "T F"], Float[Array, "T F"], Bool[Array, "T"]] | None,  # contact, force_z, valid
):
    """lax.scan of the observer; reduce(carry, estimate, truth_k) -> (carry, output)."""
    observer = ContactObserver()
    row_params = observer_params_for_axes(params, inputs.axes)
    state0 = observer.init(row_params, inputs.p[0], inputs.J_z.shape[-2])

    def step(c, x):
        state, acc = c
        (p, tau_bar, J_z, dt, restart), truth_k = x
        state = eqx.tree_at(lambda s: s.p_hat, state, jnp.where(restart, p, state.p_hat))
        state, est = observer.step(row_params, state, p, tau_bar, J_z, dt)
        acc, out = reduce(acc, vertical_estimate(est, inputs.axes), truth_k)
        return (state, acc), out

    xs = ((inputs.p, inputs.tau_bar, inputs.J_z, inputs.dt, inputs.restart), truth)
    (_, acc), out = jax.lax.scan(step, (state0, carry0), xs)
    return acc, out


def run_observer(params: ObserverParams, inputs: ObserverInputs) -> ContactEstimate:
    """The observer over one robot's inputs; per-sample estimates with a leading axis T."""
    return _observer_scan(params, inputs, None, lambda acc, est, _: (acc, est), None)[1]


def observer_counts(params: ObserverParams, inputs: ObserverInputs, truth: ContactTruth) -> Counts:
    """Contact confusion counts and squared force error of one robot, accumulated inside the scan."""
    n_feet = inputs.n_feet
    zeros = jnp.zeros(n_feet, jnp.int32)
    acc0 = Counts(
        tp=zeros, fp=zeros, fn=zeros, force_sq=jnp.zeros(n_feet, jnp.float32), samples=jnp.zeros((), jnp.int32)
    )

    def reduce(acc: Counts, est: ContactEstimate, truth_k):
        contact, force_z, valid = truth_k
        hit, true = est.contact & valid, contact & valid
        err = jnp.where(valid, est.force_z_filtered - force_z, 0.0)
        return Counts(
            tp=acc.tp + (hit & true).astype(jnp.int32),
            fp=acc.fp + (hit & ~true).astype(jnp.int32),
            fn=acc.fn + (~hit & true).astype(jnp.int32),
            force_sq=acc.force_sq + err * err,
            samples=acc.samples + valid.astype(jnp.int32),
        ), None

    return _observer_scan(params, inputs, acc0, reduce, (truth.contact, truth.force_z, truth.valid))[0]


def f1_of(counts: Counts) -> Float[Array, "..."]:
    """Pooled F1 over feet of (possibly batched) counts; 0 where nothing was detected or true."""
    tp, fp, fn = (jnp.sum(x, axis=-1).astype(jnp.float32) for x in (counts.tp, counts.fp, counts.fn))
    return jnp.where(tp > 0, 2 * tp / jnp.maximum(2 * tp + fp + fn, 1.0), 0.0)


@jax.jit
def _fleet_estimates(params: ObserverParams, inputs: ObserverInputs) -> ContactEstimate:
    return jax.vmap(run_observer, in_axes=(None, 0))(params, inputs)


def fleet_scores(
    params: ObserverParams, inputs: ObserverInputs, truth: ContactTruth, t, max_delay_s: float = 0.1
) -> dict:
    """Exact scores of one configuration over a fleet (pooled; see the module docstring)."""
    est = jax.tree.map(np.asarray, _fleet_estimates(params, inputs))
    contact, force_true, valid = (np.asarray(x) for x in (truth.contact, truth.force_z, truth.valid))
    n, T, F = contact.shape
    c = scores.contact_scores(est.contact.reshape(n * T, F), contact.reshape(n * T, F), valid.reshape(n * T))
    out = {"f1": c["f1"], "precision": c["precision"], "recall": c["recall"]}
    # Delays pooled over matched events (NaN when none matched: never a 0 from nothing).
    agg = scores.aggregate_delays(
        [scores.detection_delays(t, est.contact[i], contact[i], valid[i], max_delay_s) for i in range(n)]
    )
    for kind in ("touchdown", "liftoff"):
        a = agg[kind]
        out[f"{kind}_mean_ms"], out[f"{kind}_mean_abs_ms"] = a["mean_ms"], a["mean_abs_ms"]
        out[f"{kind}_matched"], out[f"{kind}_missed"] = a["n_events"], a["n_missed"]
    out["force_rmse_n"] = scores.force_rmse(
        est.force_z_filtered.reshape(n * T, F), force_true.reshape(n * T, F), valid.reshape(n * T)
    )["rmse_n"]
    return out


def delay_cost(s: dict, max_delay_s: float = 0.1) -> float:
    """Mean |touchdown delay| + mean |lift-off delay| (ms), a missed edge counting as max_delay_s."""
    cost = 0.0
    for kind in ("touchdown", "liftoff"):
        matched, missed = s[f"{kind}_matched"], s[f"{kind}_missed"]
        events = matched + missed
        matched_ms = s[f"{kind}_mean_abs_ms"] * matched if matched else 0.0
        cost += (matched_ms + 1e3 * max_delay_s * missed) / events if events else 0.0
    return cost
